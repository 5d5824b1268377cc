"""Issue #9 patterns: multiscale_blocks (pure mask properties) and its place in the spec."""

from __future__ import annotations

import numpy as np

from poisoner.patterns import multiscale_blocks, pattern_mask, random_blocks
from poisoner.spec import PATTERNS, PatchSpec


def test_multiscale_blocks_is_seeded_and_deterministic() -> None:
    a = pattern_mask("multiscale_blocks", 96, 4, seed=1)
    assert np.array_equal(a, pattern_mask("multiscale_blocks", 96, 4, seed=1))
    assert not np.array_equal(a, pattern_mask("multiscale_blocks", 96, 4, seed=2))
    assert a.shape == (96, 96) and a.dtype == bool and a[0, 0]  # dark origin block
    assert 0.3 < a.mean() < 0.7  # balanced: neither a blank nor a solid square


def test_multiscale_blocks_is_blockwise_at_the_finest_scale_and_differs_from_single_scale() -> None:
    mask = multiscale_blocks(64, 4, seed=0)
    cells = mask.reshape(16, 4, 16, 4)
    assert (cells == cells[:, :1, :, :1]).all()  # constant inside every 4 x 4 block
    assert not np.array_equal(mask, random_blocks(64, 4, seed=0))
    # Coarse structure: averaged over 16 x 16 cells, a single-scale 4-px texture is close to
    # grey everywhere, the multi-scale one keeps darker and brighter regions (larger keypoints).
    coarse = mask.reshape(4, 16, 4, 16).mean(axis=(1, 3))
    single = random_blocks(64, 4, seed=0).reshape(4, 16, 4, 16).mean(axis=(1, 3))
    assert coarse.std() > single.std()


def test_multiscale_blocks_is_a_spec_pattern_that_blends() -> None:
    assert "multiscale_blocks" in PATTERNS
    placement = PatchSpec(pattern="multiscale_blocks", patch_size=40, block_size=4).resolve(200, 100)
    assert placement.pattern == "multiscale_blocks" and placement.size == 40
