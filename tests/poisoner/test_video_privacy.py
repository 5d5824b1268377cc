"""poison_video: location tags left out by default (issue 15), the provenance seal (issues 20, 29)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import av
import numpy as np
import pytest

from poisoner.provenance import Marker, Seal, read_seal, seal_file
from poisoner.spec import PatchSpec
from poisoner.video import VideoOptions, poison_video
from testkit.video import mux_rgb_frames

SPEC = PatchSpec(patch_size=16, block_size=4, position="top-left", offset=(4, 4))
FAST = VideoOptions(verify_patch=False, preset="ultrafast", threads=1)
ISO6709 = "+48.8566+002.3522/"
KEY = bytes(range(32))
MARKER = Marker.placeholder(KEY, "spec-7f3a", "ab" * 32)


def clip(path: Path, tags: dict[str, str], frames: int = 6) -> Path:
    encoder = "libvpx-vp9" if path.suffix == ".webm" else "libx264"
    with av.open(str(path), "w") as out:
        for k, v in tags.items():
            out.metadata[k] = v
        vs = out.add_stream(encoder, rate=10)
        vs.width, vs.height, vs.pix_fmt = 96, 64, "yuv420p"
        rng = np.random.default_rng(3)
        mux_rgb_frames(out, vs, (rng.integers(0, 256, (64, 96, 3), dtype=np.uint8) for _ in range(frames)))
    return path


def tags_of(path: Path) -> dict[str, str]:
    with av.open(str(path)) as c:
        return {k.lower(): v for k, v in c.metadata.items()}


PLACE_TAGS = {"location": ISO6709, "com.apple.quicktime.location.ISO6709": ISO6709, "title": "kept-title"}


@pytest.mark.parametrize("suffix", [".mp4", ".mov", ".mkv"])
def test_video_location_tags_removed_title_kept(tmp_path: Path, suffix: str) -> None:
    src = clip(tmp_path / f"a{suffix}", PLACE_TAGS)
    assert any(v == ISO6709 for k, v in tags_of(src).items() if "location" in k)  # the source has one
    report = poison_video(src, tmp_path / f"out{suffix}", SPEC, options=FAST)
    out = tags_of(tmp_path / f"out{suffix}")
    assert not [k for k in out if "location" in k or "xyz" in k]
    assert ISO6709.encode() not in (tmp_path / f"out{suffix}").read_bytes()
    assert out["title"] == "kept-title"
    assert any("location" in r.lower() for r in report.location_removed)
    poison_video(src, tmp_path / f"kept{suffix}", SPEC, options=FAST, keep_location=True)
    assert any(v == ISO6709 for k, v in tags_of(tmp_path / f"kept{suffix}").items() if "location" in k)


@pytest.mark.parametrize("suffix", [".mp4", ".mov", ".mkv", ".webm"])
def test_video_seal_round_trip_and_deterministic(tmp_path: Path, suffix: str) -> None:
    src = clip(tmp_path / f"a{suffix}", {"title": "t"})
    assert read_seal(src, KEY) is None
    for i in (1, 2):
        poison_video(src, tmp_path / f"o{i}{suffix}", SPEC, options=FAST, marker=MARKER)
        seal_file(tmp_path / f"o{i}{suffix}", KEY)
    assert read_seal(tmp_path / f"o1{suffix}", KEY) == Seal("ab" * 32, "spec-7f3a")
    assert read_seal(tmp_path / f"o1{suffix}", bytes(32)) is None  # another installation's key
    data = (tmp_path / f"o1{suffix}").read_bytes()
    assert b"ab" * 32 not in data and b"spec-7f3a" not in data and b"ppd" not in data.lower()
    digest = [hashlib.sha256((tmp_path / f"o{i}{suffix}").read_bytes()).hexdigest() for i in (1, 2)]
    assert digest[0] == digest[1]
    with av.open(str(tmp_path / f"o1{suffix}")) as c:  # still a valid video with every frame
        assert sum(1 for _ in c.decode(video=0)) == 6
    # re-poisoning a sealed file replaces the seal, never stacks a second one
    other = Marker.placeholder(KEY, "spec-2", "cd" * 32)
    poison_video(tmp_path / f"o1{suffix}", tmp_path / f"o3{suffix}", SPEC, options=FAST, marker=other)
    seal_file(tmp_path / f"o3{suffix}", KEY)
    assert read_seal(tmp_path / f"o3{suffix}", KEY) == Seal("cd" * 32, "spec-2")
    # one byte changed anywhere (here: the last frame's data) and it is no longer ppd's output
    edited = bytearray((tmp_path / f"o1{suffix}").read_bytes())
    edited[len(edited) // 2] ^= 1
    (tmp_path / f"e{suffix}").write_bytes(bytes(edited))
    assert read_seal(tmp_path / f"e{suffix}", KEY) is None
