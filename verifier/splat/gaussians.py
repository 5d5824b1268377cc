"""Anisotropic 3D Gaussians: parameters, covariance from scale + quaternion, SH colour (degree 0-1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199

PARAM_NAMES = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")


@dataclass
class Gaussians:
    """Leaf tensors (requires_grad) of N Gaussians, named as 3DGS's parameter groups."""

    means: torch.Tensor  # N x 3, world
    log_scales: torch.Tensor  # N x 3, scale = exp
    quats: torch.Tensor  # N x 4 (w, x, y, z), normalised on use
    opacity_logits: torch.Tensor  # N, opacity = sigmoid
    sh_dc: torch.Tensor  # N x 3, degree-0 coefficient
    sh_rest: torch.Tensor  # N x 3 x 3, degree-1 coefficients [basis, rgb]; zeros when sh_degree = 0

    @property
    def count(self) -> int:
        return int(self.means.shape[0])

    def params(self) -> dict[str, torch.Tensor]:
        return {name: getattr(self, name) for name in PARAM_NAMES}

    def requires_grad_(self, flag: bool = True) -> Gaussians:
        for t in self.params().values():
            t.requires_grad_(flag)
        return self

    def opacity(self) -> torch.Tensor:
        return torch.sigmoid(self.opacity_logits)

    def scales(self) -> torch.Tensor:
        return torch.exp(self.log_scales)

    def covariance(self) -> torch.Tensor:
        """Sigma = R S S^T R^T (N x 3 x 3), 3DGS's computeCov3D."""
        rot = quaternion_to_matrix(self.quats)
        m = rot * self.scales()[:, None, :]  # R S
        return m @ m.transpose(1, 2)

    def colours(self, camera_centre: torch.Tensor, sh_degree: int) -> torch.Tensor:
        """RGB (N x 3) seen from camera_centre: SH evaluated along the view direction, +0.5, >= 0."""
        rgb = SH_C0 * self.sh_dc
        if sh_degree >= 1:
            d = self.means - camera_centre
            d = d / d.norm(dim=1, keepdim=True).clamp_min(1e-12)
            x, y, z = d[:, 0:1], d[:, 1:2], d[:, 2:3]
            rest = self.sh_rest
            rgb = rgb - SH_C1 * y * rest[:, 0] + SH_C1 * z * rest[:, 1] - SH_C1 * x * rest[:, 2]
        return torch.clamp_min(rgb + 0.5, 0.0)


def quaternion_to_matrix(quats: torch.Tensor) -> torch.Tensor:
    q = quats / quats.norm(dim=1, keepdim=True)
    w, x, y, z = q.unbind(1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=1,
    ).view(-1, 3, 3)


def rgb_to_sh_dc(rgb: np.ndarray) -> np.ndarray:
    return (rgb - 0.5) / SH_C0


def from_points(xyz: np.ndarray, rgb: np.ndarray, dtype: torch.dtype = torch.float32,
                initial_opacity: float = 0.1) -> Gaussians:
    """3DGS's create_from_pcd: isotropic scale = sqrt(mean squared distance to 3 nearest points),
    identity rotation, opacity 0.1, colour from the points' RGB in [0, 1]."""
    xyz = np.asarray(xyz, dtype=np.float64)
    n = xyz.shape[0]
    if n < 2:
        raise ValueError(f"need at least 2 points to initialise Gaussians, got {n}")
    k = min(4, n)
    dist, _ = cKDTree(xyz).query(xyz, k=k)
    mean_sq = np.maximum((dist[:, 1:] ** 2).mean(1), 1e-7)
    log_scale = np.log(np.sqrt(mean_sq))[:, None].repeat(3, axis=1)
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    logit = np.log(initial_opacity / (1 - initial_opacity))

    def t(a: np.ndarray) -> torch.Tensor:
        return torch.tensor(a, dtype=dtype)

    return Gaussians(
        means=t(xyz), log_scales=t(log_scale), quats=t(quats), opacity_logits=t(np.full(n, logit)),
        sh_dc=t(rgb_to_sh_dc(np.asarray(rgb, dtype=np.float64))), sh_rest=t(np.zeros((n, 3, 3))),
    ).requires_grad_(True)
