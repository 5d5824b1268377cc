"""Every command that takes a dataset takes it as a name, a folder (relative or absolute) or a
verification folder, from any working folder (issue 26). Real store, real vault, real files; the
CLI in-process (typer's runner) with a real working folder (chdir). No COLMAP: a verification
folder is a real report.json beside a run row of the store."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.context import AppContext

runner = CliRunner()
WHERE = ("holder", "inside", "elsewhere")  # the working folder: holds castle/, is castle/, neither
FORMS = ("name", "relative", "absolute")


def _shoot(root: Path) -> Path:
    folder = root / "photos" / "castle"
    folder.mkdir(parents=True)
    for i in range(2):
        rng = np.random.default_rng(i)
        Image.fromarray(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)).save(folder / f"view{i}.png")
    return folder


def _chdir_and_arg(shoot: Path, where: str, form: str, monkeypatch: pytest.MonkeyPatch) -> str:
    cwd = {"holder": shoot.parent, "inside": shoot, "elsewhere": shoot.parents[1] / "elsewhere"}[where]
    cwd.mkdir(exist_ok=True)
    monkeypatch.chdir(cwd)
    if form == "name":
        return "castle"
    if form == "absolute":
        return str(shoot)
    return os.path.relpath(shoot, cwd)  # "castle", "." or "../photos/castle"


@pytest.fixture
def shoot(ppd_env: dict[str, Path], tmp_path: Path) -> Path:
    folder = _shoot(tmp_path)
    done = runner.invoke(app, ["poison", str(folder)])
    assert done.exit_code == 0, done.output
    return folder


def _originals_back(shoot: Path) -> bool:
    for i in range(2):
        rng = np.random.default_rng(i)
        expected = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
        if not np.array_equal(np.asarray(Image.open(shoot / f"view{i}.png")), expected):
            return False
    return True


@pytest.mark.parametrize("where", WHERE)
@pytest.mark.parametrize("form", FORMS)
def test_restore_takes_a_name_or_a_folder_from_anywhere(
    shoot: Path, where: str, form: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert not _originals_back(shoot)  # ppd poison changed them
    arg = _chdir_and_arg(shoot, where, form, monkeypatch)
    done = runner.invoke(app, ["restore", arg])
    assert done.exit_code == 0, done.output
    assert "restored 2" in done.output
    assert _originals_back(shoot)


@pytest.mark.parametrize("where", WHERE)
@pytest.mark.parametrize("form", FORMS)
def test_report_takes_a_name_or_a_folder_from_anywhere(
    shoot: Path, where: str, form: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    arg = _chdir_and_arg(shoot, where, form, monkeypatch)
    out = tmp_path / f"{where}-{form}.html"
    done = runner.invoke(app, ["report", arg, "--out", str(out)])
    assert done.exit_code == 0, done.output
    page = out.read_text()
    assert "dataset castle" in page  # the dataset's page, not a folder's "no report.json here"
    assert "error" not in done.output


def test_status_verify_preview_take_the_folder(shoot: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(shoot)
    status = runner.invoke(app, ["status", "."])
    assert status.exit_code == 0, status.output
    assert "castle" in status.output and "patched, not verified" in status.output
    verify = runner.invoke(app, ["verify", ".", "--profile", "default"])
    assert verify.exit_code == 2 and "dataset 'castle' has 2" in verify.output  # the dataset, not COLMAP
    empty = shoot.parents[1] / "empty"
    empty.mkdir()
    preview = runner.invoke(app, ["preview", str(empty), "--no-visibility"])
    assert preview.exit_code == 2 and "no photo or video to preview there" in preview.output
    preview = runner.invoke(app, ["preview", ".", "--no-visibility", "--out", str(shoot.parent / "p.png")])
    assert preview.exit_code == 0, preview.output
    assert (shoot.parent / "p.png").is_file()
    missing = runner.invoke(app, ["status", "no-such-thing"])
    assert missing.exit_code == 2 and "no dataset 'no-such-thing'" in missing.output


def test_a_verification_folder_is_its_dataset_and_says_so(
    shoot: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    ctx = AppContext.open()
    try:
        run = Path(ctx.paths.data_dir) / "runs" / "castle" / "20260101T000000-abc"
        (run / "default").mkdir(parents=True)
        (run / "report.json").write_text("{}")
        now = time.time()
        model = str(run / "default")
        ctx.store.add_verification_run("castle", "default", "protected", {}, now - 1, now, model, None)
    finally:
        ctx.close()
    monkeypatch.chdir(run.parent)
    status = runner.invoke(app, ["status", run.name])
    assert status.exit_code == 0, status.output
    assert "verification of dataset 'castle': took the dataset" in status.output
    restored = runner.invoke(app, ["restore", str(run)])
    assert restored.exit_code == 0 and "restored 2" in restored.output, restored.output
    assert _originals_back(shoot)


def test_a_name_and_an_unrelated_folder_take_the_dataset(
    shoot: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    other = shoot.parents[1] / "other"
    (other / "castle").mkdir(parents=True)  # a folder named like the dataset, not the dataset's
    monkeypatch.chdir(other)
    done = runner.invoke(app, ["restore", "castle"])
    assert done.exit_code == 0 and "restored 2" in done.output, done.output
    assert "took the dataset" in done.output
    plain = runner.invoke(app, ["restore", str(other)])
    assert plain.exit_code == 2 and "not a folder ppd patched" in plain.output


def test_auto_and_experiment_take_the_dataset_folder(shoot: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """auto --show reads the dataset's decisions; experiment measures the dataset's originals (from
    the vault), never the patched files in its folder. Neither runs COLMAP here."""
    from daemon.cli.experiment_cmd import resolve_dataset

    monkeypatch.chdir(shoot.parent)
    shown = runner.invoke(app, ["auto", "castle/", "--show"])
    assert shown.exit_code == 0 and "castle: no automatic decision recorded" in shown.output, shown.output
    clean, gt, name = resolve_dataset("./castle", views=40)
    assert name == "castle" and gt is None
    staged = sorted(clean.iterdir())
    assert [p.name for p in staged] == ["view0.png", "view1.png"]
    for i, path in enumerate(staged):
        expected = np.random.default_rng(i).integers(0, 256, (120, 160, 3), dtype=np.uint8)
        assert np.array_equal(np.asarray(Image.open(path)), expected)  # the originals, not the patched


def _digests(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def test_poison_and_preview_take_a_path_through_dotdot(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`ppd poison ../photos/castle` patches the folder as its absolute path does. Before, every file
    failed ('... is not inside ...': the files kept the '..', the dataset's root did not), the failures
    stayed in the store as extra rows, and `ppd preview ../.../view0.png` took the patched file for an
    original and drew a second mark on it."""
    shoot = _shoot(tmp_path)
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    done = runner.invoke(app, ["poison", "../photos/castle"])
    assert done.exit_code == 0, done.output
    assert "patched 2" in done.output and "failed 0" in done.output
    status = runner.invoke(app, ["status", "castle"])
    assert "files 2: patched 2" in status.output, status.output
    via_dotdot = runner.invoke(
        app, ["preview", "../photos/castle/view0.png", "--no-visibility", "--out", "a.png"]
    )
    direct = runner.invoke(
        app, ["preview", str(shoot / "view0.png"), "--no-visibility", "--out", str(tmp_path / "b.png")]
    )
    assert via_dotdot.exit_code == direct.exit_code == 0, via_dotdot.output + direct.output
    assert np.array_equal(np.asarray(Image.open("a.png")), np.asarray(Image.open(tmp_path / "b.png")))


def test_a_dotdot_after_a_symlink_is_refused(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """link/../view0.png reads the link target's parent; folded it would name another file: refused."""
    shoot = _shoot(tmp_path)
    (shoot / "inner").mkdir()
    monkeypatch.chdir(tmp_path)
    (tmp_path / "link").symlink_to(shoot / "inner")
    before = _digests(shoot)
    done = runner.invoke(app, ["poison", "link/../view0.png"])
    assert done.exit_code == 2 and "follows a symlink" in done.output, done.output
    assert _digests(shoot) == before


def test_an_empty_path_or_name_is_refused(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`ppd poison "$SHOOT"` with SHOOT unset gave Path('') = '.': every photo under the working
    folder patched in place. An empty path, dataset name or target is now a one-line error (2)."""
    shoot = _shoot(tmp_path)
    monkeypatch.chdir(shoot)
    before = _digests(shoot)
    for argv in (["poison", ""], ["poison", ".", "--dataset", ""], ["poison", ".", "--subject-masks", ""],
                 ["poison", ".", "--out", ""], ["preview", ""], ["restore", ""], ["status", ""]):  # fmt: skip
        done = runner.invoke(app, argv)
        assert done.exit_code == 2, (argv, done.output)
        assert "empty" in done.output or "not a plain name" in done.output, (argv, done.output)
    assert _digests(shoot) == before


def test_a_folder_named_tilde_is_that_folder_not_home(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Found in review: folding paths expanded '~' on a path typer had already made, so `./~/photos`
    (a folder literally named ~) read $HOME/photos. The shell expands '~'; ppd does not again."""
    home = tmp_path / "home"
    (home / "photos").mkdir(parents=True)
    make = _shoot(tmp_path / "here" / "~")  # ~/photos/castle, 2 photos, under a folder named "~"
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(tmp_path / "here")
    done = runner.invoke(app, ["poison", "./~/photos/castle", "--dry-run"])
    assert done.exit_code == 0, done.output
    assert "would patch 2" in done.output, done.output
    assert make.is_dir() and not (home / "photos" / "castle").exists()
