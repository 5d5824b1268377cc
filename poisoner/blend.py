"""Blend a resolved patch into an image array (arrays in, arrays out).

The blend is PAPER.md's reading, which reproduces the paper's clean-vs-poisoned PSNR column:
two levels, bright = full scale and dark = full scale * (255 - contrast)/255; alpha as an
8-bit value a = round(255 * alpha); inside the patch I* = I + a * (pattern - I) / 255,
rounded half up to the stored integer type.

RGBA and LA images: the patch region is made opaque. Its colour is first composited over
white (what NeRF-Synthetic loaders, 3DGS's included, do with transparent pixels), then the
pattern is blended and alpha set to full. A transparent patch would vanish or change with
the background a viewer or loader puts behind it; an opaque one is the same on any
background.
"""

from __future__ import annotations

import numpy as np

from poisoner.patterns import pattern_levels, pattern_mask
from poisoner.spec import PatchPlacement, PatchSpec

RGBA_POLICY = "patch region opaque, composited over white"


def _max_value(dtype: np.dtype) -> int:
    if dtype == np.uint8:
        return 255
    if dtype == np.uint16:
        return 65535
    raise TypeError(f"unsupported pixel type {dtype}: expected uint8 or uint16")


def patch_values(placement: PatchPlacement, max_value: int = 255) -> np.ndarray:
    """The pattern's float intensities (P x P) for a placement, on a 0..max_value scale."""
    mask = pattern_mask(placement.pattern, placement.size, placement.block, placement.seed)
    return pattern_levels(mask, placement.contrast, max_value)


def apply_patch(pixels: np.ndarray, placement: PatchPlacement) -> np.ndarray:
    """Return a copy of pixels (H x W, H x W x C; uint8 or uint16) with the patch blended in."""
    if pixels.ndim not in (2, 3):
        raise ValueError(f"expected an H x W or H x W x C array, got shape {pixels.shape}")
    max_value = _max_value(pixels.dtype)
    out = pixels.copy()
    x0, y0, x1, y1 = placement.box
    if x1 > pixels.shape[1] or y1 > pixels.shape[0]:
        raise ValueError(f"patch box {placement.box} outside image of shape {pixels.shape}")
    region = out[y0:y1, x0:x1].astype(np.float64)
    pattern = patch_values(placement, max_value)
    a = placement.alpha8 / 255.0

    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    has_alpha = channels in (2, 4)
    if pixels.ndim == 2:
        colour = region
    else:
        colour = region[..., : channels - 1] if has_alpha else region
        if has_alpha:
            opacity = region[..., channels - 1 : channels] / max_value
            colour = colour * opacity + max_value * (1.0 - opacity)
        pattern = pattern[..., None]

    blended = colour + a * (pattern - colour)
    blended = np.floor(blended + 0.5)
    if pixels.ndim == 2:
        out[y0:y1, x0:x1] = blended.astype(pixels.dtype)
    elif has_alpha:
        out[y0:y1, x0:x1, : channels - 1] = blended.astype(pixels.dtype)
        out[y0:y1, x0:x1, channels - 1] = max_value
    else:
        out[y0:y1, x0:x1] = blended.astype(pixels.dtype)
    return out


def poison_array(
    pixels: np.ndarray, spec: PatchSpec, image_key: str | None = None
) -> tuple[np.ndarray, PatchPlacement]:
    """Resolve spec on this image's size (and name, for a moving spec) and blend its patch in."""
    height, width = pixels.shape[:2]
    placement = spec.resolve(width, height, image_key=image_key)
    return apply_patch(pixels, placement), placement
