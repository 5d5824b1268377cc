"""Differentiable tile-based rasterisation of 3D Gaussians on the CPU (3DGS's forward pass in torch).

Steps, after Kerbl et al. 2023 and its CUDA rasteriser:
1. EWA projection: camera-space mean t = R x + T; Jacobian of the perspective map at t,
   J = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]] (x/z, y/z clamped to 1.3 x the field of
   view as 3DGS does); 2D covariance J R Sigma R^T J^T + 0.3 I (the low-pass dilation).
   Gaussians with z <= 0.2 are culled.
2. Screen-space extent: radius r = sqrt(2 lambda_max ln(255 o)) pixels, the distance beyond
   which opacity o times the Gaussian falls below 1/255, the rasteriser's skip threshold. (3DGS
   uses 3 sqrt(lambda_max); ours is exact, so tile culling never changes the image.)
3. Tile binning: each Gaussian's square [u - r, u + r] x [v - r, v + r] lists the 16 x 16
   tiles it touches; (tile, Gaussian) pairs are sorted by tile then depth.
4. Per tile, front-to-back alpha compositing over only its Gaussians: alpha = min(0.99,
   o exp(-d^T Sigma2D^-1 d / 2)), skipped below 1/255; C = sum c_i alpha_i T_i + T_final bg with
   T_i = prod_{j<i}(1 - alpha_j); early termination: a Gaussian whose T_i (1 - alpha_i) would
   drop below 1e-4 and all behind it are left out.
Step 4 has two backends (RenderSettings.backend): "kernel" (default), numba-compiled per-pixel
loops with 3DGS's hand-written backward (verifier/splat/kernel.py); "torch", the reference: tiles
processed in groups, padded to the group's largest Gaussian count (tiles sorted by count, so
padding is small) and vectorised, autograd providing the backward pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.checkpoint import checkpoint

from verifier.splat.camera import Camera
from verifier.splat.gaussians import Gaussians

NEAR_PLANE = 0.2
DILATION = 0.3
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4


@dataclass(frozen=True)
class RenderSettings:
    tile_size: int = 16
    brute_force: bool = False  # every visible Gaussian in every tile (for tests)
    max_group_elements: int = 1 << 22  # pixels x Gaussians evaluated at once (memory bound)
    checkpoint_groups: bool = False  # recompute tile groups in backward: less memory, ~1.5x time
    # "kernel": compiled compositing with a hand-written backward (verifier/splat/kernel.py);
    # "torch": the dense per-tile autograd reference below (slow; kept to test the kernel against)
    backend: str = "kernel"


@dataclass
class Projected:
    means2d: torch.Tensor  # N x 2 pixels (grad retained when training: densification statistic)
    conics: torch.Tensor  # N x 3: inverse 2D covariance (a, b, c) of [[a, b], [b, c]]
    depths: torch.Tensor  # N
    radii: torch.Tensor  # N, int64 pixels; 0 = not visible
    opacity: torch.Tensor  # N
    colours: torch.Tensor  # N x 3


@dataclass
class RenderOutput:
    image: torch.Tensor  # 3 x H x W
    projected: Projected
    pairs: int  # (tile, Gaussian) pairs rasterised


def project(g: Gaussians, cam: Camera, sh_degree: int = 1) -> Projected:
    dtype = g.means.dtype
    rot = torch.as_tensor(cam.rotation, dtype=dtype)
    trans = torch.as_tensor(cam.translation, dtype=dtype)
    t = g.means @ rot.T + trans
    z = t[:, 2]
    in_front = z > NEAR_PLANE
    zs = torch.where(in_front, z, torch.ones_like(z))  # keep culled rows finite
    lim_x = 1.3 * cam.width / (2 * cam.fx)
    lim_y = 1.3 * cam.height / (2 * cam.fy)
    tx = (t[:, 0] / zs).clamp(-lim_x, lim_x) * zs
    ty = (t[:, 1] / zs).clamp(-lim_y, lim_y) * zs
    zero = torch.zeros_like(zs)
    jac = torch.stack(
        [
            torch.stack([cam.fx / zs, zero, -cam.fx * tx / zs**2], dim=1),
            torch.stack([zero, cam.fy / zs, -cam.fy * ty / zs**2], dim=1),
        ],
        dim=1,
    )  # N x 2 x 3
    m = jac @ rot  # J W
    cov2d = m @ g.covariance() @ m.transpose(1, 2)
    a = cov2d[:, 0, 0] + DILATION
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + DILATION
    det = a * c - b * b
    ok = in_front & (det > 0)
    det_s = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([c / det_s, -b / det_s, a / det_s], dim=1)
    means2d = torch.stack([cam.fx * t[:, 0] / zs + cam.cx, cam.fy * t[:, 1] / zs + cam.cy], dim=1)
    opacity = g.opacity()
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam_max = mid + torch.sqrt(torch.clamp_min(mid * mid - det, 0.1))
        log_term = torch.log(torch.clamp_min(255.0 * opacity, 1.0))
        radii = torch.ceil(torch.sqrt(2.0 * lam_max * log_term)).to(torch.int64)
        u, v = means2d[:, 0], means2d[:, 1]
        on_screen = (u + radii > 0) & (u - radii < cam.width) & (v + radii > 0) & (v - radii < cam.height)
        radii = torch.where(ok & on_screen, radii, torch.zeros_like(radii))
    centre = torch.as_tensor(cam.centre, dtype=dtype)
    return Projected(means2d, conics, z, radii, opacity, g.colours(centre, sh_degree))


def _bin(proj: Projected, cam: Camera, tiles_x: int, tiles_y: int, tile: int,
         brute_force: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """(tile id, Gaussian id) pairs sorted by tile then depth."""
    visible = torch.nonzero(proj.radii > 0).squeeze(1)
    visible = visible[torch.argsort(proj.depths.detach()[visible], stable=True)]
    n_tiles = tiles_x * tiles_y
    if brute_force:
        tile_ids = torch.arange(n_tiles).repeat_interleave(visible.numel())
        return tile_ids, visible.repeat(n_tiles)
    uv = proj.means2d.detach()[visible]
    r = proj.radii[visible].to(uv.dtype)
    x0 = torch.floor((uv[:, 0] - r) / tile).clamp(0, tiles_x - 1).to(torch.int64)
    x1 = torch.floor((uv[:, 0] + r) / tile).clamp(0, tiles_x - 1).to(torch.int64)
    y0 = torch.floor((uv[:, 1] - r) / tile).clamp(0, tiles_y - 1).to(torch.int64)
    y1 = torch.floor((uv[:, 1] + r) / tile).clamp(0, tiles_y - 1).to(torch.int64)
    w = x1 - x0 + 1
    counts = w * (y1 - y0 + 1)
    owner = torch.repeat_interleave(torch.arange(visible.numel()), counts)
    first = torch.cumsum(counts, 0) - counts
    offset = torch.arange(owner.numel()) - first[owner]
    tile_ids = (y0[owner] + offset // w[owner]) * tiles_x + x0[owner] + offset % w[owner]
    order = torch.argsort(tile_ids, stable=True)  # stable: depth order survives within a tile
    return tile_ids[order], visible[owner[order]]


def _composite(pix: torch.Tensor, valid: torch.Tensor, means: torch.Tensor, conics: torch.Tensor,
               opacity: torch.Tensor, colours: torch.Tensor, bg: torch.Tensor) -> torch.Tensor:
    """pix G x P x 2, valid G x K, per-tile Gaussians G x K x ... -> colours G x P x 3."""
    dx = pix[:, :, None, 0] - means[:, None, :, 0]
    dy = pix[:, :, None, 1] - means[:, None, :, 1]
    power = -0.5 * (conics[:, None, :, 0] * dx * dx + conics[:, None, :, 2] * dy * dy) \
        - conics[:, None, :, 1] * dx * dy
    # clamp before exp: no overflow (and no inf * 0 in backward) where power > 0 is skipped anyway
    alpha = torch.clamp_max(opacity[:, None, :] * torch.exp(power.clamp_max(0.0)), ALPHA_MAX)
    keep = (power <= 0) & (alpha >= ALPHA_MIN) & valid[:, None, :]
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    t_after = torch.cumprod(1.0 - alpha, dim=-1)
    t_before = torch.cat([torch.ones_like(t_after[..., :1]), t_after[..., :-1]], dim=-1)
    weights = alpha * t_before * (t_after >= TRANSMITTANCE_MIN).to(alpha.dtype)
    rgb = torch.einsum("gpk,gkc->gpc", weights, colours)
    return rgb + (1.0 - weights.sum(-1, keepdim=True)) * bg


def rasterise(
    proj: Projected, cam: Camera, bg: torch.Tensor, settings: RenderSettings
) -> tuple[torch.Tensor, int]:
    tile = settings.tile_size
    tiles_x, tiles_y = math.ceil(cam.width / tile), math.ceil(cam.height / tile)
    n_tiles = tiles_x * tiles_y
    dtype = proj.means2d.dtype
    tile_ids, gauss_ids = _bin(proj, cam, tiles_x, tiles_y, tile, settings.brute_force)
    counts = torch.bincount(tile_ids, minlength=n_tiles)
    starts = torch.cumsum(counts, 0) - counts
    if settings.backend == "kernel":
        from verifier.splat.kernel import composite

        image = composite(proj.means2d, proj.conics, proj.opacity, proj.colours, bg.to(dtype), proj.radii,
                          starts, counts, gauss_ids, cam.width, cam.height, tile, tiles_x)
        return image, int(tile_ids.numel())
    if settings.backend != "torch":
        raise ValueError(f"unknown render backend {settings.backend!r} (expected 'kernel' or 'torch')")
    local = (torch.arange(tile) + 0.5).to(dtype)
    py, px = torch.meshgrid(local, local, indexing="ij")
    offsets = torch.stack([px.reshape(-1), py.reshape(-1)], dim=1)  # P x 2 (x, y)
    bg = bg.to(dtype)
    out = bg.expand(n_tiles, tile * tile, 3).clone()

    busy = torch.nonzero(counts > 0).squeeze(1)
    busy = busy[torch.argsort(counts[busy], descending=True, stable=True)]
    busy_counts = counts[busy].tolist()
    pixels_per_tile = tile * tile
    i = 0
    while i < len(busy_counts):
        k = busy_counts[i]  # the group's largest count (sorted descending)
        g = max(1, settings.max_group_elements // (pixels_per_tile * k))
        group = busy[i : i + g]
        i += g
        pos = torch.arange(k)
        valid = pos[None, :] < counts[group][:, None]
        flat = (starts[group][:, None] + pos[None, :]).clamp_max(max(tile_ids.numel() - 1, 0))
        gid = torch.where(valid, gauss_ids[flat], torch.zeros_like(flat))
        origin = torch.stack([(group % tiles_x) * tile, (group // tiles_x) * tile], dim=1).to(dtype)
        pix = origin[:, None, :] + offsets[None]
        args = (pix, valid, proj.means2d[gid], proj.conics[gid], proj.opacity[gid], proj.colours[gid], bg)
        if settings.checkpoint_groups and torch.is_grad_enabled():
            rgb = checkpoint(_composite, *args, use_reentrant=False)
        else:
            rgb = _composite(*args)
        out = out.index_copy(0, group, rgb)
    image = out.view(tiles_y, tiles_x, tile, tile, 3).permute(0, 2, 1, 3, 4).reshape(
        tiles_y * tile, tiles_x * tile, 3
    )
    return image[: cam.height, : cam.width].permute(2, 0, 1), int(tile_ids.numel())


def render(g: Gaussians, cam: Camera, bg: torch.Tensor | None = None, sh_degree: int = 1,
           settings: RenderSettings | None = None) -> RenderOutput:
    """Render Gaussians into a 3 x H x W image (differentiable w.r.t. every parameter)."""
    settings = settings or RenderSettings()
    if bg is None:
        bg = torch.zeros(3, dtype=g.means.dtype)
    proj = project(g, cam, sh_degree)
    if proj.means2d.requires_grad:
        proj.means2d.retain_grad()
    image, pairs = rasterise(proj, cam, bg, settings)
    return RenderOutput(image, proj, pairs)


def to_uint8(image: torch.Tensor) -> np.ndarray:
    """3 x H x W tensor in [0, 1] -> H x W x 3 uint8."""
    arr = image.detach().clamp(0, 1).permute(1, 2, 0).cpu().numpy()
    return np.floor(arr * 255.0 + 0.5).astype(np.uint8)
