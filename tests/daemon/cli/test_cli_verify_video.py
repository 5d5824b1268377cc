"""`ppd verify` of a dataset of one video (a second black-box review): refused with "1 patched
file(s); SfM needs at least 3", though the verifier samples the clip's frames (verifier.pairs). A
walk-around clip is the commonest video capture. And a dataset whose folder is gone says so, not
"pair missing"."""

from __future__ import annotations

import shutil
from pathlib import Path

import av
import numpy as np
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.video import mux_rgb_frames
from verifier.synthetic import SyntheticOptions, render_scene

runner = CliRunner()


def walk_around_clip(path: Path, tmp: Path, views: int = 12) -> Path:
    render_scene(tmp, SyntheticOptions(num_views=views, width=320, height=240, backdrop="plain"))
    frames = [np.asarray(Image.open(p).convert("RGB")) for p in sorted(tmp.glob("*.png"))]
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=4)
        stream.width, stream.height, stream.pix_fmt = 320, 240, "yuv420p"
        mux_rgb_frames(out, stream, frames)
    return path


def test_one_clip_is_enough_views_to_verify(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    clip = walk_around_clip(tmp_path / "clips" / "walk.mp4", tmp_path / "frames")
    assert runner.invoke(app, ["poison", str(clip.parent)]).exit_code == 0
    result = runner.invoke(app, ["verify", "clips", "--profile", "default"])
    said = " ".join(result.output.split())
    assert result.exit_code in (0, 1) and "needs at least 3" not in said, said  # a verdict, not refused
    assert "default" in said


def test_a_dataset_whose_folder_is_gone_says_so(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot = tmp_path / "shoot"
    render_scene(shoot, SyntheticOptions(num_views=3, width=96, height=96))
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    shutil.rmtree(shoot)
    result = runner.invoke(app, ["verify", "shoot", "--profile", "default"])
    said = " ".join(result.output.split())
    assert result.exit_code == 2 and "its folder" in said and "is gone" in said, said
    assert "pair missing" not in said
