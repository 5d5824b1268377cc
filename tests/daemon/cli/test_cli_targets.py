"""`ppd verify X` / `ppd report X`: X as a dataset or as the folder `ppd poison` patched, and
which one was taken when a name and a folder both match. Real store, real files, no COLMAP."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.cli.targets import TargetError, dataset_for_folder, resolve_target
from daemon.protect.one_file import AppContext

runner = CliRunner()


def make_image(path: Path, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)).save(path)
    return path


@pytest.fixture
def shoot(ppd_env: dict[str, Path], tmp_path: Path) -> Path:
    folder = tmp_path / "photos" / "castle"
    for i in range(2):
        make_image(folder / f"view{i}.png", i)
    return folder


def test_a_patched_folder_is_its_dataset(shoot: Path, tmp_path: Path) -> None:
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    other = tmp_path / "photos" / "tower"
    make_image(other / "a.png", 3)
    assert runner.invoke(app, ["poison", str(other), "--out", str(tmp_path / "pub")]).exit_code == 0
    ctx = AppContext.open()
    try:
        assert dataset_for_folder(ctx.store, shoot) == "castle"
        assert dataset_for_folder(ctx.store, tmp_path / "pub" / "tower") == "tower"
        plain = tmp_path / "plain"
        plain.mkdir()
        assert dataset_for_folder(ctx.store, plain) is None
        assert resolve_target(ctx.store, str(shoot)).dataset == "castle"
        assert resolve_target(ctx.store, None, folder=plain).dataset is None
        assert resolve_target(ctx.store, None, dataset="tower").dataset == "tower"
        with pytest.raises(TargetError, match="no dataset 'nope'"):
            resolve_target(ctx.store, "nope")
        with pytest.raises(TargetError, match="give one of"):
            resolve_target(ctx.store, "castle", dataset="castle")
    finally:
        ctx.close()


def test_a_name_that_is_also_a_folder_here_says_which(
    shoot: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    here = tmp_path / "elsewhere"
    (here / "castle").mkdir(parents=True)  # a folder named like the dataset, not the dataset's
    monkeypatch.chdir(here)
    ctx = AppContext.open()
    try:
        chosen = resolve_target(ctx.store, "castle")
    finally:
        ctx.close()
    assert chosen.dataset == "castle" and chosen.folder is None
    assert "took the dataset" in (chosen.note or "") and "--folder castle" in (chosen.note or "")
    shown = runner.invoke(app, ["verify", "castle", "--profile", "default"])
    assert "took the dataset" in shown.output
    assert "needs at least 3" in shown.output  # it went on with the dataset (2 files), not the folder


def test_verify_and_report_accept_the_patched_folder(shoot: Path, tmp_path: Path) -> None:
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    verify = runner.invoke(app, ["verify", str(shoot), "--profile", "default"])
    assert verify.exit_code == 2 and "dataset 'castle' has 2" in verify.output  # the dataset was taken
    plain = tmp_path / "plain"
    make_image(plain / "a.png", 1)
    refused = runner.invoke(app, ["verify", str(plain)])
    assert refused.exit_code == 2 and "--clean" in refused.output
    report = runner.invoke(app, ["report", str(shoot), "--out", str(tmp_path / "r.html")])
    assert report.exit_code == 0, report.output
    assert "dataset 'castle'" in report.output and (tmp_path / "r.html").is_file()
    explicit = runner.invoke(app, ["report", "--dataset", "castle", "--out", str(tmp_path / "e.html")])
    assert explicit.exit_code == 0, explicit.output


def test_the_originals_of_a_dataset_patched_with_out_are_that_datasets(ppd_env: dict[str, Path],
                                                                     tmp_path: Path) -> None:  # fmt: skip
    """`ppd poison shoot --dataset crop --subject-masks masks --out pub`: the dataset's root is shoot,
    its rows the copies. A black-box review: `ppd preview shoot/x.png` took shoot for a new dataset
    and drew the mark on the subject its remembered masks keep it off."""
    from testkit.photos import masked_shoot

    images, masks = tmp_path / "shoot", tmp_path / "masks"
    masked_shoot(images, masks, n=3)
    pub = str(tmp_path / "pub")
    args = ["poison", str(images), "--dataset", "crop", "--subject-masks", str(masks), "--out", pub]
    assert runner.invoke(app, args).exit_code == 0
    result = runner.invoke(app, ["preview", str(images / "000001.png"), "--out", str(tmp_path / "p.png")])
    assert result.exit_code == 0, result.output
    assert "from the subject mask" in " ".join(result.output.split()), result.output
    again = runner.invoke(app, ["poison", str(images), "--out", pub])  # no name: the same dataset
    assert again.exit_code == 0 and "crop" in again.output and "shoot:" not in again.output, again.output


def test_a_folder_holding_several_datasets_names_them(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd restore ~/shoots`, the parent of datasets a and b, said "~/shoots is dataset 'a'" and
    restored a alone, exit 0 (a diff review): the folder holds both, and the command says so."""
    import hashlib

    from testkit.photos import make_shoot

    shoots = tmp_path / "shoots"
    for name in ("a", "b"):
        make_shoot(shoots / name, 2)
        assert runner.invoke(app, ["poison", str(shoots / name)]).exit_code == 0
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in shoots.rglob("*.png")}
    result = runner.invoke(app, ["restore", str(shoots)])
    said = " ".join(result.output.split())
    assert result.exit_code == 2 and "several datasets (a, b)" in said, said
    assert {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in shoots.rglob("*.png")} == before


def test_a_name_typed_in_another_unicode_form_finds_its_dataset(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A folder copied from a Mac names its dataset in NFD ("e" and a combining accent); `ppd status
    Café` typed in NFC found no dataset (a third black-box review)."""
    from testkit.photos import make_image

    nfd, nfc = "Cafe\u0301", "Caf\u00e9"
    make_image(tmp_path / nfd / "v0.png", 0)
    assert runner.invoke(app, ["poison", str(tmp_path / nfd)]).exit_code == 0
    monkeypatch.chdir(tmp_path.parent)  # no folder of either name here
    for args in (["status", nfc], ["status", "--json", nfc]):
        result = runner.invoke(app, args)
        assert result.exit_code == 0 and "no dataset" not in result.output, (args, result.output)


def test_restore_of_a_file_ppd_never_patched_is_bad_input_as_an_unknown_name_is(shoot: Path) -> None:
    """`ppd restore FILE` of a file ppd never saw said "restored 0, ..., failed 1", exit 1, as if ppd had
    failed on one of its own (a black-box review, F11); an unknown name is one line, exit 2: now both."""
    never = make_image(shoot.parent / "never.png", 7)
    before = never.read_bytes()
    for target, said in ((str(never), f"{never}: not a file ppd patched"), ("nosuch", "no dataset 'nosuch'")):
        result = runner.invoke(app, ["restore", target])
        lines = result.output.splitlines()
        assert result.exit_code == 2 and len(lines) == 1, result.output
        assert lines[0].startswith(f"ppd: error: {said}"), lines
    assert never.read_bytes() == before
