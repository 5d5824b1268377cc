"""Blending one decoded frame: the region around the patch goes to RGB, `apply_patch` blends it
exactly as for images, and only the plane samples covering the patch are written back, so pixels
outside the patch are bit-identical before encoding. Also the frame <-> RGB conversions the
contrast check and the verifier's frame sampling use."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, cast

import av
import numpy as np
from av.video.reformatter import ColorRange, Colorspace

from poisoner.blend import apply_patch
from poisoner.spec import PatchPlacement


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
    data = np.frombuffer(cast(Any, plane), dtype=dtype)  # a plane is a buffer (not in PyAV's stubs)
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
    region = _cut_region(frame, (rx0, ry0, rx1, ry1), shifts, dtype)
    local = dataclasses.replace(placement, x=x0 - rx0, y=y0 - ry0)
    back = _rgb_to_frame(apply_patch(frame_to_rgb(region), local), fmt.name, frame)
    for i, (px, py) in enumerate(shifts):
        # Full-resolution planes: exactly the patch box; subsampled planes: samples touching it.
        bx0, by0 = (x0 - rx0) >> px, (y0 - ry0) >> py
        bx1, by1 = -(-(x1 - rx0) >> px), -(-(y1 - ry0) >> py)
        ox, oy = rx0 >> px, ry0 >> py
        src = _plane_array(back, i, dtype)
        dst = _plane_array(frame, i, dtype)
        dst[oy + by0 : oy + by1, ox + bx0 : ox + bx1] = src[by0:by1, bx0:bx1]
    return frame


def _cut_region(
    frame: av.VideoFrame, box: tuple[int, int, int, int], shifts: list[tuple[int, int]], dtype: np.dtype
) -> av.VideoFrame:
    """A new frame holding frame's samples inside box (on the chroma grid), with its colour tags."""
    rx0, ry0, rx1, ry1 = box
    region = av.VideoFrame(rx1 - rx0, ry1 - ry0, frame.format.name)
    for i, (px, py) in enumerate(shifts):
        src = _plane_array(frame, i, dtype)
        dst = _plane_array(region, i, dtype)
        dst[:] = src[ry0 >> py : (ry0 >> py) + dst.shape[0], rx0 >> px : (rx0 >> px) + dst.shape[1]]
    region.colorspace, region.color_range = frame.colorspace, frame.color_range
    return region


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
