"""Subject masks are read in a photo's stored pixels (as COLMAP reads it). On a photo shown turned
whose mask has the same shape either way (EXIF orientation 2-4: upside down, mirrored) a mask drawn
as the photo is shown is silently wrong: a black-box review found the mark on the subject, called
patched. `ppd poison` says, once per mask folder, which photos that concerns."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app

runner = CliRunner()


def _shoot(folder: Path, masks: Path, orientations: list[int]) -> None:
    folder.mkdir()
    masks.mkdir()
    rng = np.random.default_rng(0)
    for i, o in enumerate(orientations):
        pixels = np.full((240, 320, 3), 200, dtype=np.uint8)
        pixels[:100] = rng.integers(0, 256, (100, 320, 3))
        exif = Image.Exif()
        exif[0x0112] = o
        Image.fromarray(pixels).save(folder / f"v{i}.jpg", quality=95, exif=exif.tobytes())
        mask = np.zeros((240, 320), dtype=np.uint8)
        mask[:100] = 255
        Image.fromarray(mask).save(masks / f"v{i}.png")


def test_poison_says_which_masked_photos_are_shown_turned(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    _shoot(tmp_path / "shoot", tmp_path / "masks", [1, 3, 1, 3])
    masks = ["--subject-masks", str(tmp_path / "masks")]
    result = runner.invoke(app, ["poison", str(tmp_path / "shoot"), *masks])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "2 photos shown turned (v1.jpg: EXIF orientation 3, ...): their masks in" in text, text
    assert "stored pixels" in text


def test_no_such_line_when_every_masked_photo_is_upright(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    _shoot(tmp_path / "shoot", tmp_path / "masks", [1, 1, 1])
    masks = ["--subject-masks", str(tmp_path / "masks")]
    result = runner.invoke(app, ["poison", str(tmp_path / "shoot"), *masks])
    assert result.exit_code == 0, result.output
    assert "shown turned" not in result.output


def test_poison_says_when_photos_get_squares_of_few_blocks(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A black-box review: a 200 x 150 photo got squares of 3 x 3 blocks, a 4:1 panorama 5 x 5 (12
    where the mark was measured), and nothing said so. A 640 x 480 photo (9 blocks) is not named."""
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    rng = np.random.default_rng(1)
    for name, size in (("small.png", (200, 150)), ("pano.png", (2000, 500)), ("normal.png", (640, 480))):
        pixels = np.full((size[1], size[0], 3), 200, dtype=np.uint8)
        pixels[size[1] // 2 :] = rng.integers(0, 256, (size[1] - size[1] // 2, size[0], 3))
        Image.fromarray(pixels).save(shoot / name)
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    # the 4:1 panorama's squares are a 2:1 frame's since (poisoner.lengths): 9 blocks, not named
    assert "1 photo got squares of fewer than 8 blocks across (small.png: 3 blocks, 12 px;" in text, text
    assert "pano.png" not in text[text.index("fewer than 8 blocks") :], text


def test_the_small_squares_line_calls_a_clip_a_video(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A black-box review: "5 photos got squares of fewer than 8 blocks" of five videos."""
    from testkit.reliability import make_video

    clips = tmp_path / "clips"
    clips.mkdir()
    make_video(clips / "a.mp4", seed=1)
    result = runner.invoke(app, ["poison", str(clips)])
    text = " ".join(result.output.split())
    assert result.exit_code == 0, result.output
    assert "1 video got squares of fewer than 8 blocks across (a.mp4:" in text, text
    two = tmp_path / "two"  # of two, the one named is the fewest (it read as the only one)
    two.mkdir()
    make_video(two / "a.mp4", seed=1)
    make_video(two / "b.mp4", seed=2)
    text = " ".join(runner.invoke(app, ["poison", str(two)]).output.split())
    assert "2 videos got squares of fewer than 8 blocks across (fewest: " in text, text


def test_a_set_of_clips_is_told_of_videos_not_photos(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """"mark placed per photo, where each photo is plainest" was said of a folder of videos (a second
    black-box review)."""
    from tests.daemon.cli.test_cli_verify_video import walk_around_clip

    clip = walk_around_clip(tmp_path / "clips" / "walk.mp4", tmp_path / "frames", views=6)
    result = runner.invoke(app, ["poison", str(clip.parent)])
    said = " ".join(result.output.split())
    assert result.exit_code == 0 and "mark placed per video" in said and "per photo" not in said, said
