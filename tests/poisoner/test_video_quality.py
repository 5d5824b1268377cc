"""A video is re-encoded no coarser than its own encoder made it (a black-box review, 2026-12-07: a
720p x264 clip made at CRF 20 with a fast preset, 0.04 bits per pixel, came out at CRF 28, the
bit-rate rule's ceiling: PSNR 35 dB outside the mark, fine texture softened, and nothing said). x264
and x265 write their settings in the stream; ppd reads the CRF there and says what it chose."""

from __future__ import annotations

import dataclasses
from fractions import Fraction
from pathlib import Path

import pytest

from poisoner.ladder import default_spec
from poisoner.video import poison_video
from poisoner.video.encoder import choose_encoder
from poisoner.video.model import SourceInfo, VideoOptions
from poisoner.video.source import probe
from testkit.video import Clip, make_clip


@pytest.mark.parametrize(("crf", "preset"), [("20", "ultrafast"), ("31", "veryfast")])
def test_the_sources_own_crf_is_read_and_not_gone_below(tmp_path: Path, crf: str, preset: str) -> None:
    src = make_clip(
        tmp_path / "clip.mp4", Clip(frames=12, audio=None, options=(("crf", crf), ("preset", preset)))
    )
    info = probe(src)
    assert info.encoded_crf == float(crf)
    choice = choose_encoder(info, VideoOptions())
    assert choice.encoder == "libx264" and choice.crf is not None and choice.crf <= int(crf)
    report = poison_video(src, tmp_path / "out.mp4", default_spec())
    assert any(n.startswith(f"video re-encoded at quality CRF {report.crf} with libx264 (lossy); the source "
                            f"was made at CRF {int(crf)}") for n in report.notes), report.notes  # fmt: skip


def test_a_low_bit_rate_no_longer_means_a_coarse_encode() -> None:
    """The bit-rate rule alone picks its ceiling for a sparse source; the recorded CRF caps it."""
    info = SourceInfo(
        muxer="mp4", codec="h264", width=1280, height=720, pix_fmt="yuv420p", time_base=Fraction(1, 30),
        average_rate=Fraction(30), frames_declared=300, duration_s=10.0, bit_rate=1_070_000,
        display_matrix=None, rotation=0, color_range=0, colorspace=2, color_primaries=2, color_trc=2,
        hdr_side_data={}, stream_index=0,
    )  # fmt: skip
    by_rate = choose_encoder(info, VideoOptions())
    recorded = choose_encoder(dataclasses.replace(info, encoded_crf=20.0), VideoOptions())
    assert by_rate.crf == 28 and recorded.crf == 20
    assert (
        choose_encoder(dataclasses.replace(info, encoded_crf=20.0), VideoOptions(crf_override=30)).crf == 30
    )


def test_a_vp9_source_has_no_recorded_crf(tmp_path: Path) -> None:
    src = make_clip(tmp_path / "clip.webm", Clip(suffix=".webm", encoder="libvpx-vp9", frames=6, audio=None))
    assert probe(src).encoded_crf is None


def test_an_x265_sources_crf_is_read_from_its_extradata(tmp_path: Path) -> None:
    """x265 in MP4 writes its settings in the hvcC's SEI (the codec's extradata), not in the first packet."""
    import av

    if "libx265" not in av.codecs_available:
        pytest.skip("this PyAV build has no libx265")
    options = (("crf", "24"), ("x265-params", "log-level=error"))
    src = make_clip(tmp_path / "clip.mp4", Clip(encoder="libx265", frames=6, audio=None, options=options))
    info = probe(src)
    assert info.codec == "hevc" and info.encoded_crf == 24.0


def _frame_types(path: Path) -> list[str]:
    import av

    with av.open(str(path)) as container:
        return [av.video.frame.PictureType(int(f.pict_type)).name for f in container.decode(video=0)]


def test_a_b_frame_sources_frame_types_are_kept(tmp_path: Path) -> None:
    """The sliding mark made x264 code as P what the source's encoder coded as B (it predicts badly across
    frames): a 720p clip grew 1.33x where its own frame types give 1.09x, at no lower quality outside the
    mark (a second black-box review, N14; bench/results/video.md, "Size of a patched video")."""
    src = make_clip(tmp_path / "clip.mp4", Clip(frames=40, audio=None, options=(("crf", "8"),)))
    assert probe(src).b_frames and "B" in _frame_types(src)
    kept, free = tmp_path / "kept.mp4", tmp_path / "free.mp4"
    poison_video(src, kept, default_spec())
    poison_video(src, free, default_spec(), options=VideoOptions(keep_frame_types=False))
    assert _frame_types(kept) == _frame_types(src) != _frame_types(free)
    assert kept.stat().st_size < free.stat().st_size


def test_x265_keeps_its_own_frame_types(tmp_path: Path) -> None:
    """Given the source's frame types x265 was smaller too, but lower in quality outside the mark."""
    import av

    if "libx265" not in av.codecs_available:
        pytest.skip("this PyAV build has no libx265")
    options = (("x265-params", "log-level=error"),)
    src = make_clip(tmp_path / "clip.mp4", Clip(encoder="libx265", frames=12, audio=None, options=options))
    info = probe(src)
    assert info.b_frames and not choose_encoder(info, VideoOptions()).keep_frame_types


def test_a_source_without_b_frames_leaves_the_encoder_its_choice(tmp_path: Path) -> None:
    """A phone's hardware encoder codes no B-frames; x264 keeps its own, smaller, choice there."""
    src = make_clip(tmp_path / "clip.mp4", Clip(frames=40, audio=None, options=(("bf", "0"),)))
    assert not probe(src).b_frames and "B" not in _frame_types(src)
    assert not choose_encoder(probe(src), VideoOptions()).keep_frame_types
    poison_video(src, tmp_path / "out.mp4", default_spec())
    assert "B" in _frame_types(tmp_path / "out.mp4")
