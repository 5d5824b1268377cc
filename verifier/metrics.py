"""Image metrics as the official 3DGS code computes them: SSIM and PSNR.

SSIM follows 3DGS `utils/loss_utils.py` exactly: an 11x11 Gaussian window (sigma 1.5,
normalised), applied per channel by a 2D convolution with zero padding 5 (so border pixels
see zeros), C1 = 0.01^2, C2 = 0.03^2, and the mean of the SSIM map over all channels and
pixels. PSNR follows 3DGS `utils/image_utils.py`: 20 log10(1 / sqrt(MSE)) on [0, 1] images.

Two entry points, same formula:
- `ssim(a, b)`, `psnr(a, b)`: NumPy float arrays in [0, 1], H x W x 3 (or H x W), return a
  float. Pure NumPy/SciPy (float64) so reports can use them without importing torch.
- `ssim_torch(a, b)`, `psnr_torch(a, b)`: torch tensors C x H x W or N x C x H x W,
  differentiable (the splat's D-SSIM loss uses `ssim_torch`). torch is imported lazily.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

if TYPE_CHECKING:
    import torch

WINDOW_SIZE = 11
WINDOW_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def gaussian_window_1d(size: int = WINDOW_SIZE, sigma: float = WINDOW_SIGMA) -> np.ndarray:
    """3DGS's `gaussian(window_size, sigma)`: exp(-(x - size//2)^2 / (2 sigma^2)), normalised."""
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-(x**2) / (2.0 * sigma**2))
    return g / g.sum()


def _as_float_image(x: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3:
        raise ValueError(f"{name}: expected an H x W or H x W x C array, got shape {arr.shape}")
    return arr


def _check_pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fa, fb = _as_float_image(a, "a"), _as_float_image(b, "b")
    if fa.shape != fb.shape:
        raise ValueError(f"images differ in shape: {fa.shape} vs {fb.shape}")
    return fa, fb


def _blur_zero_padded(x: np.ndarray) -> np.ndarray:
    """Separable Gaussian window per channel with zero padding (= conv2d(padding=5, groups=C))."""
    g = gaussian_window_1d()
    out = ndimage.correlate1d(x, g, axis=0, mode="constant", cval=0.0)
    return ndimage.correlate1d(out, g, axis=1, mode="constant", cval=0.0)


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The per-pixel, per-channel SSIM map (H x W x C) as 3DGS computes it, in float64."""
    fa, fb = _check_pair(a, b)
    mu1, mu2 = _blur_zero_padded(fa), _blur_zero_padded(fb)
    mu1_sq, mu2_sq, mu1_mu2 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    sigma1_sq = _blur_zero_padded(fa * fa) - mu1_sq
    sigma2_sq = _blur_zero_padded(fb * fb) - mu2_sq
    sigma12 = _blur_zero_padded(fa * fb) - mu1_mu2
    num = (2 * mu1_mu2 + SSIM_C1) * (2 * sigma12 + SSIM_C2)
    den = (mu1_sq + mu2_sq + SSIM_C1) * (sigma1_sq + sigma2_sq + SSIM_C2)
    return num / den


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """SSIM of two [0, 1] float images (H x W x C or H x W), exactly 3DGS's, as a float."""
    return float(ssim_map(a, b).mean())


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two [0, 1] float images; inf when identical."""
    fa, fb = _check_pair(a, b)
    mse = float(np.mean((fa - fb) ** 2))
    if mse == 0.0:
        return math.inf
    return 20.0 * math.log10(1.0 / math.sqrt(mse))


def to_unit_float(pixels: np.ndarray) -> np.ndarray:
    """uint8/uint16 (or float already in [0, 1]) pixels to float64 in [0, 1]."""
    if pixels.dtype == np.uint8:
        return pixels.astype(np.float64) / 255.0
    if pixels.dtype == np.uint16:
        return pixels.astype(np.float64) / 65535.0
    return pixels.astype(np.float64)


# --- torch (differentiable) ---------------------------------------------------------------

def _window_torch(channels: int, like: torch.Tensor) -> torch.Tensor:
    import torch

    g = torch.as_tensor(gaussian_window_1d(), dtype=like.dtype, device=like.device)
    w2 = torch.outer(g, g)
    return w2.expand(channels, 1, WINDOW_SIZE, WINDOW_SIZE).contiguous()


def ssim_torch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """3DGS's `ssim(img1, img2)` (size_average=True) on C x H x W or N x C x H x W tensors."""
    import torch.nn.functional as F

    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {tuple(a.shape)} vs {tuple(b.shape)}")
    x, y = (a[None], b[None]) if a.dim() == 3 else (a, b)
    channels = x.shape[1]
    w = _window_torch(channels, x)
    pad = WINDOW_SIZE // 2

    def blur(t: torch.Tensor) -> torch.Tensor:
        return F.conv2d(t, w, padding=pad, groups=channels)

    mu1, mu2 = blur(x), blur(y)
    mu1_sq, mu2_sq, mu1_mu2 = mu1.pow(2), mu2.pow(2), mu1 * mu2
    sigma1_sq = blur(x * x) - mu1_sq
    sigma2_sq = blur(y * y) - mu2_sq
    sigma12 = blur(x * y) - mu1_mu2
    num = (2 * mu1_mu2 + SSIM_C1) * (2 * sigma12 + SSIM_C2)
    den = (mu1_sq + mu2_sq + SSIM_C1) * (sigma1_sq + sigma2_sq + SSIM_C2)
    return (num / den).mean()


def psnr_torch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """3DGS's `psnr`: 20 log10(1 / sqrt(MSE)) over the whole tensor."""
    import torch

    mse = ((a - b) ** 2).mean()
    return 20.0 * torch.log10(1.0 / torch.sqrt(mse))
