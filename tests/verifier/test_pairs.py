"""The SfM check stages what an attacker's COLMAP reads: a JPEG named .jfif or with no suffix, which ppd
patches (COLMAP reads an image by its content), was left out of the verification's folders; a HEIC or
AVIF, which no COLMAP reads (an attacker converts it first), was left out too, and a set of iPhone
photos had nothing to verify (a seventh black-box review, F2)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pillow_heif
from PIL import Image

from testkit.photos import make_image
from verifier.pairs import stage_pairs


def _pair(folder: Path, name: str, seed: int, fmt: str) -> tuple[Path, Path]:
    pair = []
    for side in ("orig", "prot"):  # two pictures: which side is staged where shows
        src = make_image(folder / side / f"src{seed}.png", seed + 100 * (side == "prot"), size=(64, 48))
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


def test_heic_and_avif_are_staged_as_pngs_of_their_decoded_pixels(tmp_path: Path) -> None:
    """pycolmap 4.2.1 reads neither (Bitmap.read gives None): both sides become lossless PNGs of what
    the decoder gives, as an attacker's converter makes them, and are measured."""
    pillow_heif.register_heif_opener()
    pairs = [_pair(tmp_path, "IMG_0001.HEIC", 1, "HEIF"), _pair(tmp_path, "c.avif", 2, "AVIF"),
             _pair(tmp_path, "a.jpg", 3, "JPEG")]  # fmt: skip
    staged = stage_pairs(pairs, tmp_path / "clean", tmp_path / "poisoned")
    assert staged.left_out == {}
    staged_names = sorted(p.name for p in (tmp_path / "poisoned").iterdir())
    assert staged_names == ["IMG_0001.HEIC.png", "a.jpg", "c.avif.png"]
    for (original, protected), name in zip(pairs, ("IMG_0001.HEIC.png", "c.avif.png"), strict=False):
        for src, side in ((original, "clean"), (protected, "poisoned")):
            with Image.open(tmp_path / side / name) as png, Image.open(src) as decoded:
                assert png.format == "PNG"
                assert np.array_equal(np.asarray(png), np.asarray(decoded.convert(png.mode)))


def test_a_photo_that_no_longer_decodes_is_left_out_and_said(tmp_path: Path) -> None:
    pillow_heif.register_heif_opener()
    pairs = [_pair(tmp_path, f"IMG_{i}.HEIC", i, "HEIF") for i in range(3)]
    pairs[1][1].write_bytes(pairs[1][1].read_bytes()[:400])  # cut short since it was patched
    staged = stage_pairs(pairs, tmp_path / "clean", tmp_path / "poisoned")
    assert staged.left_out == {"IMG_1.HEIC": "IMG_1.HEIC: not a recognised image file"}
    for side in ("clean", "poisoned"):  # neither side of it: the two folders hold the same names
        assert sorted(p.name for p in (tmp_path / side).iterdir()) == ["IMG_0.HEIC.png", "IMG_2.HEIC.png"]


def test_a_video_s_frames_measured_are_said(tmp_path: Path) -> None:
    """A video's verdict rests on the frames sampled (about two a second), and nothing said so: a review
    found a clip "protected" on 8 frames 6 apart whose 12 first consecutive frames were only "weak"."""
    from testkit.video import Clip, make_clip
    from verifier.verification import VerificationReport

    (tmp_path / "orig").mkdir()
    clip = tmp_path / "orig" / "orbit.mp4"
    make_clip(clip, Clip(width=96, height=64, frames=30, fps=12, audio=None))
    staged = stage_pairs([(clip, clip)], tmp_path / "clean", tmp_path / "poisoned")
    assert staged.matching == "sequential"
    assert staged.video_frames == (
        "orbit.mp4: 5 frames measured, every 6th frame from frame 0 to 24; an attacker may take others "
        "(closer together or more of them): not measured",
    ), staged.video_frames
    assert len(list((tmp_path / "poisoned").iterdir())) == 5
    report = VerificationReport("c", "p", "o", 5, {}, video_frames=list(staged.video_frames))
    assert staged.video_frames[0] in report.summary_lines()
    photos = stage_pairs([_pair(tmp_path, "a.jpg", 1, "JPEG")], tmp_path / "c2", tmp_path / "p2")
    assert photos.video_frames == ()
