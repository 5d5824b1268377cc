"""The paper's baseline perturbations, with the same shape of interface as the patch.

Each baseline is a pure function of the pixels, a `BaselineSpec` and the image's key (the
key seeds the random baselines, so a dataset is reproducible image by image). The paper's
grid: blur kernel 3/7/11/21, noise sigma 5/10/25/50, JPEG quality 10/25/50/75, rotation
15/30/45 deg, random rotation +-45 deg, shear 0.15-0.2 on X/Y/XY, random shear +-0.3.
Baselines act on 8-bit images (that is what the paper's pipeline feeds 3DGS).
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from typing import Literal

import numpy as np
from PIL import Image
from scipy.ndimage import gaussian_filter

BaselineKind = Literal["blur", "noise", "jpeg", "rotation", "shear", "random_rotation", "random_shear"]
BASELINE_KINDS: tuple[str, ...] = (
    "blur", "noise", "jpeg", "rotation", "shear", "random_rotation", "random_shear",
)


@dataclass(frozen=True)
class BaselineSpec:
    """kind and its one parameter: blur kernel size (odd px), noise sigma (8-bit levels),
    JPEG quality (1-95), rotation in degrees, shear factor; random kinds draw uniformly in
    [-value, value] per image. `axis` is the shear direction: "x", "y" or "xy"."""

    kind: BaselineKind
    value: float
    axis: Literal["x", "y", "xy"] = "xy"
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in BASELINE_KINDS:
            raise ValueError(f"unknown baseline {self.kind!r}; choose one of {', '.join(BASELINE_KINDS)}")
        if self.kind == "blur" and (self.value < 1 or int(self.value) % 2 == 0):
            raise ValueError(f"blur kernel size must be an odd integer >= 1, got {self.value}")
        if self.kind == "jpeg" and not 1 <= self.value <= 95:
            raise ValueError(f"JPEG quality must be in 1..95, got {self.value}")
        if self.kind == "noise" and self.value < 0:
            raise ValueError(f"noise sigma must be >= 0, got {self.value}")

    @property
    def label(self) -> str:
        suffix = f"-{self.axis}" if "shear" in self.kind else ""
        return f"{self.kind}{suffix}={self.value:g}"


def _rng(spec: BaselineSpec, image_key: str) -> np.random.Generator:
    digest = hashlib.sha256(f"{spec.seed}:{spec.kind}:{image_key}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "big"))


def gaussian_blur(pixels: np.ndarray, kernel_size: int) -> np.ndarray:
    """Blur with a k x k Gaussian; sigma from k as OpenCV's getGaussianKernel does."""
    sigma = 0.3 * ((kernel_size - 1) * 0.5 - 1) + 0.8
    radius = (kernel_size - 1) // 2
    sigmas = (sigma, sigma) + ((0,) if pixels.ndim == 3 else ())
    out = gaussian_filter(pixels.astype(np.float64), sigma=sigmas, truncate=radius / sigma, mode="reflect")
    return np.clip(np.floor(out + 0.5), 0, 255).astype(np.uint8)


def gaussian_noise(pixels: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    noisy = pixels.astype(np.float64) + rng.normal(0.0, sigma, size=pixels.shape)
    return np.clip(np.floor(noisy + 0.5), 0, 255).astype(np.uint8)


def jpeg_roundtrip(pixels: np.ndarray, quality: int) -> np.ndarray:
    image = Image.fromarray(pixels)
    alpha = None
    if image.mode in ("RGBA", "LA"):
        alpha = pixels[..., -1]
        image = image.convert("RGB" if image.mode == "RGBA" else "L")
    buffer = io.BytesIO()
    image.save(buffer, format="JPEG", quality=int(quality))
    out = np.asarray(Image.open(io.BytesIO(buffer.getvalue())))
    if alpha is not None:
        out = np.dstack([out, alpha])
    return out.astype(np.uint8)


def _affine(pixels: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Warp about the image centre with a 2x2 forward matrix; uncovered pixels become black
    (transparent for RGBA), as torchvision's functional transforms used in the paper do."""
    h, w = pixels.shape[:2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    inverse = np.linalg.inv(matrix)
    offset = centre - inverse @ centre
    coeffs = (inverse[0, 0], inverse[0, 1], offset[0], inverse[1, 0], inverse[1, 1], offset[1])
    image = Image.fromarray(pixels)
    warped = image.transform((w, h), Image.Transform.AFFINE, coeffs, resample=Image.Resampling.BICUBIC)
    return np.asarray(warped).astype(np.uint8)


def rotate(pixels: np.ndarray, degrees: float) -> np.ndarray:
    t = np.deg2rad(degrees)
    return _affine(pixels, np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]]))


def shear(pixels: np.ndarray, factor: float, axis: str) -> np.ndarray:
    sx = factor if "x" in axis else 0.0
    sy = factor if "y" in axis else 0.0
    return _affine(pixels, np.array([[1.0, sx], [sy, 1.0]]))


def apply_baseline(pixels: np.ndarray, spec: BaselineSpec, image_key: str = "") -> np.ndarray:
    """Return a perturbed copy of an 8-bit H x W [x C] image."""
    if pixels.dtype != np.uint8:
        raise TypeError(f"baselines act on 8-bit images, got {pixels.dtype}")
    if spec.kind == "blur":
        return gaussian_blur(pixels, int(spec.value))
    if spec.kind == "noise":
        return gaussian_noise(pixels, spec.value, _rng(spec, image_key))
    if spec.kind == "jpeg":
        return jpeg_roundtrip(pixels, int(spec.value))
    if spec.kind == "rotation":
        return rotate(pixels, spec.value)
    if spec.kind == "shear":
        return shear(pixels, spec.value, spec.axis)
    draw = float(_rng(spec, image_key).uniform(-spec.value, spec.value))
    if spec.kind == "random_rotation":
        return rotate(pixels, draw)
    return shear(pixels, draw, spec.axis)
