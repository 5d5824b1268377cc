"""Videos: the dataset's one patch blended into every frame, in stored pixel coordinates.

The video stays a video: decoded with PyAV, every frame gets `apply_patch` at the placement
`frame_placements` gives (`PatchSpec.resolve(width, height)`, identical for every frame, for a
static spec; a point on the path per frame for a moving one), and the frames are re-encoded
with the source's codec (where this PyAV build has an encoder for it), pixel format, frame
timestamps (so frame rate, variable frame rate, time base, duration and frame count are kept),
rotation and colour tags. Audio, subtitle and data streams are copied packet by packet (bit-identical).

Decisions (see docs/VIDEO.md for the figures behind them):
- The patch sits in stored (coded) pixel coordinates; the display matrix is copied unchanged.
  Every frame of a video has the same matrix, so frames extracted with or without
  auto-rotation all carry the patch at one identical position (what the attack needs); only
  the corner it appears in on a rotating player differs. Same rule as images.
- The blend touches only the patch region: the region (widened to the chroma grid) is
  converted to RGB, `apply_patch` blends it exactly as for images, and only the planes' samples
  that cover the patch are written back. Pixels outside the patch are bit-identical before
  encoding.
- Quality: a constant-quality encode (CRF) chosen from the source's bits per pixel, never above
  a per-codec ceiling at which the patch was measured to survive; after encoding, the patch
  contrast is measured on the decoded output and, if it fell below `min_patch_contrast`, the
  video is encoded again at a lower CRF.
- PatchSpec.ratio < 1 selects frames by `spec.selects(f"frame:{index}")` (deterministic).
- A moving spec (issue #9) glides along its path: frame i sits at path index
  i / frame_rate * `motion_steps_per_second`, so frames 1 / motion_steps_per_second seconds
  apart are one photo-step apart, like consecutive photos, and frames sampled at any rate sit at
  different points of the path (turning points aside), which the stationary-match filter keeps.
  In between the patch moves a pixel or so per frame instead of jumping.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import av.error
import numpy as np
from av.video.reformatter import ColorRange, Colorspace

from poisoner import location, provenance
from poisoner.blend import apply_patch, patch_values
from poisoner.formats import PoisonReport
from poisoner.limits import check_video_frame_budget
from poisoner.provenance import Marker
from poisoner.spec import PatchPlacement, PatchSpec, SpecError

log = logging.getLogger(__name__)

# Output container by suffix: the same container family as the source.
_MUXER_BY_SUFFIX = {".mp4": "mp4", ".m4v": "mp4", ".mov": "mov", ".mkv": "matroska", ".webm": "webm"}

# Source codec -> encoder of this PyAV build that writes the same codec.
_ENCODER_BY_CODEC = {
    "h264": "libx264",
    "hevc": "libx265",
    "vp9": "libvpx-vp9",
    "vp8": "libvpx",
    "av1": "libsvtav1",
    "mpeg4": "mpeg4",
}

# Matroska writes a random SegmentUID unless bit-exact: the same inputs must give the same bytes
# (the daemon re-poisons to check crash recovery).
_MUXER_OPTIONS = {"matroska": {"fflags": "+bitexact"}, "webm": {"fflags": "+bitexact"}}

# When no encoder writes the source codec: a codec the container accepts.
_FALLBACK_ENCODER_BY_MUXER = {"mp4": "libx264", "mov": "libx264", "matroska": "libx264", "webm": "libvpx-vp9"}

# CRF model per encoder: (CRF at 0.1 bit/pixel, lowest CRF, highest CRF the patch survives at).
# CRF rises by 6 per halving of bits (x264/x265 rule of thumb: +6 CRF ~ half the bitrate).
# The ceilings come from bench/bench_video.py's patch-survival sweep (docs/VIDEO.md).
_CRF_MODEL: dict[str, tuple[float, int, int]] = {
    "libx264": (23.0, 12, 28),
    "libx265": (26.0, 12, 30),
    "libvpx-vp9": (33.0, 10, 40),
    "libvpx": (10.0, 4, 30),  # libvpx (VP8) crf is 4..63 and needs a bitrate cap
    "libsvtav1": (35.0, 10, 32),
}
_BPP_REFERENCE = 0.1
_CRF_STEP_ON_RETRY = 6

_FULL_LOOKAHEAD_MAX_PIXELS = 1920 * 1088
_SHORT_LOOKAHEAD = 10

# Side data types that carry HDR mastering information (kept by re-tagging where possible).
_HDR_SIDE_DATA = ("MASTERING_DISPLAY_METADATA", "CONTENT_LIGHT_LEVEL")


class VideoFormatError(Exception):
    """A video that cannot be poisoned; the message is one clear line."""


ProgressCallback = Callable[[int, int | None], None]


@dataclass(frozen=True)
class VideoOptions:
    """How a video is encoded and checked.

    min_patch_contrast: the patch's bright-minus-dark difference measured on decoded output,
      relative to the poisoned frames before encoding; below it the video is encoded again at
      a lower CRF (up to max_retries times).
    preset: x264/x265 preset (speed vs size at equal quality; quality is set by the CRF).
    threads: encoder threads, 0 = FFmpeg's choice.
    motion_steps_per_second: how fast a moving spec travels its path, in photo-steps per second
      of video (0: the patch stays at its first position in every frame).
    """

    min_patch_contrast: float = 0.8
    verify_patch: bool = True
    max_retries: int = 2
    preset: str = "medium"
    threads: int = 0
    crf_override: int | None = None
    motion_steps_per_second: float = 6.0  # bench/results/video_motion.md: 2 failed twice, 6 never


@dataclass(frozen=True)
class EncoderChoice:
    encoder: str
    crf: int | None
    bit_rate: int | None
    options: dict[str, str]
    same_codec: bool


@dataclass(frozen=True)
class SourceInfo:
    """What poison_video learns from the source before writing anything."""

    muxer: str
    codec: str
    width: int
    height: int
    pix_fmt: str
    time_base: Fraction
    average_rate: Fraction | None
    frames_declared: int
    duration_s: float | None
    bit_rate: int | None
    display_matrix: tuple[int, ...] | None
    rotation: int
    color_range: int
    colorspace: int
    color_primaries: int
    color_trc: int
    hdr_side_data: dict[str, bytes]
    stream_index: int


@dataclass
class VideoReport(PoisonReport):
    """What poison_video did: an image report (format, size, placement, preserved, notes) plus
    what is particular to video."""

    codec: str = ""
    encoder: str = ""
    pix_fmt: str = ""
    frames: int = 0
    frames_patched: int = 0
    duration_s: float | None = None
    source_bit_rate: int | None = None
    output_bit_rate: int | None = None
    crf: int | None = None
    patch_contrast_min: float | None = None
    patch_contrast_mean: float | None = None
    attempts: int = 1



# ---- probing ------------------------------------------------------------------------------


def _open_input(path: Path) -> av.container.InputContainer:
    try:
        return av.open(str(path), "r")
    except (av.error.FFmpegError, OSError, ValueError) as exc:
        raise VideoFormatError(f"{path.name}: not a readable video ({_one_line(exc)})") from exc


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _main_video_stream(container: av.container.InputContainer, name: str) -> av.video.stream.VideoStream:
    streams = [s for s in container.streams.video if not s.disposition & av.stream.Disposition.attached_pic]
    if not streams:
        raise VideoFormatError(f"{name}: no video stream")
    if len(streams) > 1:
        raise VideoFormatError(f"{name}: {len(streams)} video streams; only single-video files are supported")
    return streams[0]


def _muxer_for(path: Path) -> str:
    muxer = _MUXER_BY_SUFFIX.get(path.suffix.lower())
    if muxer is None:
        raise VideoFormatError(f"{path.name}: unsupported video suffix {path.suffix!r}")
    return muxer


def probe(path: Path, *, max_pixels: int | None = None) -> SourceInfo:
    """Read the source's video stream properties and its first frame (rotation, colour, HDR).
    A frame size over max_pixels (None: limits.DEFAULT_MAX_VIDEO_PIXELS) is refused from the
    stream header, before any frame is decoded."""
    path = Path(path)
    muxer = _muxer_for(path)
    with _open_input(path) as container:
        stream = _main_video_stream(container, path.name)
        cc = stream.codec_context
        refusal = check_video_frame_budget(path.name, cc.width or 0, cc.height or 0, max_pixels)
        if refusal:
            raise VideoFormatError(refusal)
        try:
            first = next(container.decode(stream))
        except StopIteration:
            raise VideoFormatError(f"{path.name}: the video stream has no decodable frame") from None
        except av.error.FFmpegError as exc:
            raise VideoFormatError(f"{path.name}: cannot decode the first frame ({_one_line(exc)})") from exc
        refusal = check_video_frame_budget(path.name, first.width, first.height, max_pixels)
        if refusal:  # the header did not say (width 0): one frame decoded, no more
            raise VideoFormatError(refusal)
        matrix: tuple[int, ...] | None = None
        hdr: dict[str, bytes] = {}
        for sd in first.side_data:
            if sd.type.name == "DISPLAYMATRIX":
                matrix = tuple(int(v) for v in np.frombuffer(bytes(sd), "<i4"))
            elif sd.type.name in _HDR_SIDE_DATA:
                hdr[sd.type.name] = bytes(sd)
        duration_s = None
        if stream.duration is not None and stream.time_base is not None:
            duration_s = float(stream.duration * stream.time_base)
        elif container.duration is not None:
            duration_s = container.duration / av.time_base
        bit_rate = cc.bit_rate or None
        if not bit_rate and duration_s:
            # Container-level rate minus nothing: an upper bound when the stream does not say.
            bit_rate = int(os.path.getsize(path) * 8 / duration_s) if duration_s > 0 else None
        return SourceInfo(
            muxer=muxer,
            codec=cc.name,
            width=first.width,
            height=first.height,
            pix_fmt=first.format.name,
            time_base=Fraction(stream.time_base),
            average_rate=Fraction(stream.average_rate) if stream.average_rate else None,
            frames_declared=int(stream.frames or 0),
            duration_s=duration_s,
            bit_rate=bit_rate,
            display_matrix=matrix,
            rotation=int(first.rotation),
            color_range=int(first.color_range),
            colorspace=int(first.colorspace),
            color_primaries=int(first.color_primaries),
            color_trc=int(first.color_trc),
            hdr_side_data=hdr,
            stream_index=stream.index,
        )


# ---- encoder choice -----------------------------------------------------------------------


def _encoder_available(name: str) -> bool:
    try:
        av.codec.Codec(name, "w")
    except (av.error.FFmpegError, ValueError):
        return False
    return True


def _frame_rate(info: SourceInfo) -> float:
    if info.average_rate and info.average_rate > 0:
        return float(info.average_rate)
    if info.duration_s and info.frames_declared:
        return info.frames_declared / info.duration_s
    return 25.0


def crf_for_source(encoder: str, bits_per_pixel: float | None) -> int | None:
    """CRF close to the source's quality: more source bits per pixel -> lower CRF, capped at the
    highest CRF where the patch was measured to survive this encoder."""
    model = _CRF_MODEL.get(encoder)
    if model is None:
        return None
    base, lowest, ceiling = model
    if not bits_per_pixel or bits_per_pixel <= 0:
        return min(int(round(base)), ceiling)
    crf = base - _CRF_STEP_ON_RETRY * math.log2(bits_per_pixel / _BPP_REFERENCE)
    return int(min(max(round(crf), lowest), ceiling))


def choose_encoder(info: SourceInfo, options: VideoOptions, crf_shift: int = 0) -> EncoderChoice:
    """Same codec where this build can write it; CRF from the source bitrate (see crf_for_source)."""
    wanted = _ENCODER_BY_CODEC.get(info.codec)
    same = wanted is not None and _encoder_available(wanted)
    encoder = wanted if same and wanted else _FALLBACK_ENCODER_BY_MUXER[info.muxer]
    odd_420 = (info.width % 2 or info.height % 2) and info.pix_fmt.startswith(("yuv420", "yuvj420", "nv12"))
    if not same and encoder == "libx264" and odd_420 and info.muxer == "matroska":
        # x264 cannot code odd sizes in 4:2:0; Matroska also takes VP9, which can.
        encoder = "libvpx-vp9"
    bpp = None
    if info.bit_rate:
        bpp = info.bit_rate / (info.width * info.height * _frame_rate(info))
    crf = options.crf_override if options.crf_override is not None else crf_for_source(encoder, bpp)
    if crf is not None:
        crf = max(0, crf - crf_shift)
    opts: dict[str, str] = {}
    bit_rate: int | None = None
    # x264/x265 keep rc-lookahead frames in flight (40 at preset medium): 1.48 GB peak RSS on
    # 3840x2160, 0.75 GB with 10 (measured, docs/VIDEO.md "Memory"). Above 1080p the lookahead
    # is cut to 10; at or below 1080p (every quality figure in docs/VIDEO.md) nothing changes.
    short_lookahead = info.width * info.height > _FULL_LOOKAHEAD_MAX_PIXELS
    if encoder == "libx264":
        opts = {"crf": str(crf), "preset": options.preset}
        if short_lookahead:
            opts["rc-lookahead"] = str(_SHORT_LOOKAHEAD)
    elif encoder == "libx265":
        params = "log-level=error" + (f":rc-lookahead={_SHORT_LOOKAHEAD}" if short_lookahead else "")
        opts = {"crf": str(crf), "preset": options.preset, "x265-params": params}
    elif encoder == "libvpx-vp9":
        # b=0 with crf: constant quality; row-mt for threads at this resolution.
        opts = {"crf": str(crf), "b": "0", "deadline": "good", "cpu-used": "4", "row-mt": "1"}
    elif encoder == "libvpx":
        opts = {"crf": str(crf), "deadline": "good", "cpu-used": "4"}
        bit_rate = int((info.bit_rate or 2_000_000) * 2)
    elif encoder == "libsvtav1":
        opts = {"crf": str(crf), "preset": "8"}
    else:
        # Codecs without a CRF (mpeg4, ...): the source bitrate, doubled per retry.
        bit_rate = int((info.bit_rate or 2_000_000) * 1.25 * (2 ** (crf_shift // _CRF_STEP_ON_RETRY)))
    return EncoderChoice(encoder=encoder, crf=crf, bit_rate=bit_rate, options=opts, same_codec=same)


# ---- blending one frame -------------------------------------------------------------------


def plane_shifts(pix_fmt: str) -> list[tuple[int, int]] | None:
    """Per plane, log2 of its (horizontal, vertical) subsampling; None unless every component has
    its own plane (yuv*p*, gray*, gbrp*: the formats whose planes can be cut and pasted)."""
    fmt = av.VideoFormat(pix_fmt, 64, 64)
    if fmt.is_big_endian or fmt.has_palette or fmt.is_bit_stream:
        return None
    planes = [c.plane for c in fmt.components]
    if len(set(planes)) != len(planes):
        return None
    shifts: dict[int, tuple[int, int]] = {}
    for c in fmt.components:
        shifts[c.plane] = (int(round(math.log2(64 / c.width))), int(round(math.log2(64 / c.height))))
    return [shifts[i] for i in range(len(shifts))]


def _sample_dtype(fmt: av.VideoFormat) -> np.dtype:
    return np.dtype(np.uint16) if fmt.components[0].bits > 8 else np.dtype(np.uint8)


def _plane_array(frame: av.VideoFrame, index: int, dtype: np.dtype) -> np.ndarray:
    """A writable 2-D view (rows x samples) of one plane, padding columns excluded."""
    plane = frame.planes[index]
    row = plane.line_size // dtype.itemsize
    data = np.frombuffer(plane, dtype=dtype)
    return data[: plane.height * row].reshape(plane.height, row)[:, : plane.width]


def _rgb_format(dtype: np.dtype) -> str:
    return "rgb48le" if dtype == np.uint16 else "rgb24"


def _color_args(frame: av.VideoFrame) -> tuple[Colorspace, ColorRange]:
    """swscale matrix and range matching the frame's tags (the round trip uses the same pair)."""
    cs = {
        1: Colorspace.ITU709,
        4: Colorspace.FCC,
        7: Colorspace.SMPTE240M,
        9: Colorspace.BT2020,
        10: Colorspace.BT2020,
    }.get(int(frame.colorspace), Colorspace.ITU601)
    if frame.format.name.startswith("yuvj") or int(frame.color_range) == 2:
        rng = ColorRange.JPEG
    else:
        rng = ColorRange.MPEG
    return cs, rng


def blend_frame(frame: av.VideoFrame, placement: PatchPlacement) -> av.VideoFrame:
    """Blend the patch into a (writable) decoded frame and return the frame to encode.

    Planar YUV/gray: the region around the patch, widened to the chroma grid, is converted to
    RGB, blended by apply_patch, converted back with the frame's own matrix and range, and only
    the samples covering the patch are written back. Other formats: the whole frame goes
    through RGB (packed RGB formats convert losslessly).
    """
    fmt = frame.format
    dtype = _sample_dtype(fmt)
    shifts = plane_shifts(fmt.name)
    if shifts is None:
        # Packed / semi-planar formats (rare in files): the whole frame through RGB and back.
        back = _rgb_to_frame(apply_patch(frame_to_rgb(frame), placement), fmt.name, frame)
        back.pts, back.time_base, back.duration = frame.pts, frame.time_base, frame.duration
        return back

    sx = max(s[0] for s in shifts)
    sy = max(s[1] for s in shifts)
    x0, y0, x1, y1 = placement.box
    # Region on the chroma grid, clipped to the frame (odd sizes: last chroma sample is partial).
    rx0, ry0 = (x0 >> sx) << sx, (y0 >> sy) << sy
    rx1 = min(frame.width, -(-x1 >> sx) << sx)
    ry1 = min(frame.height, -(-y1 >> sy) << sy)
    region = av.VideoFrame(rx1 - rx0, ry1 - ry0, fmt.name)
    for i, (px, py) in enumerate(shifts):
        src = _plane_array(frame, i, dtype)
        dst = _plane_array(region, i, dtype)
        dst[:] = src[ry0 >> py : (ry0 >> py) + dst.shape[0], rx0 >> px : (rx0 >> px) + dst.shape[1]]
    region.colorspace, region.color_range = frame.colorspace, frame.color_range
    rgb = frame_to_rgb(region)
    local = dataclasses.replace(placement, x=x0 - rx0, y=y0 - ry0)
    blended = apply_patch(rgb, local)
    back = _rgb_to_frame(blended, fmt.name, frame)
    for i, (px, py) in enumerate(shifts):
        # Full-resolution planes: exactly the patch box; subsampled planes: samples touching it.
        bx0, by0 = (x0 - rx0) >> px, (y0 - ry0) >> py
        bx1, by1 = -(-(x1 - rx0) >> px), -(-(y1 - ry0) >> py)
        ox, oy = rx0 >> px, ry0 >> py
        src = _plane_array(back, i, dtype)
        dst = _plane_array(frame, i, dtype)
        dst[oy + by0 : oy + by1, ox + bx0 : ox + bx1] = src[by0:by1, bx0:bx1]
    return frame


# ---- measuring the patch ------------------------------------------------------------------


def _rgb_to_frame(rgb: np.ndarray, pix_fmt: str, like: av.VideoFrame) -> av.VideoFrame:
    """RGB array -> frame in pix_fmt with like's matrix and range (the inverse of frame_to_rgb)."""
    frame = av.VideoFrame.from_ndarray(rgb, format=_rgb_format(rgb.dtype))
    if av.VideoFormat(pix_fmt, 2, 2).is_rgb:
        return frame.reformat(format=pix_fmt)
    cs, rng = _color_args(like)
    out = frame.reformat(
        format=pix_fmt,
        src_colorspace=cs,
        dst_colorspace=cs,
        src_color_range=ColorRange.JPEG,
        dst_color_range=rng,
    )
    out.colorspace, out.color_range = like.colorspace, like.color_range
    return out


def frame_to_rgb(frame: av.VideoFrame) -> np.ndarray:
    """RGB array of a decoded frame, uint8 (8-bit sources) or uint16 (deeper sources)."""
    dtype = np.dtype(np.uint16) if frame.format.components[0].bits > 8 else np.dtype(np.uint8)
    if frame.format.is_rgb and not frame.format.name.startswith("gbrp"):
        return frame.to_ndarray(format=_rgb_format(dtype))
    cs, rng = _color_args(frame)
    return frame.to_ndarray(
        format=_rgb_format(dtype),
        src_colorspace=cs,
        dst_colorspace=cs,
        src_color_range=rng,
        dst_color_range=ColorRange.JPEG,
    )


def patch_contrast(rgb: np.ndarray, placement: PatchPlacement) -> float:
    """Mean bright-block minus mean dark-block intensity inside the patch, on a 0..255 scale."""
    x0, y0, x1, y1 = placement.box
    region = rgb[y0:y1, x0:x1].astype(np.float64)
    if region.ndim == 3:
        region = region.mean(axis=2)
    if rgb.dtype == np.uint16:
        region = region / 257.0
    levels = patch_values(placement, 255)
    dark = levels < levels.max()
    if not dark.any() or dark.all():
        return 0.0
    return float(region[~dark].mean() - region[dark].mean())


def intended_contrast(placement: PatchPlacement) -> float:
    """The bright-minus-dark difference the blend puts into a flat region (0..255 scale)."""
    return placement.alpha8 / 255.0 * placement.contrast


# ---- writing ------------------------------------------------------------------------------


def _file_state(path: Path) -> tuple[int, int]:
    st = path.stat()
    return st.st_size, st.st_mtime_ns


def _copy_metadata(
    src: dict[str, str], dst_obj: object, keep_location: bool = True, removed: list[str] | None = None
) -> None:
    """Copy tags, except FFmpeg's own and (unless keep_location) those naming a place."""
    skip = {
        "encoder",
        "duration",
        "rotate",
        "_statistics_tags",
        "major_brand",
        "minor_version",
        "compatible_brands",
    }
    for key, value in src.items():
        if (
            key.lower() in skip
            or key.upper().startswith("_STATISTICS")
            or key.upper() in {"DURATION", "ENCODER"}
        ):
            continue
        if not keep_location and location.is_location_tag(key):
            if removed is not None:
                removed.append(f"tag {key}")
            continue
        if key.upper() == provenance.MKV_TAG:
            continue  # an older marker: the new one (if any) is written by _encode_once
        try:
            dst_obj.metadata[key] = value  # type: ignore[attr-defined]
        except (ValueError, TypeError):
            continue


def _configure_video_stream(
    out: av.container.OutputContainer, info: SourceInfo, choice: EncoderChoice, options: VideoOptions
) -> av.video.stream.VideoStream:
    rate = info.average_rate if info.average_rate and info.average_rate > 0 else None
    stream = out.add_stream(choice.encoder, rate=rate, options=dict(choice.options))
    cc = stream.codec_context
    stream.width, stream.height = info.width, info.height
    stream.pix_fmt = info.pix_fmt
    if info.pix_fmt not in {f.name for f in (cc.codec.video_formats or [])}:
        raise VideoFormatError(
            f"encoder {choice.encoder} cannot write pixel format {info.pix_fmt} ({info.width}x{info.height})"
        )
    stream.time_base = info.time_base
    cc.time_base = info.time_base
    if rate:
        cc.framerate = rate
    cc.color_range = info.color_range
    cc.colorspace = info.colorspace
    cc.color_primaries = info.color_primaries
    cc.color_trc = info.color_trc
    if options.threads:
        cc.thread_count = options.threads
    if choice.bit_rate:
        cc.bit_rate = choice.bit_rate
    if info.display_matrix is not None:
        stream.set_display_matrix(list(info.display_matrix))
    return stream


def _x265_hdr_params(hdr: dict[str, bytes]) -> str:
    """x265-params for the source's mastering display and light level (HDR10 static metadata)."""
    parts: list[str] = []
    md = hdr.get("MASTERING_DISPLAY_METADATA")
    if md and len(md) >= 88:
        v = np.frombuffer(md[:88], "<i4")
        rat = [v[i] / v[i + 1] if v[i + 1] else 0.0 for i in range(0, 20, 2)]
        (rx, ry, gx, gy, bx, by, wx, wy, lmin, lmax) = rat
        has_primaries, has_luminance = int(v[20]), int(v[21])
        if has_primaries and has_luminance:
            c = lambda q: int(round(q * 50000))  # noqa: E731 - x265 chromaticity unit 0.00002
            parts.append(
                f"master-display=G({c(gx)},{c(gy)})B({c(bx)},{c(by)})R({c(rx)},{c(ry)})"
                f"WP({c(wx)},{c(wy)})L({int(round(lmax * 10000))},{int(round(lmin * 10000))})"
            )
    cll = hdr.get("CONTENT_LIGHT_LEVEL")
    if cll and len(cll) >= 8:
        max_cll, max_fall = np.frombuffer(cll[:8], "<u4")
        parts.append(f"max-cll={int(max_cll)},{int(max_fall)}")
    return ":".join(parts)


def _iter_packets(container: av.container.InputContainer, name: str) -> Iterator[av.Packet]:
    try:
        yield from container.demux()
    except av.error.FFmpegError as exc:
        raise VideoFormatError(f"{name}: corrupt or truncated container ({_one_line(exc)})") from exc


def _decode(packet: av.Packet, name: str) -> list[av.VideoFrame]:
    try:
        return list(packet.decode())
    except av.error.FFmpegError as exc:
        raise VideoFormatError(f"{name}: corrupt video data ({_one_line(exc)})") from exc


PlacementAt = Callable[[int], PatchPlacement]  # frame number -> where the patch goes


def frame_placements(spec: PatchSpec, info: SourceInfo, options: VideoOptions) -> PlacementAt:
    """Where frame i's patch goes: one placement for a static spec, a point on the path per frame
    for a moving one (module docstring). Raises SpecError when a placement does not fit."""
    first = spec.resolve(info.width, info.height, index=0.0)
    if not spec.moves or options.motion_steps_per_second <= 0:
        return lambda _i: first
    per_frame = options.motion_steps_per_second / _frame_rate(info)
    return lambda i: spec.resolve(info.width, info.height, index=i * per_frame)


@dataclass
class _EncodeResult:
    frames: int
    frames_patched: int
    end_s: float | None


def _encode_once(
    src: Path,
    dst: Path,
    spec: PatchSpec,
    placement_at: PlacementAt,
    info: SourceInfo,
    choice: EncoderChoice,
    options: VideoOptions,
    progress: ProgressCallback | None,
    report: VideoReport,
    marker: Marker | None = None,
    keep_location: bool = True,
) -> _EncodeResult:
    total = info.frames_declared or (
        int(round(info.duration_s * _frame_rate(info))) if info.duration_s else None
    )
    frames = patched = 0
    last_end: float | None = None
    opts = _MUXER_OPTIONS.get(info.muxer)
    with _open_input(src) as inp, av.open(str(dst), "w", format=info.muxer, container_options=opts) as out:
        removed: list[str] = []
        _copy_metadata(dict(inp.metadata), out, keep_location, removed)
        if marker is not None and info.muxer in ("matroska", "webm"):
            out.metadata[provenance.MKV_TAG] = marker.to_json().decode()
        vin = inp.streams[info.stream_index]
        vin.thread_type = "AUTO"
        if choice.encoder == "libx265" and info.hdr_side_data:
            hdr = _x265_hdr_params(info.hdr_side_data)
            if hdr:
                choice.options["x265-params"] = choice.options["x265-params"] + ":" + hdr
        vout = _configure_video_stream(out, info, choice, options)
        _copy_metadata(dict(vin.metadata), vout, keep_location, removed)
        copied: dict[int, av.stream.Stream] = {}
        for s in inp.streams:
            if s.index == info.stream_index:
                continue
            tag = _codec_tag(s)
            if not keep_location and s.type == "data" and tag in location.LOCATION_DATA_CODEC_TAGS:
                removed.append(f"{tag} telemetry stream #{s.index}")
                continue
            try:
                o = out.add_stream_from_template(s)
            except (av.error.FFmpegError, ValueError, TypeError) as exc:
                raise VideoFormatError(
                    f"{src.name}: stream #{s.index} ({s.type}) cannot be copied into {info.muxer} "
                    f"({_one_line(exc)})"
                ) from exc
            _copy_metadata(dict(s.metadata), o, keep_location, removed)
            o.disposition = s.disposition
            copied[s.index] = o

        def encode(frame: av.VideoFrame | None) -> None:
            for pkt in vout.encode(frame):
                out.mux(pkt)

        for packet in _iter_packets(inp, src.name):
            idx = packet.stream.index
            if idx == info.stream_index:
                for frame in _decode(packet, src.name):
                    if frame.is_corrupt:
                        raise VideoFormatError(
                            f"{src.name}: corrupt frame {frames} (damaged or truncated data)"
                        )
                    if (frame.width, frame.height) != (info.width, info.height):
                        raise VideoFormatError(
                            f"{src.name}: frame size changes mid-stream ({info.width}x{info.height} -> "
                            f"{frame.width}x{frame.height}); not supported"
                        )
                    if spec.selects(f"frame:{frames}"):
                        frame.make_writable()
                        try:
                            placement = placement_at(frames)
                        except SpecError as exc:
                            raise VideoFormatError(f"{src.name}: frame {frames}: {exc}") from exc
                        frame = blend_frame(frame, placement)
                        patched += 1
                    if frame.pts is not None and frame.time_base is not None:
                        end = frame.pts + (frame.duration or 0)
                        last_end = float(end * frame.time_base)
                    frame.pict_type = av.video.frame.PictureType.NONE
                    encode(frame)
                    frames += 1
                    if progress is not None:
                        progress(frames, total)
            elif idx in copied:
                if packet.dts is None and packet.size == 0:
                    continue  # demuxer flush packet
                packet.stream = copied[idx]
                out.mux(packet)
        encode(None)
    report.location_removed = removed
    return _EncodeResult(frames=frames, frames_patched=patched, end_s=last_end)


def _codec_tag(stream: av.stream.Stream) -> str:
    try:
        return str(stream.codec_tag or "").strip("\x00 ").lower()
    except (AttributeError, ValueError):
        return ""


def measure_video_patch(video: Path, placement: PatchPlacement | PlacementAt) -> list[float]:
    """Patch contrast (0..255 scale) of every decoded frame of a video, at one placement or at
    each frame's own (a moving spec)."""
    at = placement if callable(placement) else (lambda _i: placement)
    values: list[float] = []
    with _open_input(Path(video)) as container:
        stream = _main_video_stream(container, Path(video).name)
        stream.thread_type = "AUTO"
        for i, frame in enumerate(container.decode(stream)):
            values.append(patch_contrast(frame_to_rgb(frame), at(i)))
    return values


def _stream_bit_rate(video: Path) -> int | None:
    with _open_input(video) as container:
        s = _main_video_stream(container, video.name)
        total = 0
        for pkt in container.demux(s):
            total += pkt.size
        if s.duration and s.time_base:
            dur = float(s.duration * s.time_base)
        elif container.duration:
            dur = container.duration / av.time_base
        else:
            return None
        return int(total * 8 / dur) if dur > 0 else None


def poison_video(
    src: Path,
    dst: Path,
    spec: PatchSpec,
    progress: ProgressCallback | None = None,
    *,
    options: VideoOptions | None = None,
    marker: Marker | None = None,
    keep_location: bool = False,
    max_pixels: int | None = None,
) -> VideoReport:
    """Write src's video to dst with spec's patch in every selected frame; src is only read.

    Location tags (MP4 ©xyz/'location', Apple ISO6709, Matroska *LOCATION*) and GPS telemetry
    streams (GoPro gpmd, CAMM, Apple mebx) are left out unless keep_location. With a marker, dst
    carries it (poisoner.provenance: a uuid box in MP4/MOV, a PPD_PROVENANCE tag in Matroska).
    A frame size over max_pixels (default poisoner.limits.DEFAULT_MAX_VIDEO_PIXELS) is refused
    before any frame is decoded.

    dst receives the complete file (normally the temporary path of poisoner.atomic.atomic_output);
    on any error dst may hold a partial file that the caller discards. Raises VideoFormatError
    (one line) for input that cannot be poisoned faithfully.
    """
    src, dst = Path(src), Path(dst)
    options = options or VideoOptions()
    if not src.is_file():
        raise VideoFormatError(f"{src.name}: not a file")
    if src.stat().st_size == 0:
        raise VideoFormatError(f"{src.name}: empty file (still being written?)")
    state_before = _file_state(src)
    info = probe(src, max_pixels=max_pixels)
    try:
        placement_at = frame_placements(spec, info, options)
        placement = placement_at(0)
    except SpecError as exc:
        raise VideoFormatError(f"{src.name}: {exc}") from exc
    report = VideoReport(
        format=info.muxer,
        width=info.width,
        height=info.height,
        placement=placement,
        codec=info.codec,
        pix_fmt=info.pix_fmt,
        source_bit_rate=info.bit_rate,
    )
    if spec.moves and options.motion_steps_per_second > 0:
        report.notes.append(
            f"moving spec: the patch travels its path at {options.motion_steps_per_second:g} "
            "photo-steps per second; `placement` is frame 0's"
        )
    elif spec.moves:
        report.notes.append(
            "moving spec with motion_steps_per_second = 0: the patch stays at its first position in "
            "every frame (COLMAP's stationary-match filter can remove it from extracted frames)"
        )
    target = intended_contrast(placement)
    attempts = 0
    shift = 0
    while True:
        attempts += 1
        choice = choose_encoder(info, options, crf_shift=shift)
        log.info(
            "video encode",
            extra={"src": str(src), "encoder": choice.encoder, "crf": choice.crf, "attempt": attempts},
        )
        try:
            result = _encode_once(
                src, dst, spec, placement_at, info, choice, options, progress, report, marker, keep_location
            )
        except av.error.FFmpegError as exc:
            raise VideoFormatError(
                f"{src.name}: cannot encode with {choice.encoder} ({_one_line(exc)})"
            ) from exc
        _check_complete(src, info, result)
        if not options.verify_patch or result.frames_patched == 0 or target <= 0:
            break
        measured = [v / target for v in measure_video_patch(dst, placement_at)]
        selected = [m for i, m in enumerate(measured) if spec.selects(f"frame:{i}")]
        report.patch_contrast_min = min(selected) if selected else None
        report.patch_contrast_mean = float(np.mean(selected)) if selected else None
        if report.patch_contrast_min is None or report.patch_contrast_min >= options.min_patch_contrast:
            break
        if attempts > options.max_retries or (choice.crf is not None and choice.crf == 0):
            report.notes.append(
                f"patch contrast after encoding is {report.patch_contrast_min:.2f} of intended "
                f"(below {options.min_patch_contrast}) after {attempts} attempts"
            )
            break
        shift += _CRF_STEP_ON_RETRY
    if _file_state(src) != state_before:
        raise VideoFormatError(f"{src.name}: changed while being read (still being written?)")
    report.encoder = choice.encoder
    report.crf = choice.crf
    report.attempts = attempts
    report.frames = result.frames
    report.frames_patched = result.frames_patched
    report.duration_s = info.duration_s
    report.output_bit_rate = _stream_bit_rate(dst)
    report.preserved = _preserved_list(info, choice)
    if report.location_removed:
        report.notes.append(
            f"location removed ({len(report.location_removed)}): " + ", ".join(report.location_removed)
        )
    if marker is not None and info.muxer in ("mp4", "mov"):
        # Appended after the last box: nothing in the file points past it, so no offset moves.
        with open(dst, "ab") as f:
            f.write(provenance.mp4_box(marker))
    if not choice.same_codec:
        report.notes.append(f"no {info.codec} encoder in this build; re-encoded as {choice.encoder}")
    if info.hdr_side_data and choice.encoder != "libx265":
        report.notes.append(
            "HDR mastering/light-level metadata not carried ("
            f"{choice.encoder} takes it only through x265-params here)"
        )
    return report


def _check_complete(src: Path, info: SourceInfo, result: _EncodeResult) -> None:
    if result.frames == 0:
        raise VideoFormatError(f"{src.name}: no frames decoded")
    if info.frames_declared and result.frames < info.frames_declared:
        raise VideoFormatError(
            f"{src.name}: truncated: {result.frames} of {info.frames_declared} declared frames decode"
        )
    if info.duration_s and result.end_s is not None and result.end_s < 0.9 * info.duration_s - 0.1:
        raise VideoFormatError(
            f"{src.name}: truncated: frames end at {result.end_s:.2f} s of a declared {info.duration_s:.2f} s"
        )


def _preserved_list(info: SourceInfo, choice: EncoderChoice) -> list[str]:
    kept = [
        "frame timestamps (rate, time base, duration)",
        "frame count",
        f"pixel format {info.pix_fmt}",
        "colour tags (range, matrix, primaries, transfer)",
        "audio/subtitle/data packets (copied)",
        "container and stream metadata",
    ]
    if choice.same_codec:
        kept.append(f"codec {info.codec}")
    if info.display_matrix is not None:
        kept.append(f"display matrix (rotation {info.rotation} deg)")
    if info.hdr_side_data and choice.encoder == "libx265":
        kept.append("HDR10 mastering display / content light level")
    return kept


# ---- frame sets ---------------------------------------------------------------------------


def default_every_k(frame_rate: float | None) -> int:
    """About two frames per second: consecutive samples overlap enough for sequential matching."""
    if not frame_rate or frame_rate <= 0:
        return 1
    return max(1, int(round(frame_rate / 2.0)))


def sample_frames(video: Path, out_dir: Path, every_k: int | None = None) -> list[Path]:
    """Write every k-th frame of video as PNG (stored pixel orientation) to out_dir.

    Names are frame_000000.png with the frame's index in the video, so sorting them keeps
    the time order (what COLMAP's sequential matcher expects).
    """
    from PIL import Image  # PIL only where frames are written

    video, out_dir = Path(video), Path(out_dir)
    if every_k is not None and every_k < 1:
        raise ValueError(f"every_k must be >= 1, got {every_k}")
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    with _open_input(video) as container:
        stream = _main_video_stream(container, video.name)
        stream.thread_type = "AUTO"
        rate = float(stream.average_rate) if stream.average_rate else None
        k = every_k or default_every_k(rate)
        try:
            for index, frame in enumerate(container.decode(stream)):
                if index % k:
                    continue
                rgb = frame_to_rgb(frame)
                if rgb.dtype == np.uint16:
                    rgb = ((rgb.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
                path = out_dir / f"frame_{index:06d}.png"
                Image.fromarray(rgb).save(path)
                written.append(path)
        except av.error.FFmpegError as exc:
            raise VideoFormatError(f"{video.name}: corrupt video data ({_one_line(exc)})") from exc
    return written
