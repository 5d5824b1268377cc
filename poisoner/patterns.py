"""The paper's patch patterns as boolean P x P masks (True = dark).

Pure functions: size, block size and seed in, array out. The block at the patch's origin
corner is dark (PAPER.md, "Our reading of the blend"): for the checkerboard, block (i, j) is
dark when i + j is even, so P=12, b=4 gives 5 dark and 4 bright blocks.

Combinations are the exclusive-or of their parts: XOR keeps every part's edges visible,
where OR would hide circles inside dark checkerboard squares.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

Mask = np.ndarray  # bool, shape (P, P)


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:size, 0:size]
    return yy, xx


def checkerboard(size: int, block: int, seed: int = 0) -> Mask:
    yy, xx = _grid(size)
    return ((yy // block + xx // block) % 2) == 0


def parallel_lines(size: int, block: int, seed: int = 0) -> Mask:
    """Vertical stripes of width `block` (the paper finds these ineffective: b-wide lines
    have edges but no corners, and SIFT wants corners)."""
    _, xx = _grid(size)
    return (xx // block) % 2 == 0


def diagonal_lines(size: int, block: int, seed: int = 0) -> Mask:
    yy, xx = _grid(size)
    return ((xx + yy) // block) % 2 == 0


def intersecting_lines(size: int, block: int, seed: int = 0) -> Mask:
    """A cross-hatch: two families of diagonal lines, half a block wide, period 2 blocks."""
    yy, xx = _grid(size)
    width = max(1, block // 2)
    period = 2 * block
    return ((xx + yy) % period < width) | ((xx - yy) % period < width)


def circles(size: int, block: int, seed: int = 0) -> Mask:
    """Concentric rings `block` wide around the patch centre, darkest ring in the middle."""
    yy, xx = _grid(size)
    c = (size - 1) / 2.0
    r = np.hypot(yy - c, xx - c)
    return (np.floor(r / block) % 2) == 0


def random_blocks(size: int, block: int, seed: int = 0) -> Mask:
    """A non-repetitive texture of random dark/bright blocks (seeded): unlike the
    checkerboard, its corners have distinctive descriptors, so SIFT's ratio test keeps them."""
    n = -(-size // block)
    rng = np.random.default_rng(seed)
    cells = rng.random((n, n)) < 0.5
    cells[0, 0] = True  # dark origin block, as for every pattern
    return np.kron(cells, np.ones((block, block), dtype=bool))[:size, :size]


def multiscale_blocks(size: int, block: int, seed: int = 0) -> Mask:
    """Random blocks at three scales (b, 2b, 4b) combined by exclusive-or (seeded).

    Why (issue #9): COLMAP keeps at most 8192 SIFT features per image and drops the finest
    scales first, and a platform's downscale removes them too; a texture with corners at
    several scales keeps distinctive keypoints at the coarser octaves that survive both.
    """
    mask = np.zeros((size, size), dtype=bool)
    for level, scale in enumerate((1, 2, 4)):
        mask ^= random_blocks(size, block * scale, seed + 7919 * level)
    if not mask[0, 0]:
        mask = ~mask  # dark origin block, as for every pattern
    return mask


_BASE: dict[str, Callable[[int, int, int], Mask]] = {
    "checkerboard": checkerboard,
    "parallel_lines": parallel_lines,
    "diagonal_lines": diagonal_lines,
    "intersecting_lines": intersecting_lines,
    "circles": circles,
    "random_blocks": random_blocks,
    "multiscale_blocks": multiscale_blocks,
}

_COMBINATIONS: dict[str, tuple[str, ...]] = {
    "checkerboard+circles": ("checkerboard", "circles"),
    "checkerboard+diagonal_lines": ("checkerboard", "diagonal_lines"),
    "diagonal_lines+circles": ("diagonal_lines", "circles"),
    "all": ("checkerboard", "parallel_lines", "diagonal_lines", "intersecting_lines", "circles"),
}


@functools.lru_cache(maxsize=32)
def pattern_mask(pattern: str, size: int, block: int, seed: int = 0) -> Mask:
    """The boolean mask (True = dark) of a named pattern, read-only: kept (every photo of a dataset
    carries the same squares, so a folder's files ask for the same few masks, each patch up to four
    times; 3 ms of a 12 MP JPEG's patch)."""
    mask = _pattern_mask(pattern, size, block, seed)
    mask.flags.writeable = False
    return mask


def _pattern_mask(pattern: str, size: int, block: int, seed: int) -> Mask:
    if size < 1 or block < 1:
        raise ValueError(f"size and block must be >= 1 (got {size}, {block})")
    if pattern in _BASE:
        return _BASE[pattern](size, block, seed)
    if pattern in _COMBINATIONS:
        mask = np.zeros((size, size), dtype=bool)
        for part in _COMBINATIONS[pattern]:
            mask ^= _BASE[part](size, block, seed)
        return mask
    raise ValueError(f"unknown pattern {pattern!r}")


def pattern_levels(mask: Mask, contrast: int, max_value: int = 255) -> np.ndarray:
    """Float intensities of the pattern: bright = max_value, dark = max_value*(255-contrast)/255."""
    dark = max_value * (255 - contrast) / 255.0
    return np.where(mask, dark, float(max_value))
