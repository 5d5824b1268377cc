"""The mark's size on pictures far from the measured ones.

A panorama's mark: fractions of the width are of a 2:1 frame's width of the same height (a black-box
review: a 12000x1500 photo got blocks of 30 px and squares one block across, two flat black squares
with no texture, called patched). Every frame up to 2:1 resolves exactly as before.

A picture whose squares would be one flat block fails, in the dry run too (a black-box review: a 64x64
photo got one flat block, 1x200 was "would patch" in the dry run and failed with a numpy error)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from poisoner.ladder import default_spec
from poisoner.lengths import length_base
from poisoner.spec import PatchSpec
from testkit.photos import changed_pixels, textured

runner = CliRunner()


def test_frames_up_to_two_to_one_keep_their_blocks_and_squares() -> None:
    spec = default_spec()
    # (width, height): (block, lane side) as ppd resolved them before panoramas had their own base
    before = {(800, 800): (4, 48), (1600, 1200): (4, 96), (1920, 1080): (5, 84), (6000, 4000): (15, 320),
              (4000, 2000): (10, 152)}  # fmt: skip
    for (w, h), (block, side) in before.items():
        assert length_base(w, h) == w
        p = spec.resolve(w, h, "a.jpg")
        assert (p.block, p.lane_size) == (block, side), (w, h)


def test_a_panorama_gets_squares_of_real_texture() -> None:
    spec = default_spec()
    for w, h in ((12000, 1500), (3000, 500), (4000, 1000)):
        p = spec.resolve(w, h, "a.jpg")
        assert p.lane_size // p.block >= 8, (w, h, p.block, p.lane_size)


def test_poison_of_a_panorama_writes_a_textured_mark(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot = tmp_path / "pano"
    shoot.mkdir()
    photo = shoot / "p.png"
    busy, plain = textured(1500, 6000, seed=1), np.full((1500, 6000, 3), 128, np.uint8)
    Image.fromarray(np.hstack([busy, plain])).save(photo)
    original = photo.read_bytes()
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    assert "fewer than 8 blocks" not in result.output
    changed = changed_pixels(original, photo)
    ys, xs = np.nonzero(changed)
    box = np.asarray(Image.open(photo).convert("L"))[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
    assert len(np.unique(box[changed[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]])) >= 2  # not flat
    assert ys.max() - ys.min() < 400  # squares of a 3000 px frame's, not 30 px blocks of 12000's


def test_too_small_names_pictures_whose_squares_would_be_one_flat_block() -> None:
    spec = default_spec()
    for w, h in ((16, 16), (64, 48), (64, 64), (300, 2), (1, 200)):
        assert (why := spec.too_small(w, h)) is not None and why.startswith(f"{w}x{h} "), (w, h)
        assert "too small for the mark" in why or "cannot hold the mark" in why, why
    for w, h in ((96, 96), (160, 120), (200, 150), (800, 800), (12000, 1500)):
        assert spec.too_small(w, h) is None, (w, h)


def test_a_picture_too_small_fails_in_the_dry_run_and_the_run(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "small"
    shoot.mkdir()
    for name, size in (("ok.png", (200, 150)), ("thumb.png", (64, 64)), ("line.png", (1, 200))):
        Image.fromarray(textured(size[1], size[0], seed=2)).save(shoot / name)
    before = {p.name: p.read_bytes() for p in shoot.iterdir()}
    for args in (["--dry-run"], []):
        result = runner.invoke(app, ["poison", str(shoot), *args])
        text = " ".join(result.output.split())
        assert result.exit_code == 1 and "failed 2" in text, text
        assert "thumb.png: 64x64 is too small for the mark" in text, text
        assert "line.png: 1x200 cannot hold the mark" in text, text
        assert "Warning" not in text and "numerical gradient" not in text
    assert (shoot / "thumb.png").read_bytes() == before["thumb.png"]
    assert (shoot / "ok.png").read_bytes() != before["ok.png"]


def test_the_size_check_reads_the_picture_as_shown(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The diff review: the check read the stored size while the mark is placed on the picture as shown,
    so three 1000x500 JPEGs with EXIF orientation 6 (shown 500x1000) failed under `--design watermark`,
    which c8c7375 patched."""
    shoot = tmp_path / "turned"
    shoot.mkdir()
    for i in range(3):
        exif = Image.Exif()
        exif[0x0112] = 6
        Image.fromarray(textured(500, 1000, seed=i)).save(shoot / f"IMG_{i}.jpg", exif=exif, quality=92)
    result = runner.invoke(app, ["poison", str(shoot), "--design", "watermark"])
    assert result.exit_code == 0 and "patched 3," in " ".join(result.output.split()), result.output


def test_a_mark_that_does_not_fit_says_why_in_the_specs_own_words() -> None:
    spec = PatchSpec(patch_size=0.3, motion="tumble", position="top-left")
    why = spec.too_small(2000, 1000)
    assert why is not None and why.startswith("2000x1000 cannot hold the mark: ") and "corner region" in why


def test_a_video_whose_frames_are_too_small_fails_as_a_photo_does(tmp_path: Path) -> None:
    """The diff review: the check read only photos' headers, so a 64x48 clip still got flat squares."""
    from poisoner.video.driver import poison_video
    from poisoner.video.errors import VideoFormatError
    from testkit.video import Clip, make_clip

    clip = make_clip(tmp_path / "tiny.mp4", Clip(width=64, height=48, frames=4, audio=None))
    with pytest.raises(VideoFormatError, match="64x48 is too small for the mark"):
        poison_video(clip, tmp_path / "out.mp4", default_spec())


def test_the_header_check_gives_the_size_as_shown_without_decoding(tmp_path: Path) -> None:
    """check_writable_image reads the orientation from the header: a JPEG's APP1, a PNG's eXIf chunk
    (Pillow's own PNG getexif() would decode the whole picture)."""
    from poisoner.image.read import check_writable_image

    exif = Image.Exif()
    exif[0x0112] = 6
    for name in ("turned.jpg", "turned.png"):
        Image.fromarray(textured(50, 80, seed=1)).save(tmp_path / name, exif=exif)
        assert check_writable_image(tmp_path / name, name) == (50, 80), name
    Image.fromarray(textured(50, 80, seed=1)).save(tmp_path / "upright.png")
    assert check_writable_image(tmp_path / "upright.png", "upright.png") == (80, 50)
