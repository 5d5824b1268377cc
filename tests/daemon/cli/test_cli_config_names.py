"""A `[datasets.NAME]` table of config.toml whose NAME is no dataset and no folder of the outbox (a
seventh black-box review, F5: `[datasets.kitchn] subject_masks = ...` was taken in silence, and 'kitchen'
was patched without its masks). `ppd status` and `ppd config show` warn, one line each, with a "did you
mean" when a dataset or folder is named like it; not an error: a dataset may be configured before its
folder exists, and the warning says so then. Real CLI, real folders, a real SQLite store."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_shoot

runner = CliRunner()


def run(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, list(args))
    return result.exit_code, " ".join(result.stdout.split()), " ".join(result.stderr.split())


def test_a_config_table_that_names_no_dataset_is_warned_of(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    outbox = ppd_env["outbox"]
    kitchen = make_shoot(outbox / "kitchen", 2)
    (outbox / "garden").mkdir()  # a folder of the outbox, no dataset yet: configured ahead, rightly
    masks = tmp_path / "masks"
    masks.mkdir()
    (ppd_env["config"] / "config.toml").write_text(
        f'[datasets.kitchn]\nsubject_masks = "{masks}"\n'
        '[datasets.porch.patch]\npatch_size = "7%"\n'
        '[datasets.garden.patch]\npatch_size = "7%"\n'
        '[datasets.default.patch]\npatch_size = "7%"\n'
    )
    typo = "config: [datasets.kitchn] names no dataset and no folder in the outbox (did you mean 'kitchen'?)"
    ahead = (f"config: [datasets.porch] names no dataset and no folder in the outbox (set up before its "
             f"folder? it applies once {outbox / 'porch'} exists")  # fmt: skip

    code, out, err = run("config", "show")  # no store yet: the outbox's folders are the names
    assert code == 0 and "[datasets.kitchn]" in out, out
    assert f"ppd: warning: {typo}" in err and ahead in err, err
    assert "garden" not in err and "default" not in err, err
    assert not (ppd_env["data"] / "ppd.db").exists() and not any(ppd_env["data"].iterdir())  # made nothing

    assert run("poison", str(kitchen))[0] == 0
    code, out, err = run("status")
    assert code == 0 and typo in err and ahead in err and err.count("ppd: warning:") == 2, err
    code, _, err = run("config", "show")
    assert code == 0 and typo in err and err.count("ppd: warning:") == 2, err

    (ppd_env["config"] / "config.toml").write_text('[datasets.kitchen.patch]\npatch_size = "7%"\n')
    assert run("status")[2] == "" and run("config", "show")[2] == ""
