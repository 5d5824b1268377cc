"""A patched photo saved again by another program, through the CLI (a black-box review, 2026-12-07).

F1: saved again with its seal gone (a PNG re-saved): marked a second time, and restore handed back the
once-marked picture; a crop's restore gave back a marked picture as "restored", saying nothing.
F2: a metadata-only edit (exiftool writing a rating and keywords; the seal's token kept) is recognised
as ppd's output, pixels unchanged; `ppd restore` then wrote the original over the rated file and kept
no copy. Its bytes are the creator's: restore refuses without --force, and --force keeps them in
DATA/displaced/DATASET/."""

from __future__ import annotations

import hashlib
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.protect.displaced import SAVED_OVER
from testkit.photos import rate_in_place, textured

runner = CliRunner()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _kept(data: Path) -> list[Path]:
    return sorted(p for p in (data / "displaced").rglob("*") if p.is_file())


def _said(result: object) -> str:
    return " ".join(getattr(result, "output", "").split())


def _shoot(folder: Path, suffix: str, n: int = 3) -> dict[str, str]:
    """n smooth textured photos (a re-encode keeps them close, as it does a camera's): name -> sha256."""
    folder.mkdir(parents=True)
    for i in range(n):
        Image.fromarray(textured(240, 320, seed=i)).save(folder / f"v{i}{suffix}", quality=95)
    return {p.name: _sha(p) for p in folder.iterdir()}


def test_a_rated_photo_is_not_written_over_by_restore(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot = tmp_path / "rate"
    originals = _shoot(shoot, ".jpg")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    photo = shoot / "v1.jpg"
    rate_in_place(photo)
    rated = photo.read_bytes()
    again = runner.invoke(app, ["-v", "poison", str(shoot)])
    assert again.exit_code == 0 and "its pixels unchanged" in _said(again), again.output
    assert photo.read_bytes() == rated  # no second mark
    refused = runner.invoke(app, ["restore", str(shoot)])
    text = _said(refused)
    assert refused.exit_code == 1 and "v1.jpg is ppd's patched photo saved again since" in text, text
    assert "--force keeps your version in" in text and photo.read_bytes() == rated, text
    assert not _kept(ppd_env["data"])
    assert _sha(shoot / "v0.jpg") == originals["v0.jpg"]  # the others restored
    forced = runner.invoke(app, ["restore", str(photo), "--force"])
    text = _said(forced)
    assert forced.exit_code == 0 and _sha(photo) == originals["v1.jpg"], text
    (kept,) = _kept(ppd_env["data"])
    assert kept.read_bytes() == rated and f"kept your version of v1.jpg at {kept}" in text, text


def test_a_png_resaved_with_its_seal_gone_is_not_marked_twice(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """F1, as the review ran it: the PNG saved again by Pillow (the same pixels, the seal chunk gone)
    was patched a second time; restore said "restored" and gave back the once-marked picture."""
    shoot = tmp_path / "edit"
    originals = _shoot(shoot, ".png")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    photo = shoot / "v0.png"
    with Image.open(photo) as im:
        im.save(photo)
    resaved = photo.read_bytes()
    again = runner.invoke(app, ["-v", "poison", str(shoot)])
    text = _said(again)
    assert again.exit_code == 0 and "patched 0, unchanged 3" in text, text
    assert f"unchanged {photo} (already ppd output (saved again by another program" in text, text
    assert photo.read_bytes() == resaved
    refused = runner.invoke(app, ["restore", str(shoot)])
    assert refused.exit_code == 1 and "v0.png is ppd's patched photo saved again since" in _said(refused)
    forced = runner.invoke(app, ["restore", str(photo), "--force"])
    assert forced.exit_code == 0 and _sha(photo) == originals["v0.png"], forced.output  # the clean original
    (kept,) = _kept(ppd_env["data"])
    assert kept.read_bytes() == resaved


def test_restore_of_a_cropped_patched_photo_says_its_original_carries_the_mark(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A crop of a patched photo is a new photo to protect; its restore gives back the crop, which
    carries ppd's mark: said without -v, with where the photo from before the crop is."""
    shoot = tmp_path / "crop"
    originals = _shoot(shoot, ".jpg")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    photo = shoot / "v2.jpg"
    with Image.open(photo) as im:
        im.crop((0, 0, 300, 220)).save(photo, quality=92)
    cropped = photo.read_bytes()
    assert runner.invoke(app, ["poison", str(shoot)]).output.count("patched 1") == 1
    restored = runner.invoke(app, ["restore", str(shoot)])
    text = _said(restored)
    assert restored.exit_code == 0 and photo.read_bytes() == cropped, text
    assert f"restored {photo}: its original is the file saved over ppd's patched photo" in text, text
    (vault_copy,) = (Path(w) for w in text.split() if w.startswith(str(ppd_env["data"])))
    assert _sha(vault_copy) == originals["v2.jpg"]
    # a rebuilt store keeps that note (its row is found again by the seal): it was dropped (a diff review)
    assert runner.invoke(app, ["poison", "--force", str(photo)]).exit_code == 0
    assert runner.invoke(app, ["store", "rebuild", "--force", str(shoot)]).exit_code == 0
    again = _said(runner.invoke(app, ["restore", str(photo)]))
    assert f"{SAVED_OVER}" in again and str(vault_copy) in again, again
    # forgetting the shoot would remove that only unmarked copy: refused until copied out, or --force
    refused = runner.invoke(app, ["dataset", "forget", "crop"])
    text = _said(refused)
    assert refused.exit_code == 2 and vault_copy.is_file(), text
    assert f"the photo from before each is only in the vault ({vault_copy})" in text, text
    forced = runner.invoke(app, ["dataset", "forget", "crop", "--force"])
    assert forced.exit_code == 0 and not vault_copy.exists(), forced.output


def test_a_rated_photo_renamed_is_still_not_written_over(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The row that follows a renamed file carries its 'saved again' note: it was dropped, and restore
    of the renamed rated photo wrote the original over the creator's bytes (found merging F1/F2)."""
    shoot = tmp_path / "rate"
    _shoot(shoot, ".jpg")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    rate_in_place(shoot / "v1.jpg")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0  # recognised: its bytes are yours
    renamed = (shoot / "v1.jpg").rename(shoot / "best.jpg")
    rated = renamed.read_bytes()
    moved = runner.invoke(app, ["-v", "poison", str(shoot)])
    assert moved.exit_code == 0 and "moved from" in _said(moved), moved.output
    refused = runner.invoke(app, ["restore", str(renamed)])
    assert refused.exit_code == 1 and "best.jpg is ppd's patched photo saved again since" in _said(refused)
    assert renamed.read_bytes() == rated


def test_reprotect_leaves_a_rated_photo_as_it_is(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A review (F3): `ppd dataset set NAME --reprotect` re-marked a rated photo from its vault original,
    the rating gone, kept nowhere. Now it is left as it is, one line says why, status names it."""
    shoot = tmp_path / "rate"
    _shoot(shoot, ".jpg")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    photo = shoot / "v1.jpg"
    rate_in_place(photo)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0  # recognised: its bytes are yours
    rated = photo.read_bytes()
    result = runner.invoke(app, ["dataset", "set", "rate", "--design", "paper", "--reprotect"])
    text = _said(result)
    assert "failed 1, patched 2" in text and photo.read_bytes() == rated, text  # before: re-marked
    assert f"ppd: failed: {photo}: v1.jpg was saved again by another program since ppd patched it" in text
    assert not _kept(ppd_env["data"])  # nothing displaced: nothing written
    status = _said(runner.invoke(app, ["status", "rate", "--failed"]))
    assert "v1.jpg" in status and "not re-marked" in status, status
