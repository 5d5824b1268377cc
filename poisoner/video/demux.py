"""Reading a video container: open it, find its one video stream, walk its packets and frames;
every FFmpeg failure becomes one VideoFormatError line."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import cast

import av
import av.error

from poisoner.media import SNIFF_BYTES, content_class
from poisoner.video.errors import VideoFormatError, one_line


def open_input(path: Path) -> av.container.InputContainer:
    try:
        return av.open(str(path), "r")
    except (av.error.FFmpegError, OSError, ValueError) as exc:
        raise VideoFormatError(f"{path.name}: not a readable video ({one_line(exc)})") from exc


def is_cover(stream: av.stream.Stream) -> bool:
    """A cover picture: a video stream of one still picture (`attached_pic`: an MP4's `covr`, a Matroska
    image attachment), not frames of the video; or a Matroska attachment whose bytes are a picture.
    FFmpeg makes an attached_pic only of a JPEG, PNG, GIF or TIFF type: a WebP, a BMP, an "image/jpg" or
    an octet-stream picture stays a plain attachment. A font or a subtitle file is no cover."""
    if isinstance(stream, av.stream.AttachmentStream):
        return content_class((stream.data or b"")[:SNIFF_BYTES]) is not None
    return stream.type == "video" and bool(stream.disposition & av.stream.Disposition.attached_pic)


# A VP8/VP9 video's alpha travels beside its frames (WebM BlockAdditional, flagged by the track's
# AlphaMode), which FFmpeg's own vp8/vp9 decoders ignore: libvpx decodes it (yuva420p).
_ALPHA_DECODERS = {"vp9": "libvpx-vp9", "vp8": "libvpx"}


def alpha_mode(stream: av.stream.Stream) -> bool:
    """Whether the stream says it carries alpha beside its frames (Matroska's AlphaMode 1)."""
    return any(key.lower() == "alpha_mode" and value == "1" for key, value in stream.metadata.items())


def video_decoder(stream: av.video.stream.VideoStream) -> av.video.codeccontext.VideoCodecContext:
    """The decoder for stream's frames: its own, or libvpx for a VP8/VP9 with alpha (where this build
    has it; without it the frames decode opaque)."""
    own = stream.codec_context
    name = _ALPHA_DECODERS.get(own.name)
    if name is None or not alpha_mode(stream):
        return own
    try:
        decoder = cast(av.video.codeccontext.VideoCodecContext, av.CodecContext.create(name, "r"))
    except (av.error.FFmpegError, ValueError):
        return own
    decoder.extradata = own.extradata
    decoder.thread_type = "AUTO"
    return decoder


def main_video_stream(container: av.container.InputContainer, name: str) -> av.video.stream.VideoStream:
    """The one video stream (cover art aside); several are refused."""
    streams = [s for s in container.streams.video if not is_cover(s)]
    if not streams:
        raise VideoFormatError(f"{name}: no video stream")
    if len(streams) > 1:
        raise VideoFormatError(f"{name}: {len(streams)} video streams; only single-video files are supported")
    return streams[0]


def audio_only(path: Path) -> bool:
    """Whether the container holds sound and no picture (a voice memo saved as .mp4): nothing a
    reconstruction reads. False when it cannot be read (the patch pass says why)."""
    try:
        with av.open(str(path), "r") as container:
            pictures = [s for s in container.streams.video if not is_cover(s)]
            return not pictures and bool(container.streams.audio)
    except (av.error.FFmpegError, OSError, ValueError):
        return False


def iter_packets(container: av.container.InputContainer, name: str) -> Iterator[av.Packet]:
    try:
        yield from container.demux()
    except av.error.FFmpegError as exc:
        raise VideoFormatError(f"{name}: corrupt or truncated container ({one_line(exc)})") from exc


def decode_packet(
    packet: av.Packet, name: str, decoder: av.video.codeccontext.VideoCodecContext
) -> list[av.VideoFrame]:
    try:
        return decoder.decode(packet)
    except av.error.FFmpegError as exc:
        raise VideoFormatError(f"{name}: corrupt video data ({one_line(exc)})") from exc


def stream_bit_rate(video: Path) -> int | None:
    """The video stream's mean bit rate from its packet sizes (None: no duration to divide by)."""
    with open_input(video) as container:
        s = main_video_stream(container, video.name)
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
