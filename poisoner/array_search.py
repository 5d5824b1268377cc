"""The array helpers of the placement search (poisoner.placement, poisoner.shrink): integral images
for summing a map over many boxes at once, and lexsort's first answers without a whole sort."""

from __future__ import annotations

import numpy as np


def integral_image(m: np.ndarray) -> np.ndarray:
    """A map's integral image, one row and column of zeros first (for _rect_sums)."""
    th, tw = m.shape
    out = np.zeros((th + 1, tw + 1))
    out[1:, 1:] = np.asarray(m, dtype=np.float64).cumsum(0).cumsum(1)
    return out


def count_integral(mask: np.ndarray) -> np.ndarray:
    """integral_image of a True/False map as exact int32 counts: the same sums as integral_image's
    float64 (whole numbers either way) at half the memory traffic, for scans of every box position
    (poisoner.shrink._some_square_plain)."""
    if mask.dtype != np.bool_:
        raise TypeError(f"count_integral takes a True/False map, not {mask.dtype}")
    th, tw = mask.shape
    if (th + 1) * (tw + 1) >= 2**31:
        raise ValueError(f"a {tw}x{th} map is too large to count in int32")
    out = np.zeros((th + 1, tw + 1), dtype=np.int32)
    np.cumsum(mask, axis=0, dtype=np.int32, out=out[1:, 1:])
    np.cumsum(out[1:, 1:], axis=1, out=out[1:, 1:])
    return out


def lexsort_head(keys: tuple[np.ndarray, ...], count: int) -> np.ndarray:
    """np.lexsort(keys)[:count] (the last key primary), sorting only the candidates that can be
    among the first `count`: those whose primary key is at most its count-th smallest value. The
    subset keeps its original order, so ties fall as the stable sort of all of them lets them."""
    primary = keys[-1]
    if primary.size <= count or _any_nan(keys):  # NaN sorts last in lexsort: leave those to it
        return np.lexsort(keys)[:count]
    kth = np.partition(primary, count - 1)[count - 1]
    candidates = np.flatnonzero(primary <= kth)
    return candidates[np.lexsort(tuple(k[candidates] for k in keys))][:count]


def _any_nan(keys: tuple[np.ndarray, ...]) -> bool:
    return any(k.dtype.kind in "fc" and bool(np.isnan(k).any()) for k in keys)


def lexsort_first(keys: tuple[np.ndarray, ...]) -> int:
    """int(np.lexsort(keys)[0]) without sorting: the candidates are narrowed to the smallest value
    of each key in turn, primary (last) first; the lowest index of those left (the stable sort's)."""
    if keys[-1].size == 0 or _any_nan(keys):  # NaN sorts last in lexsort: leave those to it
        return int(np.lexsort(keys)[0])
    candidates = np.arange(keys[-1].size)
    for key in reversed(keys):
        values = key[candidates]
        candidates = candidates[values == values.min()]
        if candidates.size == 1:
            break
    return int(candidates[0])
