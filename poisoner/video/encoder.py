"""The encoder model: which encoder writes the output, at which CRF, with which options, and the
output video stream configured like the source (size, pixel format, time base, colour tags,
rotation)."""

from __future__ import annotations

import math
from typing import cast

import av
import av.error

from poisoner.video.errors import VideoFormatError
from poisoner.video.model import EncoderChoice, SourceInfo, VideoOptions, frame_rate

# Source codec -> encoder of this PyAV build that writes the same codec.
_ENCODER_BY_CODEC = {
    "h264": "libx264",
    "hevc": "libx265",
    "vp9": "libvpx-vp9",
    "vp8": "libvpx",
    "av1": "libsvtav1",
    "mpeg4": "mpeg4",
    "prores": "prores_ks",
}

# ProRes profile by sample-entry tag (MOV, and Matroska's CodecPrivate): prores_ks's profile names.
# The profile sets ProRes's quality (bits per macroblock), as a CRF does for the others.
PRORES_PROFILE_BY_TAG = {
    "apco": "proxy",
    "apcs": "lt",
    "apcn": "standard",
    "apch": "hq",
    "ap4h": "4444",
    "ap4x": "4444xq",
}
_PRORES_PROFILE_BY_NAME = {"Proxy": "proxy", "LT": "lt", "Standard": "standard", "HQ": "hq", "4444": "4444"}

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
CRF_STEP_ON_RETRY = 6

# Encoders given the source's frame types (I, P, B), where that was measured smaller at no loss outside
# the mark (bench/results/video.md, "Size of a patched video"). x265 given them was smaller too, but
# 0.2 dB lower outside the mark: it keeps its own choice.
KEEP_FRAME_TYPES = frozenset({"libx264"})

# HEVC's sample entry in MP4/MOV: FFmpeg writes `hev1` unless told; Apple's players (QuickTime, iOS,
# Safari) play HEVC only under `hvc1`, what iPhones write (black-box review 9). A `hev1` source stays so.
_HEVC_TAGS = ("hvc1", "hev1")
_MP4_MUXERS = ("mp4", "mov")

_FULL_LOOKAHEAD_MAX_PIXELS = 1920 * 1088
_SHORT_LOOKAHEAD = 10


def _encoder_available(name: str) -> bool:
    try:
        av.codec.Codec(name, "w")
    except (av.error.FFmpegError, ValueError):
        return False
    return True


def crf_for_source(encoder: str, bits_per_pixel: float | None) -> int | None:
    """CRF close to the source's quality: more source bits per pixel -> lower CRF, capped at the
    highest CRF where the patch was measured to survive this encoder."""
    model = _CRF_MODEL.get(encoder)
    if model is None:
        return None
    base, lowest, ceiling = model
    if not bits_per_pixel or bits_per_pixel <= 0:
        return min(int(round(base)), ceiling)
    crf = base - CRF_STEP_ON_RETRY * math.log2(bits_per_pixel / _BPP_REFERENCE)
    return int(min(max(round(crf), lowest), ceiling))


def choose_encoder(info: SourceInfo, options: VideoOptions, crf_shift: int = 0) -> EncoderChoice:
    """Same codec where this build can write it; CRF from the source bitrate (see crf_for_source),
    never coarser than the CRF the source's encoder recorded (x264, x265)."""
    wanted = _ENCODER_BY_CODEC.get(info.codec)
    same = wanted is not None and _encoder_available(wanted)
    encoder = wanted if same and wanted else _FALLBACK_ENCODER_BY_MUXER[info.muxer]
    odd_420 = (info.width % 2 or info.height % 2) and info.pix_fmt.startswith(("yuv420", "yuvj420", "nv12"))
    if not same and encoder == "libx264" and odd_420 and info.muxer == "matroska":
        # x264 cannot code odd sizes in 4:2:0; Matroska also takes VP9, which can.
        encoder = "libvpx-vp9"
    bpp = None
    if info.bit_rate:
        bpp = info.bit_rate / (info.width * info.height * frame_rate(info))
    crf = options.crf_override if options.crf_override is not None else crf_for_source(encoder, bpp)
    if crf is not None and options.crf_override is None and same and info.encoded_crf is not None:
        # the source's own encoder said the quality it was made at (x264/x265 settings in the stream):
        # never coarser than that. The bit rate misjudges a fast preset (a CRF 20 clip at 0.04 bits
        # per pixel came out at CRF 28, PSNR 35 dB: a black-box review)
        crf = min(crf, int(round(info.encoded_crf)))
    if crf is not None:
        crf = max(0, crf - crf_shift)
    opts, bit_rate = _encoder_options(encoder, crf, info, options.preset, crf_shift)
    # The marked frames would make x264 choose P where the source's encoder chose B (the sliding mark
    # predicts badly across frames): 1.33x the size where the source's types give 1.09x, and no lower
    # quality outside the mark (bench/results/video.md). A source without B-frames (a phone's hardware
    # encoder, x264 ultrafast) leaves the encoder its own choice.
    keep = options.keep_frame_types and info.b_frames and encoder in KEEP_FRAME_TYPES
    return EncoderChoice(
        encoder=encoder, crf=crf, bit_rate=bit_rate, options=opts, same_codec=same, keep_frame_types=keep
    )


def _encoder_options(
    encoder: str, crf: int | None, info: SourceInfo, preset: str, crf_shift: int
) -> tuple[dict[str, str], int | None]:
    """(encoder options, bit rate or None) for a constant-quality encode at crf."""
    # x264/x265 keep rc-lookahead frames in flight (40 at preset medium): 1.48 GB peak RSS on
    # 3840x2160, 0.75 GB with 10 (measured, docs/VIDEO.md "Memory"). Above 1080p the lookahead
    # is cut to 10; at or below 1080p (every quality figure in docs/VIDEO.md) nothing changes.
    short_lookahead = info.width * info.height > _FULL_LOOKAHEAD_MAX_PIXELS
    if encoder == "libx264":
        opts = {"crf": str(crf), "preset": preset}
        if short_lookahead:
            opts["rc-lookahead"] = str(_SHORT_LOOKAHEAD)
        return opts, None
    if encoder == "libx265":
        params = "log-level=error" + (f":rc-lookahead={_SHORT_LOOKAHEAD}" if short_lookahead else "")
        return {"crf": str(crf), "preset": preset, "x265-params": params}, None
    if encoder == "libvpx-vp9":
        # b=0 with crf: constant quality; row-mt for threads at this resolution.
        return {"crf": str(crf), "b": "0", "deadline": "good", "cpu-used": "4", "row-mt": "1"}, None
    if encoder == "libvpx":
        return {"crf": str(crf), "deadline": "good", "cpu-used": "4"}, int((info.bit_rate or 2_000_000) * 2)
    if encoder == "libsvtav1":
        return {"crf": str(crf), "preset": "8"}, None
    if encoder == "prores_ks":
        return {"profile": prores_profile(info)}, None
    # Codecs without a CRF (mpeg4, ...): the source bitrate, doubled per retry.
    return {}, int((info.bit_rate or 2_000_000) * 1.25 * (2 ** (crf_shift // CRF_STEP_ON_RETRY)))


def prores_profile(info: SourceInfo) -> str:
    """The source's ProRes profile as prores_ks names it (its tag, else the decoder's profile name;
    "hq" where neither says: ProRes's usual master)."""
    by_tag = PRORES_PROFILE_BY_TAG.get(info.codec_tag.lower())
    return by_tag or _PRORES_PROFILE_BY_NAME.get(info.profile, "hq")


def quality_text(choice: EncoderChoice) -> str:
    """The quality an encode was made at, as the report says it: "CRF 18", "ProRes profile hq"."""
    if choice.crf is not None:
        return f"CRF {choice.crf}"
    if "profile" in choice.options:
        return f"ProRes profile {choice.options['profile']}"
    return f"{(choice.bit_rate or 0) // 1000} kbit/s"


def encoder_pix_fmt(encoder: str, pix_fmt: str) -> str | None:
    """The pixel format the encoder writes for a source decoded as pix_fmt: the same, else the same
    layout at 10 bits (the ProRes decoder gives 4444 as 12-bit, prores_ks takes 10-bit samples);
    None when the encoder takes neither."""
    formats = {f.name for f in (av.codec.Codec(encoder, "w").video_formats or [])}
    if pix_fmt in formats:
        return pix_fmt
    shallower = pix_fmt.replace("p12le", "p10le")
    return shallower if shallower in formats else None


def configure_video_stream(
    out: av.container.OutputContainer, info: SourceInfo, choice: EncoderChoice, options: VideoOptions
) -> av.video.stream.VideoStream:
    """The output's video stream: choice's encoder with the source's size, pixel format, time
    base, frame rate, colour tags and display matrix."""
    rate = info.average_rate if info.average_rate and info.average_rate > 0 else None
    stream = cast(  # a video encoder's stream
        av.video.stream.VideoStream, out.add_stream(choice.encoder, rate=rate, options=dict(choice.options))
    )
    cc = stream.codec_context
    stream.width, stream.height = info.width, info.height
    pix_fmt = encoder_pix_fmt(choice.encoder, info.pix_fmt)
    if pix_fmt is None:
        raise VideoFormatError(
            f"encoder {choice.encoder} cannot write pixel format {info.pix_fmt} ({info.width}x{info.height})"
        )
    stream.pix_fmt = pix_fmt  # the encoder converts each frame to it (poisoner.video.transcode)
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
    if choice.encoder == "libx265" and info.muxer in _MP4_MUXERS:
        stream.codec_tag = info.codec_tag if info.codec_tag in _HEVC_TAGS else "hvc1"
    return stream
