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

from dataclasses import replace

import numpy as np

from poisoner.logo import mark_shape
from poisoner.orientation import INVERSE_ORIENTATION, orientation_of, turn_square, unorient_array
from poisoner.patterns import pattern_levels, pattern_mask
from poisoner.spec import PatchPlacement, PatchSpec

RGBA_POLICY = "patch region opaque, composited over white"


def _max_value(dtype: np.dtype) -> int:
    if dtype == np.uint8:
        return 255
    if dtype == np.uint16:
        return 65535
    raise TypeError(f"unsupported pixel type {dtype}: expected uint8 or uint16")


def _turned(placement: PatchPlacement) -> tuple[np.ndarray, np.ndarray]:
    """(pattern mask, coverage) on the placement's size x size box for a turned, scaled texture.

    Nearest-neighbour inverse mapping: the two levels stay two levels (crisp corners for SIFT,
    no grey fringe that would widen the changed area).
    """
    t = placement.texture_size
    base = pattern_mask(placement.pattern, t, placement.block, placement.seed)
    n = placement.size
    c = n / 2.0
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64) + 0.5
    rad = np.radians(placement.angle)
    cos, sin = np.cos(rad), np.sin(rad)
    px, py = xx - c, yy - c
    u = (cos * px + sin * py) / placement.scale + t / 2.0
    v = (-sin * px + cos * py) / placement.scale + t / 2.0
    inside = (u >= 0) & (u < t) & (v >= 0) & (v < t)
    ui = np.clip(np.floor(u).astype(int), 0, t - 1)
    vi = np.clip(np.floor(v).astype(int), 0, t - 1)
    shape = mark_shape(placement.mark_text, placement.mark_image, t)
    if shape is not None:
        inside = inside & shape[vi, ui]
    return base[vi, ui] & inside, inside


def _lanes(placement: PatchPlacement) -> tuple[np.ndarray, np.ndarray]:
    """(pattern mask, coverage) on the box for a multi-lane mark: each lane its own texture square,
    or its top-left lane_crop square (round 3: the same blocks cropped, never rescaled)."""
    n, t, c = placement.size, placement.lane_size, placement.lane_side
    dark = np.zeros((n, n), dtype=bool)
    cover = np.zeros((n, n), dtype=bool)
    shape = mark_shape(placement.mark_text, placement.mark_image, t)
    for dx, dy, seed in placement.parts:
        dark[dy : dy + c, dx : dx + c] = pattern_mask(placement.pattern, t, placement.block, seed)[:c, :c]
        cover[dy : dy + c, dx : dx + c] = True if shape is None else shape[:c, :c]
    return dark & cover, cover


def patch_coverage(placement: PatchPlacement) -> np.ndarray:
    """Which pixels of the placement's box the patch changes (all of them unless it is turned or
    shaped as text / a logo), in the stored layout (placement.turn)."""
    return np.ascontiguousarray(unorient_array(_coverage(placement), placement.turn))


def _coverage(placement: PatchPlacement) -> np.ndarray:
    if placement.parts:
        return _lanes(placement)[1]
    if placement.texture_size == 0:
        shape = mark_shape(placement.mark_text, placement.mark_image, placement.size)
        return np.ones((placement.size, placement.size), dtype=bool) if shape is None else shape.copy()
    return _turned(placement)[1]


def patch_values(placement: PatchPlacement, max_value: int = 255) -> np.ndarray:
    """The pattern's float intensities (P x P) for a placement, on a 0..max_value scale.

    For a turned mark, pixels outside it (patch_coverage False) read as bright; apply_patch leaves
    them untouched.
    """
    if placement.parts:
        mask = _lanes(placement)[0]
    elif placement.texture_size == 0:
        mask = pattern_mask(placement.pattern, placement.size, placement.block, placement.seed)
    else:
        mask = _turned(placement)[0]
    # laid out as the picture is shown, stored turned back (issue 25)
    return pattern_levels(unorient_array(mask, placement.turn), placement.contrast, max_value)


def apply_patch(
    pixels: np.ndarray, placement: PatchPlacement, keep_out: np.ndarray | None = None
) -> np.ndarray:
    """Return a copy of pixels (H x W, H x W x C; uint8 or uint16) with the patch blended in.

    keep_out (H x W, nonzero = leave alone), e.g. a subject mask: those pixels are never changed,
    so a mark beside the subject never covers it.
    """
    if pixels.ndim not in (2, 3):
        raise ValueError(f"expected an H x W or H x W x C array, got shape {pixels.shape}")
    x0, y0, x1, y1 = placement.box
    if x0 < 0 or y0 < 0 or x1 > pixels.shape[1] or y1 > pixels.shape[0]:
        raise ValueError(f"patch box {placement.box} outside image of shape {pixels.shape}")
    return apply_patch_at(pixels, placement, (0, 0), keep_out)


def apply_patch_at(
    window: np.ndarray,
    placement: PatchPlacement,
    origin: tuple[int, int],
    keep_out: np.ndarray | None = None,
) -> np.ndarray:
    """A copy of `window`, a crop of the picture whose top-left pixel sits at `origin` (x, y) of
    the picture, with the part of the patch that falls inside it blended in (placement in the
    picture's coordinates). keep_out is window-sized. What a box-local writer (a JPEG MCU box, a
    cropped region) uses: the mark may reach beyond the window, only its overlap is written."""
    if window.ndim not in (2, 3):
        raise ValueError(f"expected an H x W or H x W x C array, got shape {window.shape}")
    if keep_out is not None and keep_out.shape[:2] != window.shape[:2]:
        raise ValueError(f"keep_out mask {keep_out.shape[:2]} does not match image {window.shape[:2]}")
    max_value = _max_value(window.dtype)
    out = window.copy()
    ox, oy = origin
    bx0, by0, bx1, by1 = placement.box
    # the overlap of the mark's box and the window, in window coordinates
    x0, y0 = max(bx0 - ox, 0), max(by0 - oy, 0)
    x1, y1 = min(bx1 - ox, window.shape[1]), min(by1 - oy, window.shape[0])
    if x0 >= x1 or y0 >= y1:
        return out
    mark = (slice(y0 + oy - by0, y1 + oy - by0), slice(x0 + ox - bx0, x1 + ox - bx0))
    write = patch_coverage(placement)[mark]
    if keep_out is not None:
        write = write & ~(keep_out[y0:y1, x0:x1] > 0)
    if not write.any():
        return out
    pattern = patch_values(placement, max_value)[mark]
    out[y0:y1, x0:x1] = _blended(window[y0:y1, x0:x1], pattern, placement.alpha8, max_value)
    if not write.all():
        out[y0:y1, x0:x1][~write] = window[y0:y1, x0:x1][~write]
    return out


def _blended(region: np.ndarray, pattern: np.ndarray, alpha8: int, max_value: int) -> np.ndarray:
    """region (h x w (x C)) with the pattern blended in; an alpha channel becomes opaque, the colour
    under it composited over white first."""
    values = region.astype(np.float64)
    a = alpha8 / 255.0
    channels = 1 if region.ndim == 2 else region.shape[2]
    has_alpha = channels in (2, 4)
    if region.ndim == 2:
        colour = values
    else:
        colour = values[..., : channels - 1] if has_alpha else values
        if has_alpha:
            opacity = values[..., channels - 1 : channels] / max_value
            colour = colour * opacity + max_value * (1.0 - opacity)
        pattern = pattern[..., None]
    blended = np.floor(colour + a * (pattern - colour) + 0.5).astype(region.dtype)
    if not has_alpha:
        return blended
    out = region.copy()
    out[..., : channels - 1] = blended
    out[..., channels - 1] = max_value
    return out


def poison_array(
    pixels: np.ndarray, spec: PatchSpec, image_key: str | None = None, keep_out: np.ndarray | None = None
) -> tuple[np.ndarray, PatchPlacement]:
    """Resolve spec on this image's size (and name, for a moving spec) and blend its patch in."""
    height, width = pixels.shape[:2]
    placement = spec.resolve(width, height, image_key=image_key)
    return apply_patch(pixels, placement, keep_out), placement


def lane_placements(placement: PatchPlacement) -> list[PatchPlacement] | None:
    """A mark of several lanes (placement.parts) as one single-lane placement per lane, each on its
    own square in stored pixels, writing exactly the pixels the whole placement writes there: a
    writer then blends each square alone instead of the box around squares placed far apart.
    None when the placement is not made of lanes, or its squares overlap (then only the whole
    placement says which lane wins)."""
    if not placement.parts or placement.lane_size <= 0:
        return None
    # Cropped squares (poisoner.shrink: each lane the top-left lane_crop of its square as shown) split
    # the same way, each lane keeping its crop: turned with its own square, the crop lands where the
    # whole box's turn puts it. The whole box between squares far apart was blended at once: on a
    # 10 MP RGBA PNG with no plain place, 0.9 GB of float copies for 2 x 0.2% of the pixels.
    n, t = placement.size, placement.lane_side  # a square as written: its crop when cropped
    corners = [(dx, dy) for dx, dy, _seed in placement.parts]
    if any(dx < 0 or dy < 0 or dx + t > n or dy + t > n for dx, dy in corners):
        return None  # cut by the box's edge: not a whole square
    for i, (ax, ay) in enumerate(corners):
        if any(abs(ax - bx) < t and abs(ay - by) < t for bx, by in corners[:i]):
            return None  # overlapping squares
    # where the stored pixels hold each square: the box turned back (unorient_array's turn), worked
    # out on the corners instead of on an n x n label picture (n: up to 2600 px on a 12 MP photo)
    back = INVERSE_ORIENTATION[orientation_of(placement.turn)]
    lanes = []
    for dx, dy, seed in placement.parts:
        x, y = turn_square(dx, dy, t, back, n, n)
        lanes.append(replace(placement, x=placement.x + x, y=placement.y + y, size=t, parts=((0, 0, seed),)))
    return lanes


def apply_lanes(
    pixels: np.ndarray, placement: PatchPlacement, keep_out: np.ndarray | None = None
) -> np.ndarray:
    """apply_patch's pixels, a square at a time where the mark is made of squares (apply_lanes_at)."""
    x0, y0, x1, y1 = placement.box
    if x0 < 0 or y0 < 0 or x1 > pixels.shape[1] or y1 > pixels.shape[0]:
        raise ValueError(f"patch box {placement.box} outside image of shape {pixels.shape}")
    return apply_lanes_at(pixels, placement, (0, 0), keep_out, lane_placements(placement))


def apply_lanes_at(
    window: np.ndarray,
    placement: PatchPlacement,
    origin: tuple[int, int],
    keep_out: np.ndarray | None,
    lanes: list[PatchPlacement] | None,
) -> np.ndarray:
    """apply_patch_at(window, placement, origin, keep_out), a lane at a time when lanes (the
    placement's lane_placements) is given: the same pixels without blending the box between squares
    placed far apart, whose float copies were several times the picture (a 10 MP 16-bit RGB PNG:
    0.8 GB)."""
    if lanes is None:
        return apply_patch_at(window, placement, origin, keep_out)
    out = window.copy()
    ox, oy = origin
    h, w = window.shape[:2]
    for lane in lanes:
        lx0, ly0, lx1, ly1 = lane.box
        x0, y0, x1, y1 = max(lx0 - ox, 0), max(ly0 - oy, 0), min(lx1 - ox, w), min(ly1 - oy, h)
        if x0 >= x1 or y0 >= y1:
            continue
        part = None if keep_out is None else keep_out[y0:y1, x0:x1]
        out[y0:y1, x0:x1] = apply_patch_at(window[y0:y1, x0:x1], lane, (ox + x0, oy + y0), part)
    return out
