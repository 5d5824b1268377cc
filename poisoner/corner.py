"""One corner per dataset (issue 14, a corner spec: `--position top-left` and the like): which corner,
and which pixels to keep out.

A corner mark lives in one corner region (`region` of the width x `region` of the height). Over a
dataset it stays in ONE corner (a photographer signs every picture in the same place), so the corner
is chosen from all the images' subject masks together: the corner whose region the subject (and any
keep-out area) covers least, ties broken by the distance from the subject's centre (farthest wins).
Pixels on the subject are then never written (poisoner.blend.apply_patch's keep_out), so no changed
pixel touches the subject even where it reaches into the chosen corner. The per-photo rule, the
default design's, is poisoner.placement.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

CORNERS = ("top-left", "top-right", "bottom-left", "bottom-right")


def corner_box(corner: str, width: int, height: int, region: float) -> tuple[int, int, int, int]:
    """(left, top, right, bottom) of a corner region, right/bottom exclusive."""
    if corner not in CORNERS:
        raise ValueError(f"unknown corner {corner!r}; choose one of {', '.join(CORNERS)}")
    if not 0.0 < region <= 0.5:
        raise ValueError(f"corner region must be in (0, 0.5], got {region}")
    rw, rh = int(region * width), int(region * height)
    x0 = 0 if corner.endswith("left") else width - rw
    y0 = 0 if corner.startswith("top") else height - rh
    return (x0, y0, x0 + rw, y0 + rh)


def _union(masks: Sequence[np.ndarray | None]) -> np.ndarray | None:
    present = [np.asarray(m) > 0 for m in masks if m is not None]
    if not present:
        return None
    shape = present[0].shape[:2]
    for m in present:
        if m.shape[:2] != shape:
            raise ValueError(f"subject masks differ in size: {m.shape[:2]} vs {shape}")
    return np.any(np.stack([m.reshape(shape) for m in present]), axis=0)


def corner_cover(occupied: np.ndarray, region: float) -> dict[str, float]:
    """Fraction of each corner region that `occupied` (H x W, nonzero = subject) covers."""
    h, w = occupied.shape[:2]
    cover = {}
    for corner in CORNERS:
        x0, y0, x1, y1 = corner_box(corner, w, h, region)
        cover[corner] = float((occupied[y0:y1, x0:x1] > 0).mean())
    return cover


def choose_corner(
    subject_masks: Sequence[np.ndarray | None],
    keep_out: np.ndarray | None = None,
    region: float = 0.2,
    default: str = "top-left",
) -> str:
    """The corner for a dataset's mark: least covered by the union of its subject masks and keep_out.

    No mask at all: `default` (nothing is known about the subject). Ties (e.g. every corner empty):
    the corner farthest from the subject's centre of mass, then the order of CORNERS.
    """
    occupied = _union([*subject_masks, keep_out])
    if occupied is None:
        return default
    if not occupied.any():
        return default
    h, w = occupied.shape[:2]
    cover = corner_cover(occupied, region)
    ys, xs = np.nonzero(occupied)
    cy, cx = ys.mean() / h, xs.mean() / w

    def distance(corner: str) -> float:
        x0, y0, x1, y1 = corner_box(corner, w, h, region)
        return float(np.hypot((x0 + x1) / 2 / w - cx, (y0 + y1) / 2 / h - cy))

    return min(CORNERS, key=lambda c: (round(cover[c], 4), -distance(c), CORNERS.index(c)))


def keep_out_mask(
    subject: np.ndarray | None, keep_out: np.ndarray | None = None, margin: int = 0
) -> np.ndarray | None:
    """Pixels the mark must not change: the subject, grown by `margin` px, plus keep_out."""
    occupied = _union([subject, keep_out])
    if occupied is None or margin <= 0:
        return occupied
    grown = occupied.copy()
    h, w = grown.shape
    # a square dilation by shifting: margin is small (a few px), no SciPy needed
    for dy in range(-margin, margin + 1):
        for dx in range(-margin, margin + 1):
            src = occupied[max(0, -dy) : h - max(0, dy), max(0, -dx) : w - max(0, dx)]
            grown[max(0, dy) : h - max(0, -dy), max(0, dx) : w - max(0, -dx)] |= src
    return grown
