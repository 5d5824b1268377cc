"""Figures for experiments and reports (matplotlib, Agg, PNG bytes).

- `tradeoff_png`: the paper's trade-off figure, one point per method/setting: reconstruction
  degradation (y) against imperceptibility (x).
- `parameter_pngs`: one metric-vs-parameter figure per swept parameter.
- `trajectory_png`: camera centres clean vs poisoned in 3D (poisoned aligned onto clean).

Only the object-oriented API (Figure + FigureCanvasAgg): no pyplot state, no GUI backend, safe
in any thread. Every function returns PNG bytes; callers embed or write them.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from verifier.poses import Pose, camera_centre, robust_similarity

KIND_COLOURS = {"patch": "#c2410c", "baseline": "#1d4ed8", "clean": "#15803d"}

# column in an aggregate entry -> axis label
AXIS_LABELS = {
    "cvp_ssim": "clean-vs-poisoned SSIM (cost2, higher = less visible)",
    "cvp_psnr": "clean-vs-poisoned PSNR dB (cost2)",
    "cvp_lpips": "clean-vs-poisoned LPIPS (cost2, lower = less visible)",
    "render_ssim": "render SSIM (cost1, lower = more degraded)",
    "render_psnr": "render PSNR dB (cost1)",
    "render_lpips": "render LPIPS (cost1, higher = more degraded)",
    "within5_of_clean": "cameras within 5° of clean SfM (Verifier I, lower = more degraded)",
    "poisoned_within5_of_gt": "cameras within 5° of ground truth",
    "median_rot_err_deg": "median camera rotation error ° vs clean",
}
PARAM_LABELS = {
    "patch_size": "patch size P (px or fraction)",
    "block_size": "block size b",
    "alpha": "blend α",
    "contrast": "contrast Δc",
    "ratio": "poisoning ratio",
    "pattern": "pattern",
}


@dataclass(frozen=True)
class PlotOptions:
    width_in: float = 7.0
    height_in: float = 5.0
    dpi: int = 100


def _png(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    return buf.getvalue()


def _mean_std(entry: Mapping[str, Any], column: str) -> tuple[float | None, float]:
    s = entry.get(column)
    mean = getattr(s, "mean", None)
    if mean is None or not math.isfinite(mean):
        return None, 0.0
    return float(mean), float(getattr(s, "std", None) or 0.0)


def degradation_axis(entries: Sequence[Mapping[str, Any]]) -> str:
    """render SSIM (cost1) when any setting has it, else Verifier I's cameras within 5°."""
    has_render = any(_mean_std(e, "render_ssim")[0] is not None for e in entries if e.get("kind") != "clean")
    return "render_ssim" if has_render else "within5_of_clean"


def tradeoff_png(
    entries: Sequence[Mapping[str, Any]],
    x: str = "cvp_ssim",
    y: str | None = None,
    options: PlotOptions | None = None,
) -> bytes:
    """One point per setting (error bars = std over runs); the paper's trade-off figure."""
    options = options or PlotOptions()
    y = y or degradation_axis(entries)
    fig = Figure(figsize=(options.width_in, options.height_in), dpi=options.dpi)
    ax = fig.add_subplot()
    for kind, colour in KIND_COLOURS.items():
        pts = []
        for e in entries:
            if e.get("kind") != kind:
                continue
            (xm, xs), (ym, ys) = _mean_std(e, x), _mean_std(e, y)
            if xm is not None and ym is not None:
                pts.append((xm, xs, ym, ys, str(e.get("label", ""))))
        if not pts:
            continue
        xs_, xe, ys_, ye, labels = zip(*pts, strict=True)
        ax.errorbar(xs_, ys_, xerr=xe, yerr=ye, fmt="o", color=colour, label=kind, capsize=3)
        for px, py, label in zip(xs_, ys_, labels, strict=True):
            ax.annotate(_short(label), (px, py), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_xlabel(AXIS_LABELS.get(x, x))
    ax.set_ylabel(AXIS_LABELS.get(y, y))
    ax.set_title("Trade-off: reconstruction degradation vs imperceptibility")
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize=8)
    return _png(fig)


def _short(label: str) -> str:
    """'P=100 b=4 a=1 c=255 checkerboard r=1' -> 'P=100 b=4 a=1' (the parts that vary most)."""
    parts = label.split()
    return " ".join(parts[:3]) if len(parts) > 3 else label


def _numeric(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def parameter_pngs(
    entries: Sequence[Mapping[str, Any]],
    metrics: Sequence[str] = ("within5_of_clean", "render_ssim", "cvp_ssim", "cvp_psnr"),
    options: PlotOptions | None = None,
) -> dict[str, bytes]:
    """{parameter: PNG} with one panel per metric that has values, over that parameter's sweep."""
    options = options or PlotOptions()
    out: dict[str, bytes] = {}
    for param in PARAM_LABELS:
        members = [e for e in entries if param in e.get("groups", ())]
        if len(members) < 2:
            continue
        values = [e.get("params", {}).get(param) for e in members]
        floats = [x for x in (_numeric(v) for v in values) if x is not None]
        numeric = len(floats) == len(values)
        if numeric:
            order = sorted(range(len(members)), key=lambda i: floats[i])
        else:
            order = sorted(range(len(members)), key=lambda i: str(values[i]))
        panels = [m for m in metrics if any(_mean_std(e, m)[0] is not None for e in members)]
        if not panels:
            continue
        fig = Figure(figsize=(options.width_in, 2.6 * len(panels)), dpi=options.dpi)
        for k, metric in enumerate(panels):
            ax = fig.add_subplot(len(panels), 1, k + 1)
            xs = [floats[i] if numeric else float(k2) for k2, i in enumerate(order)]
            stats = [_mean_std(members[i], metric) for i in order]
            ys = [np.nan if m is None else m for m, _ in stats]
            ax.errorbar(xs, ys, yerr=[s for _, s in stats], fmt="o-", color=KIND_COLOURS["patch"], capsize=3)
            if not numeric:
                ax.set_xticks(xs, [str(values[i]) for i in order])
            ax.set_ylabel(metric, fontsize=8)
            ax.grid(True, alpha=0.3)
        fig.axes[0].set_title(f"Metrics against {PARAM_LABELS[param]}")
        fig.axes[-1].set_xlabel(PARAM_LABELS[param])
        out[param] = _png(fig)
    return out


def aligned_centres(poisoned: Mapping[str, Pose], clean: Mapping[str, Pose]) -> dict[str, np.ndarray]:
    """Poisoned camera centres mapped into the clean frame (robust similarity on common cameras)."""
    return alignment(poisoned, clean)[0]


def alignment(poisoned: Mapping[str, Pose], clean: Mapping[str, Pose]) -> tuple[dict[str, np.ndarray], bool]:
    """(poisoned camera centres in the clean frame, whether they could be aligned): with fewer than
    3 common cameras, or no similarity found, the centres stay as they were (a caption says so)."""
    common = sorted(set(poisoned) & set(clean))
    centres = {n: camera_centre(p) for n, p in poisoned.items()}
    if len(common) < 3:
        return centres, False
    sim, _ = robust_similarity(
        np.array([centres[n] for n in common]), np.array([camera_centre(clean[n]) for n in common])
    )
    if sim is None:
        return centres, False
    return {n: sim.apply(c[None])[0] for n, c in centres.items()}, True


def _view_box(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and half-width of the plotted cube: the clean cameras' spread, with a margin."""
    centre = np.median(points, axis=0)
    radius = float(np.max(np.linalg.norm(points - centre, axis=1))) if len(points) else 1.0
    return centre, 1.6 * max(radius, 1e-6)


def trajectory_png(
    clean: Mapping[str, Pose],
    poisoned: Mapping[str, Pose],
    title: str = "Camera centres: clean SfM vs poisoned SfM (aligned onto clean)",
    options: PlotOptions | None = None,
) -> bytes:
    """3D scatter of camera centres, clean (green) vs poisoned (orange), lines between the same image.

    The view is the clean cameras' cube (a wrecked poisoned solution can put cameras hundreds of
    scene radii away, which would shrink the clean ring to a dot): poisoned cameras outside it are
    drawn on its faces as crosses.
    """
    options = options or PlotOptions()
    fig = Figure(figsize=(options.width_in, options.height_in), dpi=options.dpi)
    ax = fig.add_subplot(projection="3d")
    c = {n: camera_centre(p) for n, p in clean.items()}
    p = aligned_centres(poisoned, clean)
    ref = np.array(list(c.values()) or list(p.values()) or [np.zeros(3)])
    centre, half = _view_box(ref)
    lo, hi = centre - half, centre + half
    clipped = {n: np.clip(x, lo, hi) for n, x in p.items()}
    outside = {n for n, x in p.items() if not np.array_equal(clipped[n], x)}
    if c:
        arr = np.array([c[n] for n in sorted(c)])
        ax.scatter(arr[:, 0], arr[:, 1], arr[:, 2], color=KIND_COLOURS["clean"], label=f"clean ({len(c)})")
    inside = sorted(set(p) - outside)
    if inside:
        arr = np.array([clipped[n] for n in inside])
        ax.scatter(
            arr[:, 0], arr[:, 1], arr[:, 2], color=KIND_COLOURS["patch"], label=f"poisoned ({len(inside)})"
        )
    if outside:
        arr = np.array([clipped[n] for n in sorted(outside)])
        ax.scatter(arr[:, 0], arr[:, 1], arr[:, 2], color=KIND_COLOURS["patch"], marker="x",
                   label=f"poisoned, beyond the view ({len(outside)})")  # fmt: skip
    for n in sorted(set(c) & set(p)):
        seg = np.array([c[n], clipped[n]])
        ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="#888888", linewidth=0.6)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_title(title, fontsize=9)
    if c or p:
        ax.legend(loc="upper left", fontsize=8)
    return _png(fig)
