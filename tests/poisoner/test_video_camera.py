"""poisoner.video on what cameras, phones and editors write beyond a plain clip: HEVC under Apple's
sample entry, ProRes, timecode tracks, VP9 with alpha, Apple `mdta` tags (black-box review 9)."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest

from poisoner.spec import PatchSpec
from poisoner.video import poison_video
from testkit.video import scene

SPEC = PatchSpec()
SIZE = (320, 240)


def write_clip(
    path: Path,
    encoder: str,
    pix_fmt: str,
    frames: int = 6,
    *,
    codec_tag: str | None = None,
    options: dict[str, str] | None = None,
    stream_tags: dict[str, str] | None = None,
    container_tags: dict[str, str] | None = None,
    container_options: dict[str, str] | None = None,
    alpha: bool = False,
) -> Path:
    """A clip of the panning test scene; with alpha, the left half opaque and the right half clear."""
    width, height = SIZE
    with av.open(str(path), "w", options=container_options or {}) as out:
        out.metadata.update(container_tags or {})
        vs = out.add_stream(encoder, rate=24, options=options or {})
        vs.width, vs.height, vs.pix_fmt = width, height, pix_fmt
        if codec_tag:
            vs.codec_tag = codec_tag
        vs.metadata.update(stream_tags or {})
        for i in range(frames):
            rgb = scene(width, height, i)
            if alpha:
                opaque = np.where(np.arange(width) < width // 2, 255, 0).astype(np.uint8)
                rgba = np.dstack([rgb, np.broadcast_to(opaque, (height, width))])
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgba), format="rgba")
            else:
                frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
            frame.pts = i
            for pkt in vs.encode(frame):
                out.mux(pkt)
        for pkt in vs.encode(None):
            out.mux(pkt)
    return path


def video_tag(path: Path) -> str:
    with av.open(str(path)) as c:
        return str(c.streams.video[0].codec_tag)


def frame_count(path: Path) -> int:
    with av.open(str(path)) as c:
        return sum(1 for _ in c.decode(video=0))


# ---- F2: HEVC keeps its sample entry ----------------------------------------------------------


@pytest.mark.parametrize(("suffix", "tag"), [(".mp4", "hvc1"), (".mov", "hvc1"), (".mp4", "hev1")])
def test_hevc_keeps_its_sample_entry_tag(tmp_path: Path, suffix: str, tag: str) -> None:
    """An iPhone's HEVC is `hvc1`, the only entry Apple's players play; FFmpeg writes `hev1` unless told."""
    src = write_clip(tmp_path / f"clip{suffix}", "libx265", "yuv420p", codec_tag=tag,
                     options={"x265-params": "log-level=error"})  # fmt: skip
    assert video_tag(src) == tag
    dst = tmp_path / f"out{suffix}"
    report = poison_video(src, dst, SPEC)
    assert report.encoder == "libx265"
    assert video_tag(dst) == tag
    assert frame_count(dst) == frame_count(src) == 6


def alpha_planes(path: Path) -> list[np.ndarray]:
    """Each frame's alpha as 8-bit (libvpx-vp9 decodes a VP9's alpha, FFmpeg's own vp9 decoder drops it)."""
    with av.open(str(path)) as c:
        stream = c.streams.video[0]
        decoder = stream.codec_context
        if decoder.name == "vp9":
            decoder = av.CodecContext.create("libvpx-vp9", "r")
            decoder.extradata = stream.codec_context.extradata
        planes = []
        for pkt in c.demux(stream):
            for frame in decoder.decode(pkt):
                assert frame.format.name.startswith("yuva"), frame.format.name
                planes.append(frame.reformat(format="rgba").to_ndarray()[..., 3])
        return planes


def assert_alpha_kept(src: Path, dst: Path) -> None:
    """The same transparency in every frame, but under the mark, which is opaque (as in a photo)."""
    before, after = alpha_planes(src), alpha_planes(dst)
    assert len(after) == len(before)
    assert before[0][:, -40:].max() <= 4 and before[0][:, :40].min() >= 250  # the clip is half clear
    x0, y0, x1, y1 = SPEC.resolve(*SIZE).box
    for a, b in zip(before, after, strict=True):
        assert (b[y0:y1, x0:x1] == 255).all()
        a[y0:y1, x0:x1] = b[y0:y1, x0:x1] = 0
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 8


# ---- F6: ProRes stays ProRes ------------------------------------------------------------------


def test_prores_is_written_as_prores_of_the_same_profile(tmp_path: Path) -> None:
    src = write_clip(tmp_path / "master.mov", "prores_ks", "yuv422p10le", options={"profile": "hq"})
    dst = tmp_path / "out.mov"
    report = poison_video(src, dst, SPEC)
    with av.open(str(dst)) as c:
        v = c.streams.video[0]
        assert (v.codec_context.name, str(v.codec_tag), v.codec_context.profile) == ("prores", "apch", "HQ")
        assert v.codec_context.format.name == "yuv422p10le"
    assert frame_count(dst) == 6
    notes = " ".join(" ".join(report.notes).split())
    assert "ProRes profile hq with prores_ks" in notes
    assert "no prores encoder" not in notes


def test_prores_4444_keeps_its_alpha(tmp_path: Path) -> None:
    src = write_clip(tmp_path / "key.mov", "prores_ks", "yuva444p10le", alpha=True)
    dst = tmp_path / "out.mov"
    report = poison_video(src, dst, SPEC)
    with av.open(str(dst)) as c:
        v = c.streams.video[0]
        assert (v.codec_context.name, str(v.codec_tag)) == ("prores", "ap4h")
    assert_alpha_kept(src, dst)
    # the ProRes decoder gives 4444 as 12-bit, prores_ks writes 10-bit samples: said
    assert "written as yuva444p10le" in " ".join(" ".join(report.notes).split())


# ---- F4: a timecode track ---------------------------------------------------------------------


def timecodes(path: Path) -> list[tuple[str, str]]:
    with av.open(str(path)) as c:
        return [(s.type, s.metadata.get("timecode", "")) for s in c.streams]


@pytest.mark.parametrize("suffix", [".mov", ".mp4"])
def test_a_timecode_track_is_kept(tmp_path: Path, suffix: str) -> None:
    """A pro camera's or drone's clip: a `tmcd` track beside the video (it failed: "cannot encode with
    libx264 (Invalid argument)", and the daemon quarantined the camera file)."""
    start = {"timecode": "01:00:00:00"}
    src = write_clip(tmp_path / f"A001{suffix}", "libx264", "yuv420p", stream_tags=start)
    assert ("data", "01:00:00:00") in timecodes(src)
    dst = tmp_path / f"out{suffix}"
    report = poison_video(src, dst, SPEC)
    assert timecodes(dst) == timecodes(src)
    assert frame_count(dst) == 6
    assert "timecode" not in " ".join(report.notes)


# ---- F3: a VP9 WebM with transparency ---------------------------------------------------------


def test_vp9_with_alpha_keeps_its_alpha(tmp_path: Path) -> None:
    """A transparent product spin (it came back opaque, still tagged ALPHA_MODE=1)."""
    src = write_clip(tmp_path / "spin.webm", "libvpx-vp9", "yuva420p", alpha=True,
                     options={"deadline": "realtime", "cpu-used": "8"})  # fmt: skip
    dst = tmp_path / "out.webm"
    report = poison_video(src, dst, SPEC)
    assert report.encoder == "libvpx-vp9"
    assert_alpha_kept(src, dst)
    assert "alpha" not in " ".join(report.notes)


def test_vp9_alpha_that_does_not_decode_is_said_and_not_claimed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A build without the libvpx decoder reads the frames opaque: said, and ALPHA_MODE not left on."""
    from poisoner.video import demux

    monkeypatch.setitem(demux._ALPHA_DECODERS, "vp9", "no-such-decoder")
    src = write_clip(tmp_path / "spin.webm", "libvpx-vp9", "yuva420p", alpha=True,
                     options={"deadline": "realtime", "cpu-used": "8"})  # fmt: skip
    dst = tmp_path / "out.webm"
    report = poison_video(src, dst, SPEC)
    assert "transparency (alpha) left out" in " ".join(" ".join(report.notes).split())
    with av.open(str(dst)) as c:
        assert not any(k.lower() == "alpha_mode" for k in c.streams.video[0].metadata)


# ---- F5: Apple `mdta` tags --------------------------------------------------------------------

IPHONE_TAGS = {
    "com.apple.quicktime.location.ISO6709": "+48.8584+002.2945+035.000/",
    "com.apple.quicktime.make": "Apple",
    "com.apple.quicktime.model": "iPhone 15",
    "com.apple.quicktime.creationdate": "2026-05-01T12:00:00+0200",
}


def container_tags(path: Path) -> dict[str, str]:
    with av.open(str(path)) as c:
        return dict(c.metadata)


def test_apple_mdta_tags_are_kept_but_the_location(tmp_path: Path) -> None:
    """An iPhone clip's make, model and capture date (photo libraries sort by it) were dropped, and only
    the location's removal was said."""
    src = write_clip(tmp_path / "IMG_0002.MOV", "libx264", "yuv420p", container_tags=IPHONE_TAGS,
                     container_options={"movflags": "use_metadata_tags"})  # fmt: skip
    assert IPHONE_TAGS.items() <= container_tags(src).items()
    dst = tmp_path / "out.mov"
    report = poison_video(src, dst, SPEC)
    kept = container_tags(dst)
    for key in ("com.apple.quicktime.make", "com.apple.quicktime.model", "com.apple.quicktime.creationdate"):
        assert kept[key] == IPHONE_TAGS[key]
    assert "com.apple.quicktime.location.ISO6709" not in kept
    notes = " ".join(" ".join(report.notes).split())
    assert "location removed (1): tag com.apple.quicktime.location.ISO6709" in notes
    assert "left out" not in notes


def test_a_tag_the_muxer_does_not_write_is_said(tmp_path: Path) -> None:
    """A key FFmpeg read but its muxer has no place for (a dot-less `mdta` key: written as a classic
    tag, which has none of that name) is named, not dropped in silence."""
    src = write_clip(tmp_path / "clip.mp4", "libx264", "yuv420p", container_tags={"shotby": "Ana"},
                     container_options={"movflags": "use_metadata_tags"})  # fmt: skip
    assert container_tags(src)["shotby"] == "Ana"
    dst = tmp_path / "out.mp4"
    report = poison_video(src, dst, SPEC)
    assert "shotby" not in container_tags(dst)
    notes = " ".join(" ".join(report.notes).split())
    assert "tags left out (1; FFmpeg's mp4 muxer does not write them): shotby" in notes


@pytest.mark.parametrize("fourcc", [b"gpmd", b"camm"])
def test_a_gps_telemetry_track_is_removed_unless_location_is_kept(tmp_path: Path, fourcc: bytes) -> None:
    """PyAV gives a data stream no codec tag, so a GoPro's GPS track (gpmd) or a CAMM track was copied
    into the published video while the container's location tags were removed and said: its sample
    entry is now read from the file (poisoner.video.sample_entries)."""
    from testkit.video import telemetry_clip

    src = telemetry_clip(tmp_path / "GX010001.MP4", fourcc)
    with av.open(str(src)) as c:
        assert [s.type for s in c.streams] == ["video", "data"]
    dst = tmp_path / "out.mp4"
    report = poison_video(src, dst, SPEC)
    with av.open(str(dst)) as c:
        assert [s.type for s in c.streams] == ["video"]
    assert fourcc not in dst.read_bytes()
    notes = " ".join(" ".join(report.notes).split())
    assert f"location removed (1): {fourcc.decode()} telemetry stream #1" in notes, notes
    if fourcc == b"gpmd":  # kept when asked (FFmpeg's MP4 muxer writes gpmd; a camm copy it refuses)
        kept = tmp_path / "kept.mp4"
        poison_video(src, kept, SPEC, keep_location=True)
        with av.open(str(kept)) as c:
            assert [s.type for s in c.streams] == ["video", "data"]


def test_sample_entries_of_what_is_not_a_whole_mp4_are_none(tmp_path: Path) -> None:
    from poisoner.video.sample_entries import sample_entries
    from testkit.video import telemetry_clip

    clip = telemetry_clip(tmp_path / "a.mp4", b"gpmd")
    whole = sample_entries(clip)
    assert sorted(whole.values()) == ["avc1", "gpmd"]
    data = clip.read_bytes()
    moov = data.index(b"moov") - 4
    for cut in (moov + 20, moov + 300, len(data) - 7):  # the moov cut short: what is whole, no error
        (tmp_path / f"cut{cut}.mp4").write_bytes(data[:cut])
        assert sample_entries(tmp_path / f"cut{cut}.mp4").items() <= whole.items(), cut
    (tmp_path / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    assert sample_entries(tmp_path / "x.png") == {} and sample_entries(tmp_path / "gone.mp4") == {}
