"""Training a CPU Gaussian splat as official 3DGS does, scaled down to a bounded iteration count.

Loss (1 - 0.2) L1 + 0.2 (1 - SSIM); Adam (eps 1e-15) with 3DGS's learning rates (position
0.00016 x scene extent decaying exponentially to 1/100 of that, SH DC 0.0025, SH rest
0.0025/20, opacity 0.025, scale 0.005, rotation 0.001); SH degree raised from 0 to 1 partway.
Simplified adaptive density control: every `densify_interval` iterations between
`densify_from` and `densify_until`, Gaussians whose mean view-space positional gradient
(in 3DGS's NDC units) exceeds 0.0002 are cloned (small: max scale <= 1% of the extent) or
split in two (large: samples from the Gaussian, scales / 1.6); Gaussians with opacity < 0.005
are pruned; the count is capped at `max_gaussians`. No opacity reset (runs are short).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from verifier.splat.camera import Camera
from verifier.splat.gaussians import PARAM_NAMES, Gaussians, quaternion_to_matrix
from verifier.splat.loss import ssim_fast
from verifier.splat.render import RenderOutput, RenderSettings, render

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SplatOptions:
    long_edge: int = 200  # working resolution (pixels on the longer image edge)
    iterations: int = 1500
    time_budget_s: float | None = None  # stop early (after a whole iteration) past this
    sh_degree: int = 1
    sh_degree_up_at: int = 500
    white_background: bool = False
    lambda_dssim: float = 0.2
    position_lr_init: float = 0.00016
    position_lr_final: float = 0.0000016
    feature_lr: float = 0.0025
    opacity_lr: float = 0.025
    scaling_lr: float = 0.005
    rotation_lr: float = 0.001
    densify_from: int = 200
    densify_until_fraction: float = 0.6  # of `iterations`
    densify_interval: int = 100
    densify_grad_threshold: float = 0.0002
    percent_dense: float = 0.01
    min_opacity: float = 0.005
    max_gaussians: int = 50_000
    max_init_points: int = 50_000
    seed: int = 0
    threads: int | None = None  # torch.set_num_threads; None leaves torch's default
    tile_size: int = 16
    max_group_elements: int = 1 << 22
    checkpoint_groups: bool = False
    render_backend: str = "kernel"  # "kernel" (compiled, default) or "torch" (reference autograd)
    preview_views: int = 3
    cost2_long_edge: int = 800  # cost2 (clean vs poisoned) is measured at min(native, this)
    lpips_net: str = "vgg"

    def render_settings(self) -> RenderSettings:
        return RenderSettings(self.tile_size, False, self.max_group_elements, self.checkpoint_groups,
                              self.render_backend)


@dataclass
class TrainResult:
    gaussians: Gaussians
    iterations: int
    seconds: float
    losses: list[float] = field(default_factory=list)

    @property
    def iterations_per_second(self) -> float:
        return self.iterations / self.seconds if self.seconds > 0 else math.nan


def expon_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """3DGS's get_expon_lr_func without delay: log-linear from lr_init to lr_final."""
    t = min(max(step / max(max_steps, 1), 0.0), 1.0)
    return math.exp((1 - t) * math.log(lr_init) + t * math.log(lr_final))


def _make_optimizer(g: Gaussians, o: SplatOptions, extent: float) -> torch.optim.Adam:
    lrs = {
        "means": o.position_lr_init * extent, "sh_dc": o.feature_lr, "sh_rest": o.feature_lr / 20.0,
        "opacity_logits": o.opacity_lr, "log_scales": o.scaling_lr, "quats": o.rotation_lr,
    }
    groups = [{"params": [getattr(g, n)], "lr": lrs[n], "name": n} for n in PARAM_NAMES]
    return torch.optim.Adam(groups, lr=0.0, eps=1e-15)


def _rebuild(
    g: Gaussians, opt: torch.optim.Adam, keep: torch.Tensor, extra: dict[str, torch.Tensor]
) -> Gaussians:
    """New leaf tensors = old[keep] ++ extra; Adam moments follow (zeros for new rows)."""
    new_params: dict[str, torch.Tensor] = {}
    for group in opt.param_groups:
        name = group["name"]
        old = group["params"][0]
        add = extra[name]
        new = torch.cat([old.detach()[keep], add.detach()], 0).requires_grad_(True)
        state = opt.state.pop(old, None)
        if state:
            for key in ("exp_avg", "exp_avg_sq"):
                state[key] = torch.cat([state[key][keep], torch.zeros_like(add)], 0)
            opt.state[new] = state
        group["params"][0] = new
        new_params[name] = new
    return Gaussians(**new_params)


def densify_and_prune(g: Gaussians, opt: torch.optim.Adam, grad_mean: torch.Tensor, o: SplatOptions,
                      extent: float, generator: torch.Generator) -> Gaussians:
    with torch.no_grad():
        scales = g.scales()
        big = scales.max(dim=1).values > o.percent_dense * extent
        hot = grad_mean >= o.densify_grad_threshold
        room = max(o.max_gaussians - g.count, 0)
        candidates = torch.nonzero(hot).squeeze(1)
        # each clone adds 1, each split adds 1 net (2 new, original removed): cap by the hottest
        if candidates.numel() > room:
            candidates = candidates[torch.argsort(grad_mean[candidates], descending=True)[:room]]
        chosen = torch.zeros(g.count, dtype=torch.bool)
        chosen[candidates] = True
        clone = chosen & ~big
        split = chosen & big
        params = g.params()
        extra = {n: params[n].detach()[clone] for n in PARAM_NAMES}
        if split.any():
            s = scales[split].repeat(2, 1)
            samples = torch.randn(s.shape, generator=generator, dtype=s.dtype) * s
            rot = quaternion_to_matrix(g.quats.detach()[split]).repeat(2, 1, 1)
            split_params = {n: params[n].detach()[split].repeat(2, *([1] * (params[n].dim() - 1)))
                            for n in PARAM_NAMES}
            split_params["means"] = (rot @ samples[..., None]).squeeze(-1) + split_params["means"]
            split_params["log_scales"] = torch.log(s / (0.8 * 2))
            extra = {n: torch.cat([extra[n], split_params[n]], 0) for n in PARAM_NAMES}
        keep = ~split & (g.opacity().detach() >= o.min_opacity)
        # pruning also applies to the new rows
        new_ok = torch.sigmoid(extra["opacity_logits"]) >= o.min_opacity
        extra = {n: v[new_ok] for n, v in extra.items()}
        return _rebuild(g, opt, keep, extra)


class _GradStats:
    """Per-Gaussian screen-space gradient norms accumulated between densifications (3DGS's rule)."""

    def __init__(self, count: int) -> None:
        self.accum = torch.zeros(count)
        self.count = torch.zeros(count)

    @torch.no_grad()
    def add(self, out: RenderOutput, cam: Camera) -> None:
        if out.projected.means2d.grad is None:
            return
        vis = out.projected.radii > 0
        # 3DGS accumulates the gradient w.r.t. NDC coordinates: pixels x (W/2, H/2)
        ndc_scale = torch.tensor([cam.width * 0.5, cam.height * 0.5])
        norms = (out.projected.means2d.grad * ndc_scale).norm(dim=1)
        self.accum[vis] += norms[vis]
        self.count[vis] += 1

    def mean(self) -> torch.Tensor:
        return torch.nan_to_num(self.accum / self.count, nan=0.0)


def _training_step(
    g: Gaussians, opt: torch.optim.Optimizer, cam: Camera, gt: torch.Tensor, bg: torch.Tensor, sh: int,
    settings: RenderSettings, o: SplatOptions,
) -> tuple[float, RenderOutput]:
    """Render one view, L1 + D-SSIM loss against its image, backward; (loss, render output)."""
    out = render(g, cam, bg, sh, settings)
    l1 = (out.image - gt).abs().mean()
    loss = (1.0 - o.lambda_dssim) * l1 + o.lambda_dssim * (1.0 - ssim_fast(out.image, gt))
    opt.zero_grad(set_to_none=True)
    loss.backward()
    return float(loss.detach()), out


def train_splat(
    g: Gaussians,
    cameras: list[Camera],
    images: list[torch.Tensor],
    options: SplatOptions,
    extent: float,
    progress: Callable[[int, float, int], None] | None = None,
) -> TrainResult:
    """Optimise g on (camera, 3 x H x W image in [0, 1]) pairs; returns the trained Gaussians."""
    if len(cameras) != len(images) or not cameras:
        raise ValueError(f"need matching, non-empty cameras and images ({len(cameras)} vs {len(images)})")
    o = options
    if o.threads:
        torch.set_num_threads(o.threads)
    gen = torch.Generator().manual_seed(o.seed)
    rng = np.random.default_rng(o.seed)
    bg = torch.ones(3) if o.white_background else torch.zeros(3)
    settings = o.render_settings()
    opt = _make_optimizer(g, o, extent)
    densify_until = int(o.densify_until_fraction * o.iterations)
    grads = _GradStats(g.count)
    order: list[int] = []
    losses: list[float] = []
    start = time.perf_counter()
    it = 0
    for it in range(1, o.iterations + 1):
        opt.param_groups[0]["lr"] = expon_lr(  # group 0 is "means"
            it, o.position_lr_init * extent, o.position_lr_final * extent, o.iterations
        )
        order = order or list(rng.permutation(len(cameras)))
        view = order.pop()
        sh = min(o.sh_degree, 1) if it >= o.sh_degree_up_at else 0
        loss, out = _training_step(g, opt, cameras[view], images[view], bg, sh, settings, o)
        losses.append(loss)
        if it < densify_until:
            grads.add(out, cameras[view])
        opt.step()
        if o.densify_from <= it < densify_until and it % o.densify_interval == 0:
            g = densify_and_prune(g, opt, grads.mean(), o, extent, gen)
            grads = _GradStats(g.count)
            log.debug("densified", extra={"iteration": it, "gaussians": g.count})
        else:
            g = Gaussians(**{grp["name"]: grp["params"][0] for grp in opt.param_groups})
        if progress is not None and (it % 100 == 0 or it == o.iterations):
            progress(it, losses[-1], g.count)
        if o.time_budget_s is not None and time.perf_counter() - start > o.time_budget_s:
            break
    return TrainResult(g, it, time.perf_counter() - start, losses)


@torch.no_grad()
def render_views(g: Gaussians, cameras: list[Camera], options: SplatOptions) -> list[torch.Tensor]:
    bg = torch.ones(3) if options.white_background else torch.zeros(3)
    return [render(g, c, bg, options.sh_degree, options.render_settings()).image for c in cameras]
