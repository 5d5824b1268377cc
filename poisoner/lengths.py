"""Lengths in a spec: pixels (an int, or a float >= 1) or a fraction of the width (a float in (0, 1)),
resolved on one picture's size. On a panorama wider than 2:1 a fraction is of a 2:1 frame's width of
the same height (length_base)."""

from __future__ import annotations

from poisoner.errors import SpecError

Length = int | float

# Smallest block the spec resolves to. The paper's block-size ablation (P=100) finds b=1 and
# b=2 nearly harmless (render SSIM 0.952/0.953 vs 0.969 clean) and b=4..8 strongest, because
# SIFT's finest octave needs corners a few pixels apart. A fractional block on a small image
# must not fall below this.
MIN_BLOCK_PX = 4
# Wider than this (width / height), a picture's fractions are of a frame this wide (length_base).
PANORAMA_ASPECT = 2


def length_base(width: int, height: int) -> int:
    """The width a fractional length is a fraction of: the frame's, but a 2:1 frame's of the same
    height on a panorama wider than that. With the panorama's own width a 12000x1500 photo got blocks
    of 30 px and squares one block across (a flat square: no texture; a black-box review). Every frame
    up to 2:1 (3:2, 4:3, 16:9, square, portrait) resolves as before."""
    return min(width, PANORAMA_ASPECT * height)


def resolve_length(value: Length, width: int) -> int:
    """Pixels for a length given in pixels (>= 1) or as a fraction of the width (0 < v < 1)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpecError(f"length must be a number, got {value!r}")
    if value <= 0:
        raise SpecError(f"length must be positive, got {value}")
    if value < 1:
        return max(1, round(value * width))
    return int(round(value))
