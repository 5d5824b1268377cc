"""One encode pass: decode the source, blend the patch into every selected frame, encode with the
chosen encoder, and copy every other stream packet by packet (bit-identical), a cover picture aside:
it is written marked or left out (poisoner.video.cover)."""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import cast

import av
import av.error

from poisoner.provenance import Marker
from poisoner.spec import PatchSpec, SpecError
from poisoner.video import model
from poisoner.video.blend import blend_frame
from poisoner.video.cover import CoverPlan, add_cover, cover_packet
from poisoner.video.demux import decode_packet, is_cover, iter_packets, open_input, video_decoder
from poisoner.video.encoder import configure_video_stream
from poisoner.video.errors import VideoFormatError, one_line
from poisoner.video.metadata import (
    add_marker_tag,
    codec_tag,
    copy_metadata,
    is_location_stream,
    is_timecode_stream,
    muxer_options,
    x265_hdr_params,
)


@dataclass
class EncodeResult:
    frames: int
    frames_patched: int
    end_s: float | None  # where the last frame ends, in seconds (None: no timestamps)


@dataclass
class _Pass:
    """One pass's open streams and counters."""

    src_name: str
    info: model.SourceInfo
    spec: PatchSpec
    placement_at: model.PlacementAt
    out: av.container.OutputContainer
    vout: av.video.stream.VideoStream
    copied: dict[int, av.stream.Stream]
    progress: model.ProgressCallback | None
    total: int | None
    covers: CoverPlan
    decoder: av.video.codeccontext.VideoCodecContext  # demux.video_decoder: a VP9 with alpha needs libvpx
    keep_frame_types: bool = False
    frames: int = 0
    patched: int = 0
    last_end: float | None = None
    # each source frame's duration by its pts, in its time base (the encoder gives a frame's packet a
    # duration of its own: the last frames of a variable-rate clip came out longer, and the clip with
    # them, 2.267 s -> 2.284 s; a black-box review)
    durations: dict[int, tuple[int, Fraction]] = field(default_factory=dict)
    covers_written: set[int] = field(default_factory=set)  # source cover streams whose picture is muxed


def encode_once(
    src: Path,
    dst: Path,
    spec: PatchSpec,
    placement_at: model.PlacementAt,
    info: model.SourceInfo,
    choice: model.EncoderChoice,
    options: model.VideoOptions,
    progress: model.ProgressCallback | None,
    report: model.VideoReport,
    marker: Marker | None = None,
    keep_location: bool = True,
    covers: CoverPlan | None = None,
) -> EncodeResult:
    """Write dst from src in one pass at choice's settings; report.location_removed says what
    location was left out. covers: the marked cover pictures, written in place of the source's
    (poisoner.video.cover.plan_covers); a cover without one is left out."""
    covers = covers or CoverPlan()
    total = info.frames_declared or (
        int(round(info.duration_s * model.frame_rate(info))) if info.duration_s else None
    )
    opts = muxer_options(info.muxer, info.mdta_tags)
    removed: list[str] = []
    with open_input(src) as inp, av.open(str(dst), "w", format=info.muxer, container_options=opts) as out:
        copy_metadata(dict(inp.metadata), out, keep_location, removed)
        add_marker_tag(out, info.muxer, marker)
        vout = _video_stream(inp, out, info, choice, options, keep_location, removed)
        copied = _copied_streams(inp, out, src.name, info, keep_location, removed, covers)
        decoder = video_decoder(cast(av.video.stream.VideoStream, inp.streams[info.stream_index]))
        run = _Pass(
            src.name, info, spec, placement_at, out, vout, copied, progress, total, covers, decoder,
            choice.keep_frame_types,
        )  # fmt: skip
        for packet in iter_packets(inp, src.name):
            _mux_packet(run, packet)
        _encode(run, None)
    report.location_removed = removed
    return EncodeResult(frames=run.frames, frames_patched=run.patched, end_s=run.last_end)


def _video_stream(
    inp: av.container.InputContainer,
    out: av.container.OutputContainer,
    info: model.SourceInfo,
    choice: model.EncoderChoice,
    options: model.VideoOptions,
    keep_location: bool,
    removed: list[str],
) -> av.video.stream.VideoStream:
    vin = cast(av.video.stream.VideoStream, inp.streams[info.stream_index])  # the source's video stream
    vin.thread_type = "AUTO"
    if choice.encoder == "libx265" and info.hdr_side_data:
        hdr = x265_hdr_params(info.hdr_side_data)
        if hdr:
            choice.options["x265-params"] = choice.options["x265-params"] + ":" + hdr
    vout = configure_video_stream(out, info, choice, options)
    copy_metadata(dict(vin.metadata), vout, keep_location, removed)
    if info.alpha_mode and not model.has_alpha(info.pix_fmt):
        # its alpha did not decode (driver notes it): the output must not claim a transparency it lacks
        for key in [k for k in vout.metadata if k.lower() == "alpha_mode"]:
            del vout.metadata[key]
    return vout


def _copied_streams(
    inp: av.container.InputContainer,
    out: av.container.OutputContainer,
    src_name: str,
    info: model.SourceInfo,
    keep_location: bool,
    removed: list[str],
    covers: CoverPlan,
) -> dict[int, av.stream.Stream]:
    """Output streams for every source stream but the video one, by source index; GPS telemetry
    streams are left out unless keep_location, a cover picture unless covers has it marked."""
    copied: dict[int, av.stream.Stream] = {}
    for s in inp.streams:
        if s.index == info.stream_index:
            continue
        if is_cover(s):
            if (cover := _cover_stream(out, s, info.muxer, covers, keep_location, removed)) is not None:
                copied[s.index] = cover
            continue
        if is_timecode_stream(s):
            # FFmpeg cannot copy a timecode (tmcd) track's packets (the header failed: "Invalid
            # argument"); the mov/mp4 muxer writes its own from the video stream's timecode tag.
            _keep_timecode(s, out)
            continue
        if not keep_location and is_location_stream(s):
            removed.append(f"{codec_tag(s)} telemetry stream #{s.index}")
            continue
        try:
            o = out.add_stream_from_template(s)
        except (av.error.FFmpegError, ValueError, TypeError) as exc:
            raise VideoFormatError(
                f"{src_name}: stream #{s.index} ({s.type}) cannot be copied into {info.muxer} "
                f"({one_line(exc)})"
            ) from exc
        copy_metadata(dict(s.metadata), o, keep_location, removed)
        o.disposition = s.disposition
        copied[s.index] = o
    return copied


def _keep_timecode(s: av.stream.Stream, out: av.container.OutputContainer) -> None:
    """The timecode track's start on the output's video stream, where the muxer reads it."""
    vout = out.streams.video[0]  # the first stream added (encode_once)
    start = s.metadata.get("timecode")
    if start and "timecode" not in vout.metadata:
        vout.metadata["timecode"] = start


def _cover_stream(
    out: av.container.OutputContainer,
    s: av.stream.Stream,
    muxer: str,
    covers: CoverPlan,
    keep_location: bool,
    removed: list[str],
) -> av.stream.Stream | None:
    """The output stream a marked cover's packet goes to (MP4); None: written as an attachment with
    the header (Matroska), or left out (covers.removed says why)."""
    if s.index not in covers.marked:
        return None
    o = add_cover(out, s, muxer, covers.marked[s.index])
    copy_metadata(dict(s.metadata), o, keep_location, removed)
    if o.type == "attachment":
        return None
    o.disposition = s.disposition
    return o


def _mux_packet(run: _Pass, packet: av.Packet) -> None:
    idx = packet.stream.index
    if idx == run.info.stream_index:
        for frame in decode_packet(packet, run.src_name, run.decoder):
            _encode(run, _patched(run, frame))
            run.frames += 1
            if run.progress is not None:
                run.progress(run.frames, run.total)
    elif idx in run.copied:
        if packet.dts is None and packet.size == 0:
            return  # demuxer flush packet
        if idx in run.covers.marked:
            _mux_cover(run, packet)
            return
        packet.stream = run.copied[idx]
        run.out.mux(packet)


def _mux_cover(run: _Pass, packet: av.Packet) -> None:
    """The marked picture in place of the source's cover, once (FFmpeg gives a cover's picture again
    after a seek; never the source's)."""
    idx = packet.stream.index
    if idx not in run.covers_written:
        run.covers_written.add(idx)
        run.out.mux(cover_packet(packet, run.copied[idx], run.covers.marked[idx]))


def _patched(run: _Pass, frame: av.VideoFrame) -> av.VideoFrame:
    """The frame to encode: checked, patched when the spec selects it, its end time noted."""
    name, info, index = run.src_name, run.info, run.frames
    source_type = frame.pict_type
    if frame.is_corrupt:
        raise VideoFormatError(f"{name}: corrupt frame {index} (damaged or truncated data)")
    if (frame.width, frame.height) != (info.width, info.height):
        raise VideoFormatError(
            f"{name}: frame size changes mid-stream ({info.width}x{info.height} -> "
            f"{frame.width}x{frame.height}); not supported"
        )
    if run.spec.selects(f"frame:{index}"):
        frame.make_writable()
        try:
            placement = run.placement_at(index)
        except SpecError as exc:
            raise VideoFormatError(f"{name}: frame {index}: {exc}") from exc
        frame = blend_frame(frame, placement)
        run.patched += 1
    if frame.pts is not None and frame.time_base is not None:
        run.last_end = float((frame.pts + (frame.duration or 0)) * frame.time_base)
        if frame.duration:
            run.durations[frame.pts] = (frame.duration, frame.time_base)
    # the source's own frame type where kept (EncoderChoice.keep_frame_types), else the encoder's choice
    frame.pict_type = source_type if run.keep_frame_types else av.video.frame.PictureType.NONE
    return frame


def _encode(run: _Pass, frame: av.VideoFrame | None) -> None:
    for pkt in run.vout.encode(frame):
        _keep_duration(run, pkt)
        run.out.mux(pkt)


def _keep_duration(run: _Pass, pkt: av.Packet) -> None:
    """The packet's duration: its source frame's (same pts), in the packet's time base."""
    if pkt.pts is None or pkt.time_base is None or (kept := run.durations.pop(pkt.pts, None)) is None:
        return
    duration, time_base = kept
    pkt.duration = duration if time_base == pkt.time_base else round(duration * time_base / pkt.time_base)
