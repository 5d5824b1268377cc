"""The SfM check stages what an attacker's COLMAP reads: a JPEG named .jfif or with no suffix, which ppd
patches (COLMAP reads an image by its content), was left out of the verification's folders."""

from __future__ import annotations

from pathlib import Path

from PIL import Image

from testkit.photos import make_image
from verifier.pairs import stage_pairs


def _pair(folder: Path, name: str, seed: int, fmt: str) -> tuple[Path, Path]:
    pair = []
    for side in ("orig", "prot"):
        src = make_image(folder / side / f"src{seed}.png", seed, size=(64, 48))
        Image.open(src).save(folder / side / name, fmt)
        src.unlink()
        pair.append(folder / side / name)
    return pair[0], pair[1]


def test_photos_under_other_names_are_staged_as_colmap_reads_them(tmp_path: Path) -> None:
    pairs = [_pair(tmp_path, "a.jpg", 1, "JPEG"), _pair(tmp_path, "b.jfif", 2, "JPEG"),
             _pair(tmp_path, "IMG_3", 3, "PNG"), _pair(tmp_path, "loop", 4, "GIF")]  # fmt: skip
    stage_pairs(pairs, tmp_path / "clean", tmp_path / "poisoned")
    staged = sorted(p.name for p in (tmp_path / "poisoned").iterdir())
    assert staged == ["IMG_3.png", "a.jpg", "b.jfif.jpg"]  # the GIF, which ppd does not patch, is not
    assert sorted(p.name for p in (tmp_path / "clean").iterdir()) == staged
    assert (tmp_path / "poisoned" / "b.jfif.jpg").read_bytes() == pairs[1][1].read_bytes()
