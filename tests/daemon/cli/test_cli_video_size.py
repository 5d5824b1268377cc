"""A patched video can be much larger than its source (a second black-box review, N14: a 720p clip grew
1.85x, unsaid; a creator with an upload limit finds out at the upload). `ppd poison` says it once per
run, with the files' sizes, and `ppd -v poison` gives each video's size."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from testkit.video import Clip, make_clip

runner = CliRunner()
NOTICEABLE = 1.10  # poisoner.video.model.NOTICEABLE: said in the summary from this ratio on


def size_text(n: int) -> str:
    """As ppd writes a size under 1 MB (powers of 1000, as upload limits are)."""
    assert n < 1_000_000
    return f"{n / 1000:.0f} KB"


def test_poison_says_once_how_much_its_videos_grew(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    clips = [make_clip(shoot / name, Clip(frames=30, audio=None)) for name in ("a.mp4", "b.mp4")]
    before = [p.stat().st_size for p in clips]
    result = runner.invoke(app, ["-v", "poison", str(shoot)])
    assert result.exit_code == 0, result.output
    after = [p.stat().st_size for p in clips]  # the patched files, in place
    ratios = [a / b for a, b in zip(after, before, strict=True)]
    assert min(ratios) >= NOTICEABLE, ratios  # the mark on this texture costs bits
    text = " ".join(result.output.split())
    order = sorted(zip(ratios, ("a.mp4", "b.mp4"), strict=True), key=lambda g: (-g[0], g[1]))
    line = (f"videos grew up to {order[0][0]:.2f}x in size (the mark costs bits): 2 video(s), "
            f"{size_text(sum(before))} -> {size_text(sum(after))} "
            f"({order[0][1]} {order[0][0]:.2f}x, {order[1][1]} {order[1][0]:.2f}x); "
            "`ppd -v poison` gives each file's size")  # fmt: skip
    assert line in text and text.count("videos grew") == 1, text
    for b, a, r in zip(before, after, ratios, strict=True):
        assert f"note: size {size_text(b)} -> {size_text(a)} ({r:.2f}x; the mark costs bits)" in text


def test_no_size_line_where_no_video_grew_noticeably(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """Re-encoding alone moves a size a few percent either way: not a line in the summary, only -v's."""
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    clip = make_clip(shoot / "hi.mp4", Clip(frames=30, audio=None, options=(("crf", "8"),)))  # many bits
    before = clip.stat().st_size
    result = runner.invoke(app, ["-v", "poison", str(shoot)])
    ratio = clip.stat().st_size / before
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and ratio < NOTICEABLE, (ratio, text)
    assert "videos grew" not in text and f"note: size {size_text(before)} -> " in text
