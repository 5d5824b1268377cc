"""SSIM/PSNR as official 3DGS computes them, checked against independent computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from poisoner.blend import poison_array
from poisoner.spec import PatchSpec
from verifier.metrics import psnr, psnr_torch, ssim, ssim_map, ssim_torch, to_unit_float

BORDER = 5  # the 11x11 window's half-width: pixels closer to the edge see 3DGS's zero padding


def _pair(seed: int, shape: tuple[int, int, int] = (48, 40, 3)) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.random(shape)
    b = np.clip(a + rng.normal(0, 0.1, shape), 0, 1)
    return a, b


def test_numpy_and_torch_ssim_agree() -> None:
    a, b = _pair(0)
    ta = torch.from_numpy(a).permute(2, 0, 1)
    tb = torch.from_numpy(b).permute(2, 0, 1)
    assert ssim(a, b) == pytest.approx(float(ssim_torch(ta, tb)), abs=1e-12)
    assert psnr(a, b) == pytest.approx(float(psnr_torch(ta, tb)), abs=1e-9)


def test_ssim_interior_matches_scikit_image() -> None:
    # skimage with these options uses the same 11x11 sigma-1.5 window but reflect-pads and then
    # averages only the interior (5 px from each edge); there the two maps are the same numbers.
    a, b = _pair(1)
    ours_interior = ssim_map(a, b)[BORDER:-BORDER, BORDER:-BORDER].mean()
    theirs = structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=2
    )
    assert ours_interior == pytest.approx(theirs, abs=1e-9)


def test_zero_padding_lowers_ssim_at_the_border_only() -> None:
    # A uniform grey image vs itself + constant: 3DGS's zero padding makes border pixels differ
    # from the interior, which is why whole-image SSIM differs slightly from scikit-image's.
    a = np.full((32, 32, 3), 0.5)
    b = a + 0.05
    m = ssim_map(a, b)
    interior = m[BORDER + 1 : -BORDER - 1, BORDER + 1 : -BORDER - 1]
    assert np.ptp(interior) < 1e-12
    assert not np.isclose(m[0, 0, 0], interior[0, 0, 0])


def test_identical_images() -> None:
    a, _ = _pair(2)
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert psnr(a, a) == math.inf


def test_psnr_of_a_constant_offset() -> None:
    a = np.full((8, 8, 3), 0.25)
    assert psnr(a, a + 0.1) == pytest.approx(20.0, abs=1e-9)  # MSE 0.01


def test_shape_mismatch_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="differ in shape"):
        ssim(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))


def test_ssim_torch_is_differentiable() -> None:
    a, b = _pair(3, (16, 16, 3))
    ta = torch.from_numpy(a).permute(2, 0, 1).requires_grad_(True)
    tb = torch.from_numpy(b).permute(2, 0, 1)
    (1 - ssim_torch(ta, tb)).backward()
    assert ta.grad is not None and torch.isfinite(ta.grad).all() and ta.grad.abs().sum() > 0


@pytest.mark.parametrize(("patch", "paper_ssim"), [(12, 0.9996), (100, 0.9831)])
def test_white_image_clean_vs_poisoned_ssim_near_paper(patch: int, paper_ssim: float) -> None:
    # The paper's cost2 SSIM column (white 800x800, b=4). Ours: 0.99966 (P=12), 0.98343 (P=100).
    white = np.full((800, 800, 3), 255, np.uint8)
    poisoned, _ = poison_array(white, PatchSpec(patch_size=patch, block_size=4))
    value = ssim(to_unit_float(white), to_unit_float(poisoned))
    assert value == pytest.approx(paper_ssim, abs=1e-3)
    assert value < 1.0
