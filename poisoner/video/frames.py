"""Frame sets for the verifier: every k-th frame of a video as PNG, in stored pixel orientation,
named by the frame's index so that sorting keeps the time order."""

from __future__ import annotations

from pathlib import Path

import av.error
import numpy as np

from poisoner.video.blend import frame_to_rgb
from poisoner.video.demux import main_video_stream, open_input
from poisoner.video.errors import VideoFormatError, one_line


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
    with open_input(video) as container:
        stream = main_video_stream(container, video.name)
        stream.thread_type = "AUTO"
        rate = float(stream.average_rate) if stream.average_rate else None
        k = every_k or default_every_k(rate)
        try:
            for index, frame in enumerate(container.decode(stream)):
                if index % k:
                    continue
                path = out_dir / f"frame_{index:06d}.png"
                Image.fromarray(_rgb8(frame_to_rgb(frame))).save(path)
                written.append(path)
        except av.error.FFmpegError as exc:
            raise VideoFormatError(f"{video.name}: corrupt video data ({one_line(exc)})") from exc
    return written


def _rgb8(rgb: np.ndarray) -> np.ndarray:
    """16-bit samples rounded to 8 bits (PNG frames for COLMAP are 8-bit)."""
    if rgb.dtype == np.uint16:
        return ((rgb.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    return rgb
