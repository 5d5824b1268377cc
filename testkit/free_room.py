"""Room off a subject (issue 25, round 4): how large a square, and whether two squares, fit where a
subject mask has no pixel. Pure numpy; what bench/bench_fill.py judges each view's touch against
("a free place existed" or "no placement could avoid the subject")."""

from __future__ import annotations

import numpy as np


def fits(subject: np.ndarray, side: int) -> np.ndarray:
    """Top-left corners (a bool map) where a side x side square holds no subject pixel."""
    h, w = subject.shape
    if side <= 0 or side > min(h, w):
        return np.zeros((0, 0), dtype=bool)
    s = np.zeros((h + 1, w + 1), dtype=np.int64)
    s[1:, 1:] = (np.asarray(subject) > 0).astype(np.int64).cumsum(0).cumsum(1)
    sums = s[side:, side:] - s[:-side, side:] - s[side:, :-side] + s[:-side, :-side]
    return sums == 0


def largest_free_square(subject: np.ndarray) -> int:
    """The side of the largest square holding no subject pixel (0: none; a binary search on fits)."""
    lo, hi = 0, min(subject.shape)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if fits(subject, mid).any():
            lo = mid
        else:
            hi = mid - 1
    return lo


def two_fit(subject: np.ndarray, side: int) -> bool:
    """Whether two non-overlapping side x side squares fit off the subject: two fitting top-left
    corners at least `side` apart in x or in y exist exactly when the fitting corners span that much."""
    ok = fits(subject, side)
    if not ok.any():
        return False
    ys, xs = np.nonzero(ok)
    return bool(xs.max() - xs.min() >= side or ys.max() - ys.min() >= side)
