"""The patch contrast check: how much of the patch's bright-minus-dark difference survived the
encode, measured on the decoded output (poison_video re-encodes at a lower CRF below
VideoOptions.min_patch_contrast)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from poisoner.blend import patch_coverage, patch_values
from poisoner.spec import PatchPlacement
from poisoner.video.blend import frame_to_rgb
from poisoner.video.demux import main_video_stream, open_input
from poisoner.video.model import PlacementAt


def patch_contrast(rgb: np.ndarray, placement: PatchPlacement) -> float:
    """Mean bright-block minus mean dark-block intensity inside the patch, on a 0..255 scale."""
    x0, y0, x1, y1 = placement.box
    region = rgb[y0:y1, x0:x1].astype(np.float64)
    if region.ndim == 3:
        region = region.mean(axis=2)
    if rgb.dtype == np.uint16:
        region = region / 257.0
    levels = patch_values(placement, 255)
    written = patch_coverage(placement)  # lanes, turned or shaped marks leave part of their box alone
    dark = (levels < levels.max()) & written
    bright = ~(levels < levels.max()) & written
    if not dark.any() or not bright.any():
        return 0.0
    return float(region[bright].mean() - region[dark].mean())


def intended_contrast(placement: PatchPlacement) -> float:
    """The bright-minus-dark difference the blend puts into a flat region (0..255 scale)."""
    return placement.alpha8 / 255.0 * placement.contrast


def measure_video_patch(video: Path, placement: PatchPlacement | PlacementAt) -> list[float]:
    """Patch contrast (0..255 scale) of every decoded frame of a video, at one placement or at
    each frame's own (a moving spec)."""
    at = placement if callable(placement) else (lambda _i: placement)
    values: list[float] = []
    with open_input(Path(video)) as container:
        stream = main_video_stream(container, Path(video).name)
        stream.thread_type = "AUTO"
        for i, frame in enumerate(container.decode(stream)):
            values.append(patch_contrast(frame_to_rgb(frame), at(i)))
    return values
