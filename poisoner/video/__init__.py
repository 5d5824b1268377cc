"""Videos: the dataset's one patch blended into every frame, in stored pixel coordinates.

The video stays a video: decoded with PyAV, every frame gets `apply_patch` at the placement
`frame_placements` gives (`PatchSpec.resolve(width, height)`, identical for every frame, for a
static spec; a point on the path per frame for a moving one), and the frames are re-encoded
with the source's codec (where this PyAV build has an encoder for it), pixel format, frame
timestamps (so frame rate, variable frame rate, time base, duration and frame count are kept),
rotation and colour tags. Audio, subtitle and data streams are copied packet by packet (bit-identical);
a cover picture is marked as a photo is, or left out (cover.py).

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

The stages, one module each (data flows top to bottom; poison_video in driver.py runs them):
- source.py     probe: SourceInfo of the source (container, codec, size, timing, rotation, colour, HDR);
                the frame-size budget (poisoner.limits) is checked from the header.
- encoder.py    the encoder model: same codec where possible, CRF from the source's bits per pixel,
                the output stream configured like the source.
- blend.py      one frame: the patch region to RGB, apply_patch, the covering samples written back.
- cover.py      cover pictures (MP4 covr, Matroska image attachments): marked by the image path, or left out.
- transcode.py  one encode pass: decode, blend, encode, copy the other streams packet by packet.
- contrast.py   the patch contrast measured on the decoded output (drives the retry).
- metadata.py   tags, GPS telemetry streams, HDR for x265, the provenance marker, `preserved`.
- driver.py     poison_video: source checks, placements per frame, encode-until-visible, report.
- frames.py     sample_frames / default_every_k: the verifier's frame sets.
- model.py, errors.py, demux.py: the data passed between stages, the one-line error, reading.

Names load on first use (PEP 562): catching VideoFormatError or reading VideoOptions does not
import PyAV.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from poisoner.video.blend import blend_frame, frame_to_rgb, plane_shifts
    from poisoner.video.contrast import intended_contrast, measure_video_patch, patch_contrast
    from poisoner.video.driver import frame_placements, poison_video
    from poisoner.video.encoder import choose_encoder, crf_for_source
    from poisoner.video.errors import VideoFormatError
    from poisoner.video.frames import default_every_k, sample_frames
    from poisoner.video.model import (
        EncoderChoice,
        PlacementAt,
        ProgressCallback,
        SourceInfo,
        VideoOptions,
        VideoReport,
    )
    from poisoner.video.source import probe

_HOME = {
    "VideoFormatError": "errors",
    "EncoderChoice": "model",
    "PlacementAt": "model",
    "ProgressCallback": "model",
    "SourceInfo": "model",
    "VideoOptions": "model",
    "VideoReport": "model",
    "probe": "source",
    "choose_encoder": "encoder",
    "crf_for_source": "encoder",
    "blend_frame": "blend",
    "frame_to_rgb": "blend",
    "plane_shifts": "blend",
    "intended_contrast": "contrast",
    "measure_video_patch": "contrast",
    "patch_contrast": "contrast",
    "frame_placements": "driver",
    "poison_video": "driver",
    "default_every_k": "frames",
    "sample_frames": "frames",
}
__all__ = [
    "EncoderChoice",
    "PlacementAt",
    "ProgressCallback",
    "SourceInfo",
    "VideoFormatError",
    "VideoOptions",
    "VideoReport",
    "blend_frame",
    "choose_encoder",
    "crf_for_source",
    "default_every_k",
    "frame_placements",
    "frame_to_rgb",
    "intended_contrast",
    "measure_video_patch",
    "patch_contrast",
    "plane_shifts",
    "poison_video",
    "probe",
    "sample_frames",
]


def __getattr__(name: str) -> Any:
    if name in _HOME:
        value = getattr(importlib.import_module(f"poisoner.video.{_HOME[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'poisoner.video' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_HOME])
