"""`ppd preview` of a video (found by a black-box review, 2026-12-07): a patched clip could not be
previewed at all (its vault original, named by its hash, was read as a photo), and an unpatched one
showed the default mark where `ppd poison` does not write it (the spec's preferred place, where the
clip's own keyframes decide it)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import av
import numpy as np
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from poisoner.ladder import default_spec
from poisoner.preview import GAP, LABEL_HEIGHT
from poisoner.video.driver import frame_placements
from poisoner.video.model import VideoOptions
from poisoner.video.source import probe
from testkit.video import Clip, make_clip, mux_rgb_frames

runner = CliRunner()


def plain_band_clip(path: Path, w: int = 320, h: int = 240) -> Path:
    """A still scene textured everywhere but a band along the right edge: the per-photo mark goes
    there, far from its preferred place across the top."""
    rng = np.random.default_rng(5)
    still = np.full((h, w, 3), 128, np.uint8)
    texture = (rng.random((h // 4, w // 4, 3)) * 200 + 28).astype(np.uint8).repeat(4, 0).repeat(4, 1)
    still[:, : int(w * 0.75)] = texture[:, : int(w * 0.75)]
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=12)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        mux_rgb_frames(out, stream, [still] * 12)
    return path


def said_box(output: str) -> tuple[int, int, int, int]:
    """The pixels (x0,y0)-(x1,y1) of the preview's mark line."""
    text = " ".join(output.split())
    start = text.index("pixels (") + len("pixels (")
    first, second = text[start:].split(")", 1)[0], text[start:].split("-(", 1)[1].split(")", 1)[0]
    x0, y0 = map(int, first.split(","))
    x1, y1 = map(int, second.split(","))
    return (x0, y0, x1, y1)


def test_preview_of_a_clip_shows_where_poison_writes_and_works_once_it_is_patched(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    clip = plain_band_clip(tmp_path / "shoot" / "clip.mp4")
    written = frame_placements(default_spec(), probe(clip), VideoOptions(), clip)(0).box
    assert written != default_spec().resolve(320, 240, index=0.0).box  # not the preferred place
    before = runner.invoke(app, ["preview", str(clip), "--out", str(tmp_path / "p1.png"), "--no-visibility"])
    assert before.exit_code == 0, before.output
    assert said_box(before.output) == written and "of the first frame" in " ".join(before.output.split())
    assert runner.invoke(app, ["poison", str(clip.parent)]).exit_code == 0
    after = runner.invoke(app, ["preview", str(clip), "--out", str(tmp_path / "p2.png"), "--no-visibility"])
    assert after.exit_code == 0, after.output  # was: "cannot read <hash>: not a recognised image file"
    assert said_box(after.output) == written and (tmp_path / "p2.png").stat().st_size > 0
    assert not list(Path(tempfile.gettempdir()).glob("ppd-preview-*"))  # its scratch folder is gone


def test_a_patched_clips_preview_says_the_codec_changed_most_pixels(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """"65.57% of pixels changed, not confined to a corner" of a patched clip read as two thirds of the
    frame altered (a second black-box review): the frame was re-encoded, the mark is under 1%."""
    clip = plain_band_clip(tmp_path / "shoot" / "clip.mp4")
    planned = runner.invoke(app, ["preview", str(clip), "--out", str(tmp_path / "p1.png")])
    assert planned.exit_code == 0 and "codec's" not in planned.output, planned.output  # marked, not coded
    assert runner.invoke(app, ["poison", str(clip.parent)]).exit_code == 0
    after = runner.invoke(app, ["preview", str(clip), "--out", str(tmp_path / "p2.png")])
    said = " ".join(after.output.split())
    assert after.exit_code == 0 and "most changed pixels are the codec's" in said, said


def test_a_phone_clips_preview_is_drawn_as_players_show_it(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A clip stored landscape with a -90 rotation (a phone held upright; players turn it 90 degrees
    clockwise) was previewed sideways, "as stored" (a second black-box review, N11): the preview now
    draws it as players do, as a photo's EXIF orientation is, and says both places of the mark."""
    (tmp_path / "shoot").mkdir()
    clip = make_clip(tmp_path / "shoot" / "phone.mp4", Clip(rotation=-90, frames=12, audio=None))
    with av.open(str(clip)) as container:
        stored = next(iter(container.decode(video=0))).to_ndarray(format="rgb24")
    shown = np.rot90(stored, k=-1)  # what a player shows: 240 wide, 320 high
    x0, y0, x1, y1 = frame_placements(default_spec(), probe(clip), VideoOptions(), clip)(0).box
    turned = (240 - y1, x0, 240 - y0, x1)  # the stored box, turned 90 degrees clockwise
    out = tmp_path / "p.png"
    result = runner.invoke(app, ["preview", str(clip), "--out", str(out), "--no-visibility"])
    said = " ".join(result.output.split())
    assert result.exit_code == 0 and "as players show it" in said, said
    assert said_box(result.output) == turned and f"writes it at ({x0},{y0})-({x1},{y1}) of the stored" in said
    picture = np.asarray(Image.open(out).convert("RGB"))
    assert picture.shape[1] == 2 * 240 + GAP  # two portrait panels side by side
    panel = picture[LABEL_HEIGHT : LABEL_HEIGHT + 320, :240].astype(int)
    away = np.ones((320, 240), bool)  # the outline drawn around the mark's box is the preview's own
    away[max(0, turned[1] - 3) : turned[3] + 3, max(0, turned[0] - 3) : turned[2] + 3] = False
    assert np.abs(panel - shown)[away].max() == 0


def test_an_unreadable_clips_preview_says_why_in_one_line(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """It printed libav's errno and the path ("[Errno 1094995529] Invalid data found ..."), where `ppd
    poison` says of the same file that it is incomplete (black-box review 9, F10)."""
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    whole = make_clip(tmp_path / "whole.mp4", Clip(audio=None, frames=12)).read_bytes()
    truncated = shoot / "trunc.mp4"
    truncated.write_bytes(whole[: len(whole) // 2])
    noise = shoot / "noise.mp4"
    noise.write_bytes(np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    said = []
    out = ["--no-visibility", "--out", str(tmp_path / "p.png")]
    for clip in (truncated, noise):
        result = runner.invoke(app, ["preview", str(clip), *out])
        assert result.exit_code == 2, result.output
        text = " ".join(result.output.split())
        assert "Errno" not in text and str(tmp_path) not in text
        assert text.startswith(f"ppd: error: cannot read {clip.name}: ")
        said.append(text)
    assert "trunc.mp4: it is incomplete ('mdat' box at byte" in said[0]
    assert "noise.mp4: not a readable video (Invalid data found when processing input)" in said[1]
