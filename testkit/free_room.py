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


def two_fit_within(subject: np.ndarray, side: int, box: int, gap: int = 0) -> bool:
    """two_fit with the default mark's own geometry: both squares inside one box x box square (ppd
    keeps its two lanes within a square of the frame's shorter side, poisoner.placement.choose_split),
    so pockets at opposite ends of a wide frame do not count as room for the mark, and at least `gap`
    px apart in x or y (choose_split keeps split squares a sixth of a side apart). A fitting corner p
    has a partner q when some fitting corner lies within box - side of it in x and y (Chebyshev) but
    not within side + gap - 1 of it (the squares would overlap, or lie closer than gap): two window
    counts on one integral image."""
    ok = fits(subject, side)
    if not ok.any() or box < 2 * side + gap:
        return False
    s = np.zeros((ok.shape[0] + 1, ok.shape[1] + 1), dtype=np.int64)
    s[1:, 1:] = ok.astype(np.int64).cumsum(0).cumsum(1)
    ys, xs = np.nonzero(ok)

    def count(radius: int) -> np.ndarray:
        y0, y1 = np.clip(ys - radius, 0, ok.shape[0]), np.clip(ys + radius + 1, 0, ok.shape[0])
        x0, x1 = np.clip(xs - radius, 0, ok.shape[1]), np.clip(xs + radius + 1, 0, ok.shape[1])
        return s[y1, x1] - s[y0, x1] - s[y1, x0] + s[y0, x0]

    return bool((count(box - side) - count(side + gap - 1) > 0).any())
