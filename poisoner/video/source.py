"""Probing the source: what it is (container, codec, size, pixel format, timing, rotation, colour,
HDR) before anything is written; a frame size over the budget is refused from the header."""

from __future__ import annotations

import os
import re
from fractions import Fraction
from pathlib import Path
from typing import Any, cast

import av
import av.error
import numpy as np

from poisoner.limits import check_video_frame_budget
from poisoner.video.demux import alpha_mode, main_video_stream, open_input, video_decoder
from poisoner.video.errors import VideoFormatError, one_line
from poisoner.video.metadata import is_mdta_key, is_timecode_stream
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
        first, encoded_crf = _first_frame(container, stream, path.name)
        # The header did not say (width 0): one frame decoded, no more.
        _refuse_over_budget(path.name, first.width, first.height, max_pixels)
        matrix, hdr = frame_side_data(first)
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
            encoded_crf=encoded_crf,
            b_frames=bool(cc.has_b_frames),
            codec_tag=stream_codec_tag(stream),
            profile=str(cc.profile or ""),
            timecode=timecode_of(container),
            alpha_mode=alpha_mode(stream),
            mdta_tags=any(is_mdta_key(key) for key in container.metadata),
        )


# x264 ("x264 - core 164 ... options: ... crf=20.0 ...") and x265 ("x265 (build 199) - ... crf=28.0")
# write their settings as text in an SEI message of the stream's first frame.
_ENCODER_SETTINGS = re.compile(rb"(?:x264 - core|x265 \(build)[^\x00]{0,16000}?[ :]crf=(\d+(?:\.\d+)?)")


def timecode_of(container: av.container.InputContainer) -> str:
    """The start of the container's timecode track ("01:00:00:00"), "" where it has none."""
    return next((s.metadata["timecode"] for s in container.streams if is_timecode_stream(s)), "")


def stream_codec_tag(stream: av.stream.Stream) -> str:
    """The stream's codec tag as text ("hvc1"), "" where it has none (Matroska's are zero)."""
    try:
        return str(getattr(stream, "codec_tag", "") or "").strip("\x00 ")
    except (ValueError, UnicodeDecodeError):
        return ""


def _refuse_over_budget(name: str, width: int, height: int, max_pixels: int | None) -> None:
    refusal = check_video_frame_budget(name, width, height, max_pixels)
    if refusal:
        raise VideoFormatError(refusal)


def _recorded_crf(data: bytes) -> float | None:
    found = _ENCODER_SETTINGS.search(data)
    return float(found.group(1)) if found else None


def _first_frame(
    container: av.container.InputContainer, stream: av.video.stream.VideoStream, name: str
) -> tuple[av.VideoFrame, float | None]:
    """The first decoded frame, and the CRF x264 or x265 recorded in the stream (its settings SEI: in
    the codec's extradata or the first packet), or None."""
    crf = _recorded_crf(bytes(stream.codec_context.extradata or b""))  # x265 in MP4: the hvcC's SEI
    decoder = video_decoder(stream)  # what the encode pass decodes with (a VP9's alpha: libvpx)
    first_packet = crf is None
    try:
        for packet in container.demux(stream):
            if first_packet and packet.size:
                first_packet = False
                crf = _recorded_crf(bytes(packet)[:65536])
            for frame in decoder.decode(packet):
                return cast(av.VideoFrame, frame), crf
    except av.error.FFmpegError as exc:
        raise VideoFormatError(f"{name}: cannot decode the first frame ({one_line(exc)})") from exc
    raise VideoFormatError(f"{name}: the video stream has no decodable frame")


def side_data_of(frame: av.VideoFrame) -> list[Any]:
    """The frame's SideData objects: PyAV up to 18.1.0 iterates them, 18.1.1 iterates their types, each
    SideData under its type (CI's fresh install took 18.1.1: every video failed, "'Type' object has no
    attribute 'type'")."""
    found: Any = frame.side_data
    return [item if hasattr(item, "type") else found[item] for item in list(found)]


def frame_side_data(frame: av.VideoFrame) -> tuple[tuple[int, ...] | None, dict[str, bytes]]:
    """(display matrix, HDR side data by type name) of a decoded frame."""
    matrix: tuple[int, ...] | None = None
    hdr: dict[str, bytes] = {}
    for sd in side_data_of(frame):
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
