"""ppd's data folder (the vault of originals, the seal key, restore's kept copies) is never where files
get published (a second black-box review): `ppd dataset set --publish-dir` took a folder holding it,
and data/displaced itself, and `ppd poison` patched a folder holding it in place."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_image, make_shoot

runner = CliRunner()


def test_a_publish_folder_never_holds_or_sits_in_the_data_folder(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 2)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    for folder in (tmp_path, ppd_env["data"] / "displaced"):
        result = runner.invoke(app, ["dataset", "set", "shoot", "--publish-dir", str(folder)])
        assert result.exit_code == 2 and "data folder" in result.output, result.output
    shown = runner.invoke(app, ["dataset", "show", "shoot", "--json"]).stdout
    assert '"publish_dir": null' in shown
    fine = runner.invoke(app, ["dataset", "set", "shoot", "--publish-dir", str(tmp_path / "pub")])
    assert fine.exit_code == 0, fine.output


def test_poison_refuses_a_folder_that_holds_the_data_folder(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    make_image(tmp_path / "v0.png", 0)  # tmp_path holds data/: patched in place, published with it
    before = (tmp_path / "v0.png").read_bytes()
    result = runner.invoke(app, ["poison", str(tmp_path)])
    assert result.exit_code == 3 and "vault of originals" in result.output, result.output
    assert (tmp_path / "v0.png").read_bytes() == before
    out = runner.invoke(app, ["poison", str(tmp_path), "--out", str(tmp_path.parent / "copies")])
    assert out.exit_code == 0, out.output  # copies elsewhere publish nothing of ppd's


def test_a_publish_folder_inside_the_outbox_is_refused(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A black-box review (s5 F6): a publish folder inside the outbox was taken; the daemon then took the
    files it published there in as a new dataset ('public') that `ppd status` called not patched yet.
    Refused as `--out` inside a dataset is, before anything is written (the refusal made the dataset)."""
    outbox = ppd_env["outbox"]
    (outbox / "castle").mkdir(parents=True)
    (tmp_path / "link").symlink_to(outbox / "castle")
    for folder in (outbox / "public", outbox, tmp_path / "link" / "pub"):
        result = runner.invoke(app, ["dataset", "set", "castle", "--publish-dir", str(folder)])
        said = " ".join(result.output.split())
        assert result.exit_code == 2 and f"is inside the outbox {outbox}" in said, result.output
        assert said.startswith(f"ppd: error: --publish-dir {folder}")
        assert said.endswith("choose another folder")
    assert "castle" not in runner.invoke(app, ["status"]).output
    fine = runner.invoke(app, ["dataset", "set", "castle", "--publish-dir", str(tmp_path / "pub")])
    assert fine.exit_code == 0, fine.output


@pytest.mark.parametrize("table", ["", "[datasets.castle]\n"])
def test_a_configured_publish_folder_inside_the_outbox_stops_every_command(
    ppd_env: dict[str, Path], table: str
) -> None:
    """config.toml's publish_dir (or a dataset's) inside the outbox: one line naming the key, exit 2,
    `ppd watch` included (a real process), before it watches anything."""
    import subprocess
    import sys

    from testkit.reliability import REPO

    config, outbox = ppd_env["config"] / "config.toml", ppd_env["outbox"]
    config.write_text(f'{table}publish_dir = "{outbox / "public"}"\n')
    key = "datasets.castle.publish_dir" if table else "publish_dir"
    status = runner.invoke(app, ["status"])
    assert status.exit_code == 2, status.output
    assert " ".join(status.output.split()) == (
        f"ppd: error: {config}: {key}: {outbox / 'public'} is inside the outbox {outbox}, whose new files "
        "ppd patches as a dataset; choose a folder outside it"
    )
    watch = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "watch", "--no-verify"], cwd=REPO, capture_output=True,
        text=True, timeout=60,
    )  # fmt: skip
    assert watch.returncode == 2 and f"{key}: " in watch.stderr and len(watch.stderr.splitlines()) == 1
