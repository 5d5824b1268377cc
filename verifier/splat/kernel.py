"""Compiled CPU compositing (numba) with a hand-written backward, as the official 3DGS CUDA rasteriser.

Forward, per pixel of each 16 x 16 tile, front to back over the tile's depth-sorted Gaussians:
alpha = min(0.99, o exp(power)), power = -1/2 (a dx^2 + c dy^2) - b dx dy; skipped where
power > 0 or alpha < 1/255; stop before a Gaussian whose T (1 - alpha) < 1e-4 (left out, as the
reference's mask does). It stores the final transmittance T_final and how many of the tile's
list entries were walked (`n_walked`: the last contributor + 1) per pixel.

Backward (3DGS `renderCUDA` backward): walk the same list back to front from n_walked, recompute
alpha, recover T_i = T_{i+1} / (1 - alpha_i), and keep the running colour of everything behind
(`accum`) so dL/dalpha_i = T_i (c_i - accum_i) . dL/dC - T_final / (1 - alpha_i) bg . dL/dC.
The 0.99 clamp has zero gradient as in torch's clamp_max (the reference's autograd).

Tiles run in parallel (numba prange). Gradients are written per (tile, Gaussian) pair (each pair
belongs to one tile, so no two threads write the same row) and summed per Gaussian by the caller
with index_add_. All arithmetic is float64 whatever the caller's dtype (scalar code: no speed
cost), so float32 training gets float64 compositing.
"""

from __future__ import annotations

import math
from typing import Any, cast

import numba
import numpy as np
import torch
from numba import njit, prange

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4


@njit(inline="always")
def _box(mx: float, my: float, radius: float, x0: int, y0: int, x1: int,
         y1: int) -> tuple[int, int, int, int]:
    """Pixels of [x0, x1) x [y0, y1) whose centres lie within radius (L-inf) of the mean: outside,
    o G < 1/255 (the radius's definition), so those pixels would skip this Gaussian anyway."""
    bx0 = max(x0, int(math.floor(mx - radius - 0.5)))
    bx1 = min(x1, int(math.ceil(mx + radius - 0.5)) + 1)
    by0 = max(y0, int(math.floor(my - radius - 0.5)))
    by1 = min(y1, int(math.ceil(my + radius - 0.5)) + 1)
    return bx0, bx1, by0, by1


@njit(parallel=True, fastmath=False, cache=True)
def _forward_kernel(
    starts: np.ndarray, counts: np.ndarray, gauss_ids: np.ndarray,
    means: np.ndarray, conics: np.ndarray, opacity: np.ndarray, colours: np.ndarray, radii: np.ndarray,
    bg: np.ndarray, width: int, height: int, tile: int, tiles_x: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n_tiles = counts.shape[0]
    image = np.empty((height, width, 3))
    final_t = np.empty((height, width))
    n_walked = np.zeros((height, width), dtype=np.int64)
    for t in prange(n_tiles):
        x0 = (t % tiles_x) * tile
        y0 = (t // tiles_x) * tile
        x1 = min(x0 + tile, width)
        y1 = min(y0 + tile, height)
        start = starts[t]
        # per-pixel state of this tile; Gaussians outer, pixels inner: each pixel still sees the
        # tile's Gaussians front to back, and each Gaussian only visits the pixels of its box
        trans = np.ones((tile, tile))
        rgb = np.zeros((tile, tile, 3))
        walked = np.zeros((tile, tile), dtype=np.int64)
        done = np.zeros((tile, tile), dtype=np.bool_)
        n_done = 0
        n_pixels = (x1 - x0) * (y1 - y0)
        for k in range(counts[t]):
            if n_done == n_pixels:
                break
            gi = gauss_ids[start + k]
            mx = means[gi, 0]
            my = means[gi, 1]
            ca = conics[gi, 0]
            cb = conics[gi, 1]
            cc = conics[gi, 2]
            op = opacity[gi]
            bx0, bx1, by0, by1 = _box(mx, my, radii[gi], x0, y0, x1, y1)
            for py in range(by0, by1):
                dy = my - (py + 0.5)
                ly = py - y0
                for px in range(bx0, bx1):
                    lx = px - x0
                    if done[ly, lx]:
                        continue
                    dx = mx - (px + 0.5)
                    power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                    if power > 0.0:
                        continue
                    alpha = min(ALPHA_MAX, op * math.exp(power))
                    if alpha < ALPHA_MIN:
                        continue
                    tr = trans[ly, lx]
                    test_t = tr * (1.0 - alpha)
                    if test_t < TRANSMITTANCE_MIN:
                        done[ly, lx] = True
                        n_done += 1
                        continue
                    w = alpha * tr
                    rgb[ly, lx, 0] += colours[gi, 0] * w
                    rgb[ly, lx, 1] += colours[gi, 1] * w
                    rgb[ly, lx, 2] += colours[gi, 2] * w
                    trans[ly, lx] = test_t
                    walked[ly, lx] = k + 1
        for py in range(y0, y1):
            for px in range(x0, x1):
                tr = trans[py - y0, px - x0]
                for ch in range(3):
                    image[py, px, ch] = rgb[py - y0, px - x0, ch] + tr * bg[ch]
                final_t[py, px] = tr
                n_walked[py, px] = walked[py - y0, px - x0]
    return image, final_t, n_walked


@njit(parallel=True, fastmath=False, cache=True)
def _backward_kernel(
    starts: np.ndarray, counts: np.ndarray, gauss_ids: np.ndarray,
    means: np.ndarray, conics: np.ndarray, opacity: np.ndarray, colours: np.ndarray, radii: np.ndarray,
    bg: np.ndarray, final_t: np.ndarray, n_walked: np.ndarray, grad_image: np.ndarray,
    width: int, height: int, tile: int, tiles_x: int,
) -> np.ndarray:
    """Per-pair gradients (n_pairs x 9): d mean (2), d conic (3), d opacity (1), d colour (3)."""
    n_tiles = counts.shape[0]
    pair_grad = np.zeros((gauss_ids.shape[0], 9))
    for t in prange(n_tiles):
        x0 = (t % tiles_x) * tile
        y0 = (t // tiles_x) * tile
        x1 = min(x0 + tile, width)
        y1 = min(y0 + tile, height)
        start = starts[t]
        # per-pixel back-to-front state: T_i, colour behind (acc), the previous (behind) Gaussian
        trans = np.empty((tile, tile))
        acc = np.zeros((tile, tile, 3))
        last_alpha = np.zeros((tile, tile))
        last_col = np.zeros((tile, tile, 3))
        max_walked = 0
        for py in range(y0, y1):
            for px in range(x0, x1):
                trans[py - y0, px - x0] = final_t[py, px]
                max_walked = max(max_walked, n_walked[py, px])
        for k in range(max_walked - 1, -1, -1):
            gi = gauss_ids[start + k]
            mx = means[gi, 0]
            my = means[gi, 1]
            ca = conics[gi, 0]
            cb = conics[gi, 1]
            cc = conics[gi, 2]
            op = opacity[gi]
            cr = colours[gi, 0]
            cg = colours[gi, 1]
            cbl = colours[gi, 2]
            g_mx = 0.0
            g_my = 0.0
            g_ca = 0.0
            g_cb = 0.0
            g_cc = 0.0
            g_op = 0.0
            g_r = 0.0
            g_g = 0.0
            g_b = 0.0
            bx0, bx1, by0, by1 = _box(mx, my, radii[gi], x0, y0, x1, y1)
            for py in range(by0, by1):
                dy = my - (py + 0.5)
                ly = py - y0
                for px in range(bx0, bx1):
                    if k >= n_walked[py, px]:
                        continue  # behind this pixel's last contributor
                    lx = px - x0
                    dx = mx - (px + 0.5)
                    power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                    if power > 0.0:
                        continue
                    gauss = math.exp(power)
                    raw = op * gauss
                    alpha = min(ALPHA_MAX, raw)
                    if alpha < ALPHA_MIN:
                        continue
                    gr = grad_image[py, px, 0]
                    gg = grad_image[py, px, 1]
                    gb = grad_image[py, px, 2]
                    tr = trans[ly, lx] / (1.0 - alpha)
                    trans[ly, lx] = tr
                    w = alpha * tr
                    g_r += w * gr
                    g_g += w * gg
                    g_b += w * gb
                    # colour of everything behind this Gaussian, as 3DGS's accum_rec
                    la = last_alpha[ly, lx]
                    ar = la * last_col[ly, lx, 0] + (1.0 - la) * acc[ly, lx, 0]
                    ag = la * last_col[ly, lx, 1] + (1.0 - la) * acc[ly, lx, 1]
                    ab = la * last_col[ly, lx, 2] + (1.0 - la) * acc[ly, lx, 2]
                    acc[ly, lx, 0] = ar
                    acc[ly, lx, 1] = ag
                    acc[ly, lx, 2] = ab
                    last_col[ly, lx, 0] = cr
                    last_col[ly, lx, 1] = cg
                    last_col[ly, lx, 2] = cbl
                    last_alpha[ly, lx] = alpha
                    if raw > ALPHA_MAX:
                        continue  # clamped: no gradient to opacity or the Gaussian (clamp_max)
                    bg_dot = bg[0] * gr + bg[1] * gg + bg[2] * gb
                    d_alpha = tr * ((cr - ar) * gr + (cg - ag) * gg + (cbl - ab) * gb)
                    d_alpha -= final_t[py, px] / (1.0 - alpha) * bg_dot
                    g_op += gauss * d_alpha
                    d_power = raw * d_alpha  # d alpha / d power = o G
                    g_mx -= d_power * (ca * dx + cb * dy)
                    g_my -= d_power * (cb * dx + cc * dy)
                    g_ca -= d_power * 0.5 * dx * dx
                    g_cb -= d_power * dx * dy
                    g_cc -= d_power * 0.5 * dy * dy
            row = start + k
            pair_grad[row, 0] = g_mx
            pair_grad[row, 1] = g_my
            pair_grad[row, 2] = g_ca
            pair_grad[row, 3] = g_cb
            pair_grad[row, 4] = g_cc
            pair_grad[row, 5] = g_op
            pair_grad[row, 6] = g_r
            pair_grad[row, 7] = g_g
            pair_grad[row, 8] = g_b
    return pair_grad


def _np64(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to(torch.float64).numpy())


KERNEL_THREADS: int | None = None  # None: follow torch.get_num_threads(); set by set_kernel_threads


def set_kernel_threads(threads: int | None) -> None:
    """Threads for the compositing kernels (numba's pool), independent of torch's intra-op threads."""
    global KERNEL_THREADS
    KERNEL_THREADS = threads


def _sync_threads() -> None:
    wanted = KERNEL_THREADS or torch.get_num_threads()
    ceiling = cast(Any, numba.config).NUMBA_NUM_THREADS  # set from the environment at import
    numba.set_num_threads(max(1, min(wanted, ceiling)))


class CompositeFunction(torch.autograd.Function):
    """image (3 x H x W) = composite(means2d, conics, opacity, colours, bg; tile lists)."""

    @staticmethod
    def forward(
        ctx: Any,  # torch's FunctionCtx: forward leaves what backward needs as its attributes
        means2d: torch.Tensor, conics: torch.Tensor, opacity: torch.Tensor, colours: torch.Tensor,
        bg: torch.Tensor, radii: torch.Tensor, starts: torch.Tensor, counts: torch.Tensor,
        gauss_ids: torch.Tensor, geometry: tuple[int, int, int, int],
    ) -> torch.Tensor:
        width, height, tile, tiles_x = geometry
        _sync_threads()
        arrays = (
            starts.numpy(), counts.numpy(), gauss_ids.numpy(),
            _np64(means2d), _np64(conics), _np64(opacity), _np64(colours), _np64(radii), _np64(bg),
        )
        image, final_t, n_walked = _forward_kernel(*arrays, width, height, tile, tiles_x)
        ctx.arrays = arrays
        ctx.final_t = final_t
        ctx.n_walked = n_walked
        ctx.geometry = geometry
        ctx.n_gaussians = means2d.shape[0]
        ctx.dtype = means2d.dtype
        return torch.from_numpy(image).to(means2d.dtype).permute(2, 0, 1)

    @staticmethod
    def backward(
        ctx: Any, grad_image: torch.Tensor
    ) -> tuple[torch.Tensor | None, ...]:
        width, height, tile, tiles_x = ctx.geometry
        _sync_threads()
        grad_hwc = _np64(grad_image.permute(1, 2, 0))
        pair_grad = cast(Any, _backward_kernel)(  # numba's Dispatcher: its typing knows no arguments
            *ctx.arrays, ctx.final_t, ctx.n_walked, grad_hwc, width, height, tile, tiles_x
        )
        gauss_ids = torch.from_numpy(ctx.arrays[2])
        grads = torch.zeros(ctx.n_gaussians, 9, dtype=torch.float64)
        grads.index_add_(0, gauss_ids, torch.from_numpy(pair_grad))
        grads = grads.to(ctx.dtype)
        d_bg = None
        if ctx.needs_input_grad[4]:
            d_bg = torch.from_numpy((ctx.final_t[..., None] * grad_hwc).sum((0, 1))).to(ctx.dtype)
        return grads[:, 0:2], grads[:, 2:5], grads[:, 5], grads[:, 6:9], d_bg, None, None, None, None, None


def composite(
    means2d: torch.Tensor, conics: torch.Tensor, opacity: torch.Tensor, colours: torch.Tensor,
    bg: torch.Tensor, radii: torch.Tensor, starts: torch.Tensor, counts: torch.Tensor,
    gauss_ids: torch.Tensor, width: int, height: int, tile: int, tiles_x: int,
) -> torch.Tensor:
    """Differentiable 3 x H x W image from depth-sorted per-tile Gaussian lists (int64 tensors).

    radii: per Gaussian, the pixel radius beyond which o G < 1/255 (render.project's)."""
    index = tuple(x.to(torch.int64).contiguous() for x in (starts, counts, gauss_ids))
    return CompositeFunction.apply(
        means2d, conics, opacity, colours, bg, radii, *index, (width, height, tile, tiles_x)
    )
