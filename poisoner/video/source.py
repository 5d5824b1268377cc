"""Probing the source: what it is (container, codec, size, pixel format, timing, rotation, colour,
HDR) before anything is written; a frame size over the budget is refused from the header."""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path
from typing import Any, cast

import av
import av.error
import numpy as np

from poisoner.limits import check_video_frame_budget
from poisoner.video.demux import main_video_stream, open_input
from poisoner.video.errors import VideoFormatError, one_line
from poisoner.video.model import SourceInfo

# Output container by suffix: the same container family as the source.
MUXER_BY_SUFFIX = {".mp4": "mp4", ".m4v": "mp4", ".mov": "mov", ".mkv": "matroska", ".webm": "webm"}

# Side data types that carry HDR mastering information (kept by re-tagging where possible).
HDR_SIDE_DATA = ("MASTERING_DISPLAY_METADATA", "CONTENT_LIGHT_LEVEL")


def muxer_for(path: Path) -> str:
    muxer = MUXER_BY_SUFFIX.get(path.suffix.lower())
    if muxer is None:
        raise VideoFormatError(f"{path.name}: unsupported video suffix {path.suffix!r}")
    return muxer


def probe(path: Path, *, max_pixels: int | None = None) -> SourceInfo:
    """Read the source's video stream properties and its first frame (rotation, colour, HDR).
    A frame size over max_pixels (None: limits.DEFAULT_MAX_VIDEO_PIXELS) is refused from the
    stream header, before any frame is decoded."""
    path = Path(path)
    muxer = muxer_for(path)
    with open_input(path) as container:
        stream = main_video_stream(container, path.name)
        cc = stream.codec_context
        _refuse_over_budget(path.name, cc.width or 0, cc.height or 0, max_pixels)
        first = _first_frame(container, stream, path.name)
        # The header did not say (width 0): one frame decoded, no more.
        _refuse_over_budget(path.name, first.width, first.height, max_pixels)
        matrix, hdr = _side_data(first)
        duration_s = _duration_s(container, stream)
        return SourceInfo(
            muxer=muxer,
            codec=cc.name,
            width=first.width,
            height=first.height,
            pix_fmt=first.format.name,
            time_base=Fraction(cast(Fraction, stream.time_base)),  # a decoded stream's is set
            average_rate=Fraction(stream.average_rate) if stream.average_rate else None,
            frames_declared=int(stream.frames or 0),
            duration_s=duration_s,
            bit_rate=_bit_rate(path, cc.bit_rate or None, duration_s),
            display_matrix=matrix,
            rotation=int(first.rotation),
            color_range=int(first.color_range),
            colorspace=int(first.colorspace),
            color_primaries=int(first.color_primaries),
            color_trc=int(first.color_trc),
            hdr_side_data=hdr,
            stream_index=stream.index,
        )


def _refuse_over_budget(name: str, width: int, height: int, max_pixels: int | None) -> None:
    refusal = check_video_frame_budget(name, width, height, max_pixels)
    if refusal:
        raise VideoFormatError(refusal)


def _first_frame(
    container: av.container.InputContainer, stream: av.video.stream.VideoStream, name: str
) -> av.VideoFrame:
    try:
        return next(container.decode(stream))
    except StopIteration:
        raise VideoFormatError(f"{name}: the video stream has no decodable frame") from None
    except av.error.FFmpegError as exc:
        raise VideoFormatError(f"{name}: cannot decode the first frame ({one_line(exc)})") from exc


def _side_data(frame: av.VideoFrame) -> tuple[tuple[int, ...] | None, dict[str, bytes]]:
    """(display matrix, HDR side data by type name) of a decoded frame."""
    matrix: tuple[int, ...] | None = None
    hdr: dict[str, bytes] = {}
    side_data: list[Any] = list(frame.side_data)  # SideData objects (PyAV's stubs say str)
    for sd in side_data:
        if sd.type.name == "DISPLAYMATRIX":
            matrix = tuple(int(v) for v in np.frombuffer(bytes(sd), "<i4"))
        elif sd.type.name in HDR_SIDE_DATA:
            hdr[sd.type.name] = bytes(sd)
    return matrix, hdr


def _duration_s(container: av.container.InputContainer, stream: av.video.stream.VideoStream) -> float | None:
    if stream.duration is not None and stream.time_base is not None:
        return float(stream.duration * stream.time_base)
    if container.duration is not None:
        return container.duration / av.time_base
    return None


def _bit_rate(path: Path, stream_rate: int | None, duration_s: float | None) -> int | None:
    if stream_rate or not duration_s:
        return stream_rate
    # Container-level rate minus nothing: an upper bound when the stream does not say.
    return int(os.path.getsize(path) * 8 / duration_s) if duration_s > 0 else None
