"""Generated test videos (PyAV): a textured scene panning under a fixed camera, with a sine tone."""

from __future__ import annotations

import io
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np
from PIL import Image


def mux_rgb_frames(out: Any, stream: Any, frames: Iterable[np.ndarray]) -> None:
    """Encode RGB frames (pts 0, 1, ...) into stream as yuv420p, then flush the encoder."""
    for i, rgb in enumerate(frames):
        frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
        frame.pts = i
        for pkt in stream.encode(frame.reformat(format="yuv420p")):
            out.mux(pkt)
    for pkt in stream.encode(None):
        out.mux(pkt)


def mux_sine(
    out: Any,
    aud: Any,
    samples: int,
    *,
    hz: float,
    amplitude: float,
    fmt: str,
    layout: str,
    fallback_step: int = 1024,
) -> None:
    """A 48 kHz sine tone of `samples` samples per channel into the audio stream aud (the same
    wave in every channel of layout, "mono" or "stereo"), then flush the encoder."""
    rate, t = 48000, 0
    step = aud.codec_context.frame_size or fallback_step
    channels = 2 if layout == "stereo" else 1
    while t < samples:
        wave = (amplitude * np.sin(2 * np.pi * hz * np.arange(t, t + step) / rate)).astype(np.float32)
        af = av.AudioFrame.from_ndarray(np.stack([wave] * channels), format=fmt, layout=layout)
        af.sample_rate, af.pts = rate, t
        for pkt in aud.encode(af):
            out.mux(pkt)
        t += step
    for pkt in aud.encode(None):
        out.mux(pkt)


@dataclass(frozen=True)
class Clip:
    """A generated test video: a textured scene panning under a fixed camera grid, with audio."""

    suffix: str = ".mp4"
    encoder: str = "libx264"
    pix_fmt: str = "yuv420p"
    width: int = 320
    height: int = 240
    fps: int = 20
    frames: int = 40
    audio: str | None = "aac"
    rotation: int | None = None
    pts: Sequence[int] | None = None  # explicit timestamps (variable frame rate)
    time_base: Fraction | None = None
    options: tuple[tuple[str, str], ...] = ()
    colour: tuple[int, int, int, int] | None = None  # range, space, primaries, trc
    cover: bytes | None = None  # a cover picture (JPEG or PNG file bytes): add_cover


def scene(width: int, height: int, index: int) -> np.ndarray:
    """A moving textured scene: a random block texture panning diagonally, plus a gradient."""
    rng = np.random.default_rng(7)
    tex = (rng.random((height // 4 + 40, width // 4 + 60, 3)) * 200 + 28).astype(np.uint8)
    tex = tex.repeat(4, 0).repeat(4, 1)
    dy, dx = index % 20, 3 * index
    return np.ascontiguousarray(tex[dy : dy + height, dx : dx + width])


def make_clip(path: Path, clip: Clip) -> Path:
    with av.open(str(path), "w") as out:
        vs = out.add_stream(clip.encoder, rate=clip.fps, options=dict(clip.options))
        vs.width, vs.height, vs.pix_fmt = clip.width, clip.height, clip.pix_fmt
        if clip.time_base is not None:
            vs.codec_context.time_base = clip.time_base
            vs.time_base = clip.time_base
        if clip.colour is not None:
            cc = vs.codec_context
            cc.color_range, cc.colorspace, cc.color_primaries, cc.color_trc = clip.colour
        if clip.rotation is not None:
            vs.set_display_rotation(clip.rotation)
        aud = None
        if clip.audio:
            aud = out.add_stream(clip.audio, rate=48000)
            aud.layout = "mono"
        if clip.cover is not None:
            add_cover(out, clip.cover)
        for i in range(clip.frames):
            rgb = scene(clip.width, clip.height, i)
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24").reformat(format=clip.pix_fmt)
            if clip.colour is not None:
                frame.color_range, frame.colorspace = clip.colour[0], clip.colour[1]
            frame.pts = clip.pts[i] if clip.pts is not None else i
            if clip.time_base is not None:
                frame.time_base = clip.time_base
            for pkt in vs.encode(frame):
                out.mux(pkt)
        for pkt in vs.encode(None):
            out.mux(pkt)
        if aud is not None:
            samples = int(clip.frames / clip.fps * 48000)
            mux_sine(out, aud, samples, hz=440, amplitude=0.3, fmt="flt", layout="mono", fallback_step=960)
    return path


def add_cover(out: Any, picture: bytes) -> None:
    """A cover picture as FFmpeg writes one, before any packet: MP4 an attached_pic stream whose one
    packet is the picture (the muxer writes it as `covr` when the file ends), Matroska an image
    attachment (written with the header). The mov muxer writes none (quicktime_branded makes a MOV)."""
    jpeg = picture.startswith(b"\xff\xd8")
    if out.format.name == "matroska":
        name, mime = ("cover.jpg", "image/jpeg") if jpeg else ("cover.png", "image/png")
        out.add_attachment(name, mime, picture)
        return
    with Image.open(io.BytesIO(picture)) as im:
        size = im.size
    stream = out.add_stream("mjpeg" if jpeg else "png")
    stream.width, stream.height = size
    stream.pix_fmt = "yuvj420p" if jpeg else "rgb24"
    stream.disposition = av.stream.Disposition.attached_pic
    packet = av.Packet(picture)
    packet.stream, packet.pts, packet.dts, packet.is_keyframe = stream, 0, 0, True
    out.mux(packet)


def quicktime_branded(mp4: Path, mov: Path) -> Path:
    """mp4's bytes as a QuickTime file (its ftyp brands `qt  `): how a MOV with a `covr` is made here,
    FFmpeg's mov muxer writing none. FFmpeg reads it as it reads any MOV."""
    data = bytearray(mp4.read_bytes())
    assert data[4:8] == b"ftyp" and int.from_bytes(data[:4], "big") == 32, "FFmpeg's 32-byte ftyp"
    data[8:32] = b"qt  \x00\x00\x02\x00" + b"qt  " * 4
    mov.write_bytes(data)
    return mov


# ---- reading them back --------------------------------------------------------------------


def telemetry_clip(path: Path, fourcc: bytes, size: tuple[int, int] = (320, 240), frames: int = 10) -> Path:
    """An MP4/MOV with a data track whose sample entry is fourcc (b"gpmd": a GoPro's GPS telemetry,
    b"camm", b"mebx"), besides its video: a clip muxed with a timecode track, that track's handler and
    sample entry then renamed (PyAV cannot write such a track itself; FFmpeg demuxes it as a data
    stream, as it does a camera's)."""
    import struct

    width, height = size
    with av.open(str(path), "w") as out:
        vs = out.add_stream("libx264", rate=10)
        vs.width, vs.height, vs.pix_fmt = width, height, "yuv420p"
        vs.metadata["timecode"] = "01:00:00:00"
        mux_rgb_frames(out, vs, (scene(width, height, i) for i in range(frames)))
    data = bytearray(path.read_bytes())

    def rename(start: int, end: int, in_tref: bool = False) -> None:
        at = start
        while at + 8 <= end:
            length, kind = struct.unpack(">I4s", data[at : at + 8])
            if length < 8:
                return
            if kind in (b"moov", b"trak", b"mdia", b"minf", b"stbl", b"tref"):
                rename(at + 8, at + length, kind == b"tref")
            elif kind == b"hdlr" and data[at + 16 : at + 20] == b"tmcd":
                data[at + 16 : at + 20] = b"meta"
            elif kind == b"stsd" and data[at + 20 : at + 24] == b"tmcd":
                data[at + 20 : at + 24] = fourcc
            elif kind == b"tmcd" and in_tref:  # the video's reference to the timecode track
                data[at + 4 : at + 8] = b"cdsc"
            at += length

    rename(0, len(data))
    path.write_bytes(bytes(data))
    return path
