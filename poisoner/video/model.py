"""What the video stages pass each other: the options, what the source is, the encoder chosen and
the report. Plain data, no PyAV."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction

from poisoner.formats import PoisonReport
from poisoner.spec import PatchPlacement

ProgressCallback = Callable[[int, int | None], None]  # (frames done, frames expected or None)
PlacementAt = Callable[[int], PatchPlacement]  # frame number -> where the patch goes

_DEFAULT_FRAME_RATE = 25.0  # neither the container nor the frame count says

# A patched video this much larger than its source is said in `ppd poison`'s summary: re-encoding alone
# moves the size a few percent either way (bench/results/video.md), the mark costs more.
NOTICEABLE_GROWTH = 1.10


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
    keep_frame_types: x264 codes each frame as the source's (I, P or B) where the source has
      B-frames, instead of deciding again on the marked frames (docs/VIDEO.md "Size").
    """

    min_patch_contrast: float = 0.8
    verify_patch: bool = True
    max_retries: int = 2
    preset: str = "medium"
    threads: int = 0
    crf_override: int | None = None
    motion_steps_per_second: float = 6.0  # bench/results/video_motion.md: 2 failed twice, 6 never
    keep_frame_types: bool = True


@dataclass(frozen=True)
class EncoderChoice:
    encoder: str
    crf: int | None
    bit_rate: int | None
    options: dict[str, str]
    same_codec: bool
    keep_frame_types: bool = False  # each frame coded as the source's type (I, P, B)


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
    # the CRF the source's own encoder wrote in its stream (x264/x265 put their settings in an SEI
    # message of the first frame), or None: the quality it was made at, which ppd does not go below
    encoded_crf: float | None = None
    # the source reorders frames (B-frames): its encoder chose I, P and B for this content
    b_frames: bool = False
    # the stream's sample-entry tag in MP4/MOV ("hvc1", "hev1", "avc1", "apch", ...), "" where none
    codec_tag: str = ""
    # the container's tags include reverse-DNS keys (QuickTime `mdta`: com.apple.quicktime.make)
    mdta_tags: bool = False
    alpha_mode: bool = False  # the stream says it carries alpha beside its frames (WebM VP8/VP9)
    timecode: str = ""  # a timecode track's start ("01:00:00:00"), "" where the source has none
    profile: str = ""  # the decoder's name for the stream's profile ("HQ", "High 4:2:2"), "" where none


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
    source_bytes: int = 0  # the files' sizes: a creator with an upload limit is told the growth
    output_bytes: int = 0


def frame_rate(info: SourceInfo) -> float:
    """Frames per second: the stream's average rate, else frames over duration, else 25."""
    if info.average_rate and info.average_rate > 0:
        return float(info.average_rate)
    if info.duration_s and info.frames_declared:
        return info.frames_declared / info.duration_s
    return _DEFAULT_FRAME_RATE


def has_alpha(pix_fmt: str) -> bool:
    """Whether frames in pix_fmt carry an alpha plane (yuva420p, yuva444p12le, gbrap)."""
    return pix_fmt.startswith(("yuva", "gbrap"))


def size_text(n: int) -> str:
    """A size as a creator reads it: 640 bytes, 425 KB, 12.3 MB, 1.20 GB (powers of 1000, as upload
    limits); said of videos and of what `ppd dataset forget` frees ("0.0 MB" for 43 KB: a review)."""
    if n < 1000:
        return f"{n} bytes"
    if n < 1_000_000:
        return f"{n / 1000:.0f} KB"
    if n < 1_000_000_000:
        return f"{n / 1e6:.1f} MB"
    return f"{n / 1e9:.2f} GB"
