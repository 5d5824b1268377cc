"""Candidate perturbations for textured real scenes (issue 18), as pure array functions.

- `coarse_decoys`: per-image random Gaussian blobs at one scale, to take COLMAP's 8192-feature
  budget (which keeps coarse octaves first) before the scene's finer features do.
- `smooth_warp`: a per-image smooth non-rigid displacement (sub-percent of the width).
- `descriptor_attack`: projected sign-gradient steps that move the SIFT descriptors of the keypoints
  COLMAP keeps, through kornia's differentiable `SIFTDescriptor` on patches sampled at each
  keypoint's scale and orientation (a stand-in; transfer is judged with COLMAP's own SIFT).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

if TYPE_CHECKING:
    import torch


def coarse_decoys(rgb: np.ndarray, seed: int, sigma: float, amplitude: float, spacing: float) -> np.ndarray:
    """Add +-amplitude grey-level Gaussian blobs of std sigma px on a jittered grid of the given spacing."""
    h, w = rgb.shape[:2]
    rng = np.random.default_rng(seed)
    field = np.zeros((h, w), np.float32)
    ys = np.arange(spacing / 2, h, spacing)
    xs = np.arange(spacing / 2, w, spacing)
    gy, gx = np.meshgrid(ys, xs, indexing="ij")
    jitter = (rng.random((2, *gy.shape)) - 0.5) * spacing * 0.6
    py = np.clip(np.round(gy + jitter[0]), 0, h - 1).astype(int)
    px = np.clip(np.round(gx + jitter[1]), 0, w - 1).astype(int)
    field[py, px] = rng.choice([-1.0, 1.0], size=py.shape)
    # a unit impulse blurred by sigma peaks at 1 / (2 pi sigma^2): rescale so blobs peak at +-amplitude
    blob = ndimage.gaussian_filter(field, sigma, mode="reflect") * (2 * np.pi * sigma**2) * amplitude
    return np.clip(rgb.astype(np.float32) + blob[..., None], 0, 255).round().astype(np.uint8)


def smooth_field(shape: tuple[int, int], seed: int, amplitude: float, wavelength: float) -> np.ndarray:
    """(2, h, w) displacement: smoothed white noise with feature size ~wavelength, max |d| = amplitude px."""
    h, w = shape
    rng = np.random.default_rng(seed)
    step = max(wavelength / 4, 1.0)
    gh, gw = int(np.ceil(h / step)) + 3, int(np.ceil(w / step)) + 3
    coarse = ndimage.gaussian_filter(rng.standard_normal((2, gh, gw)), (0, 1.0, 1.0), mode="wrap")
    zoom = (1, h / (gh - 3), w / (gw - 3))
    fine = ndimage.zoom(coarse, zoom, order=3)[:, :h, :w]
    return (fine / np.abs(fine).max() * amplitude).astype(np.float32)


def smooth_warp(rgb: np.ndarray, seed: int, amplitude: float, wavelength: float) -> np.ndarray:
    """Resample rgb at x + d(x) for a smooth per-image displacement d (bicubic, edges reflected)."""
    h, w = rgb.shape[:2]
    d = smooth_field((h, w), seed, amplitude, wavelength)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    coords = np.stack([yy + d[0], xx + d[1]])
    out = np.empty_like(rgb)
    for c in range(rgb.shape[2]):
        out[..., c] = np.clip(
            ndimage.map_coordinates(rgb[..., c].astype(np.float32), coords, order=3, mode="reflect"), 0, 255
        ).round()
    return out


def texture_mask(gray: np.ndarray, radius: float = 4.0) -> np.ndarray:
    """Local contrast in [0, 1] (std of grey levels over ~radius px, / 16): where changes hide."""
    g = gray.astype(np.float32)
    mean = ndimage.gaussian_filter(g, radius)
    var = np.maximum(ndimage.gaussian_filter(g * g, radius) - mean * mean, 0)
    return np.clip(np.sqrt(var) / 16.0, 0.0, 1.0)


def masked_noise(rgb: np.ndarray, seed: int, epsilon: float, box: tuple[int, int, int, int]) -> np.ndarray:
    """The control for descriptor_attack: uniform noise of the same texture-masked budget in the window."""
    x0, y0, x1, y1 = box
    gray = rgb[y0:y1, x0:x1].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    noise = np.random.default_rng(seed).choice([-1.0, 1.0], size=gray.shape) * epsilon * texture_mask(gray)
    out = rgb.astype(np.float32)
    out[y0:y1, x0:x1] += noise[..., None]
    return np.clip(out, 0, 255).round().astype(np.uint8)


def _attack_in_box(
    rgb: np.ndarray,
    kps: np.ndarray,
    epsilon: float,
    steps: int,
    patch_magnif: float,
    seed: int,
    log: bool,
    box: tuple[int, int, int, int],
    ori_sign: float,
) -> np.ndarray:
    """descriptor_attack on the window only, with the keypoints inside it; the rest of rgb unchanged."""
    x0, y0, x1, y1 = box
    inside = (kps[:, 0] >= x0) & (kps[:, 0] < x1) & (kps[:, 1] >= y0) & (kps[:, 1] < y1)
    sub = kps[inside].copy()
    sub[:, 0] -= x0
    sub[:, 1] -= y0
    out = rgb.copy()
    out[y0:y1, x0:x1] = descriptor_attack(
        rgb[y0:y1, x0:x1], sub, epsilon, steps, patch_magnif, seed, log, ori_sign=ori_sign
    )
    return out


def _keypoint_lafs(kps: np.ndarray, patch_magnif: float, ori_sign: float) -> torch.Tensor:
    """kornia local affine frames at the keypoints: centre, SIFT window scale, orientation in degrees."""
    import torch
    from kornia.feature import laf_from_center_scale_ori

    centres = torch.from_numpy(kps[:, :2].copy())[None]
    # the SIFT window is 4 bins of 3 sigma each (VLFeat magnif 3), i.e. half-width 6 sigma
    scales = torch.from_numpy(kps[:, 2:3].copy() * patch_magnif)[None, :, :, None]
    oris = torch.from_numpy(ori_sign * np.degrees(kps[:, 3:4]).copy())[None]
    return laf_from_center_scale_ori(centres, scales, oris)


def descriptor_attack(
    rgb: np.ndarray,
    kps: np.ndarray,
    epsilon: float,
    steps: int,
    patch_magnif: float = 6.0,
    seed: int = 0,
    log: bool = True,
    box: tuple[int, int, int, int] | None = None,
    ori_sign: float = 1.0,
) -> np.ndarray:
    """PGD on the grey image: push kornia SIFT descriptors at COLMAP's keypoints away from clean.

    kps: (N, 4) x, y, scale, orientation (radians) in rgb's pixels. epsilon: L-inf budget in grey levels,
    scaled per pixel by `texture_mask` (flat areas get ~nothing). The same delta is added to R, G, B.
    """
    import time

    import torch

    if box is not None:  # attack only this window (a sample of the image, to keep the CPU cost down)
        return _attack_in_box(rgb, kps, epsilon, steps, patch_magnif, seed, log, box, ori_sign)

    from kornia.feature import SIFTDescriptor, extract_patches_from_pyramid

    torch.manual_seed(seed)
    gray = rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    budget = torch.from_numpy(epsilon * texture_mask(gray))[None, None] / 255.0
    img = torch.from_numpy(gray)[None, None] / 255.0
    laf = _keypoint_lafs(kps, patch_magnif, ori_sign)
    desc = SIFTDescriptor(32, rootsift=False)
    with torch.no_grad():
        clean = desc(extract_patches_from_pyramid(img, laf, 32)[0])
    delta = (torch.rand_like(img) * 2 - 1) * budget
    delta.requires_grad_(True)
    step = budget / max(steps / 4, 1)
    t0 = time.time()
    for i in range(steps):
        d = desc(extract_patches_from_pyramid((img + delta).clamp(0, 1), laf, 32)[0])
        loss = -(d - clean).pow(2).sum(1).mean()  # maximise the descriptor distance
        loss.backward()
        with torch.no_grad():
            delta -= step * delta.grad.sign()
            delta.copy_(torch.maximum(torch.minimum(delta, budget), -budget))
            delta.grad = None
        if log and (i % 5 == 0 or i == steps - 1):
            print(
                f"  step {i}: descriptor distance {(-loss.item()) ** 0.5:.3f} ({time.time() - t0:.0f} s)",
                flush=True,
            )
    out = rgb.astype(np.float32) + 255.0 * delta.detach()[0, 0].numpy()[..., None]
    return np.clip(out, 0, 255).round().astype(np.uint8)


def standin_descriptors(
    gray: np.ndarray, kps: np.ndarray, patch_magnif: float, ori_sign: float, ori_offset_deg: float
) -> np.ndarray:
    """kornia RootSIFT descriptors (unit norm) at COLMAP keypoints, as descriptor_attack samples them."""
    import torch
    from kornia.feature import SIFTDescriptor, extract_patches_from_pyramid, laf_from_center_scale_ori

    img = torch.from_numpy(gray.astype(np.float32))[None, None] / 255.0
    laf = laf_from_center_scale_ori(
        torch.from_numpy(kps[:, :2].copy())[None],
        torch.from_numpy(kps[:, 2:3] * patch_magnif)[None, :, :, None],
        torch.from_numpy(ori_sign * np.degrees(kps[:, 3:4]) + ori_offset_deg)[None].float(),
    )
    with torch.no_grad():
        d = SIFTDescriptor(32, rootsift=True)(extract_patches_from_pyramid(img, laf.float(), 32)[0]).numpy()
    return d / (np.linalg.norm(d, axis=1, keepdims=True) + 1e-9)
