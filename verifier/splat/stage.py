"""The paper's two costs with our CPU splat: `run_splat_stage(...) -> dict`.

- cost1 (reconstruction degradation): train a splat on the poisoned images with the poses that
  SfM found on them, render it at those poses and compare with the poisoned inputs (SSIM, PSNR,
  LPIPS); the same for the clean set (clean renders vs clean inputs) as the reference.
- cost2 (imperceptibility): SSIM, PSNR, LPIPS of each poisoned image vs its clean original.

`run_splat_stage` runs the work in a child process (`python -m verifier.splat.stage`, job JSON
on stdin, result JSON in out_dir), so a caller never imports torch or pycolmap and a crash is a
result ("crashed"), not a dead caller. The child runs in its own process group (run_child): a
timeout or the cancel event kills all of it. This module's top level imports neither.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import msgspec

from verifier.childenv import child_env
from verifier.supervise import run_child

log = logging.getLogger(__name__)

RESULT_NAME = "splat.json"
PREVIEW_NAME = "splat_views.png"


class SplatJob(msgspec.Struct, frozen=True):
    """What the parent sends the splat child (JSON on stdin)."""

    clean_model_dir: str
    clean_images: str
    poisoned_model_dir: str
    poisoned_images: str
    out_dir: str
    options: dict[str, Any] = {}  # SplatOptions' fields (the parent must not import torch)


class SplatResult(msgspec.Struct):
    """What the child writes to out_dir/splat.json; the parent checks it on the way in.

    outcome: "ok" | "failed" (error says why) | "crashed" | "cancelled" (no result file: the parent's)."""

    outcome: str
    error: str | None = None
    clean: dict[str, Any] | None = None  # per side: cost1 (renders vs inputs), views, iterations, seconds
    poisoned: dict[str, Any] | None = None
    cost1: dict[str, Any] | None = None  # the poisoned side's cost1 (the paper's reconstruction cost)
    cost2: dict[str, Any] | None = None  # poisoned vs clean images (the paper's imperceptibility cost)
    lpips_net: str | None = None
    lpips_unavailable: str | None = None
    preview: str | None = None
    preview_views: Any = None
    preview_layout: str | None = None
    seconds: float | None = None
    options: dict[str, Any] | None = None


def _options_cls() -> Any:
    from verifier.splat.train import SplatOptions

    return SplatOptions


def __getattr__(name: str) -> Any:  # `from verifier.splat.stage import SplatOptions`, lazily (torch)
    if name == "SplatOptions":
        return _options_cls()
    raise AttributeError(name)


def run_splat_stage(
    clean_model_dir: Path,
    clean_images: Path,
    poisoned_model_dir: Path,
    poisoned_images: Path,
    out_dir: Path,
    options: Any | None = None,
    timeout_s: float | None = None,
    cancel: threading.Event | None = None,
) -> dict:
    """Train clean and poisoned splats in a child process and return their metrics (see module doc).

    The dict always has "outcome": "ok" | "failed" (with "error") | "crashed" (child died,
    or ran past timeout_s) | "cancelled" (cancel was set).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    job = SplatJob(
        str(clean_model_dir), str(clean_images), str(poisoned_model_dir), str(poisoned_images), str(out_dir),
        # a SplatOptions, or its fields as a dict (callers that must not import torch pass a dict)
        dict(options) if isinstance(options, dict) else msgspec.to_builtins(options) if options else {},
    )  # fmt: skip
    result_path = out_dir / RESULT_NAME
    result_path.unlink(missing_ok=True)
    started = time.time()
    ended = run_child(
        [sys.executable, "-m", "verifier.splat.stage"],
        log_path=out_dir / "splat.log",
        stdin_data=msgspec.json.encode(job),
        timeout_s=timeout_s,
        cancel=cancel,
        env={**child_env(), "OMP_WAIT_POLICY": "PASSIVE"},  # see verifier/splat/__init__.py
    )
    if result_path.is_file():
        try:
            return msgspec.to_builtins(msgspec.json.decode(result_path.read_bytes(), type=SplatResult))
        except msgspec.ValidationError as exc:  # the child's own file: a broken one is a failed stage
            return {"outcome": "failed", "error": f"unreadable splat result: {exc}"}
    why = {
        "timeout": "timed out",
        "cancelled": "was cancelled",
        "crashed": f"was killed by {ended.signal_name}",
    }.get(ended.kind, f"exited with code {ended.returncode}")
    return {
        "outcome": "cancelled" if ended.kind == "cancelled" else "crashed",
        "error": f"splat child {why} without a result (see {out_dir / 'splat.log'})",
        "seconds": time.time() - started,
    }


# --- everything below runs in the child ----------------------------------------------------


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _image_metrics(pairs: list[tuple[Any, Any]], lpips_model: Any) -> dict[str, float | None]:
    """Mean SSIM/PSNR/LPIPS over (a, b) pairs of H x W x 3 float arrays in [0, 1]."""
    from verifier.metrics import psnr, ssim

    ssims = [ssim(a, b) for a, b in pairs]
    psnrs = [psnr(a, b) for a, b in pairs]
    lp = [lpips_model.distance(a, b) for a, b in pairs] if lpips_model is not None else []
    return {
        "ssim": sum(ssims) / len(ssims),
        # inf (identical images) is not JSON; report the mean of finite values, None when none are
        "psnr": _finite(sum(p for p in psnrs if math.isfinite(p)) / max(1, sum(map(math.isfinite, psnrs))))
        if any(map(math.isfinite, psnrs))
        else None,
        "lpips": (sum(lp) / len(lp)) if lp else None,
    }


def _train_side(model_dir: Path, images_dir: Path, options: Any, lpips_model: Any) -> tuple[dict, Any, Any]:
    from verifier.splat.camera import scene_extent
    from verifier.splat.gaussians import from_points
    from verifier.splat.scenes import load_colmap_scene
    from verifier.splat.train import render_views, train_splat

    bg = (1.0, 1.0, 1.0) if options.white_background else (0.0, 0.0, 0.0)
    scene = load_colmap_scene(
        model_dir, images_dir, options.long_edge, bg, options.max_init_points, options.seed
    )
    g = from_points(scene.points, scene.colours)
    result = train_splat(g, scene.cameras, scene.images, options, scene_extent(scene.cameras))
    renders = render_views(result.gaussians, scene.cameras, options)
    pairs = [
        (r.clamp(0, 1).permute(1, 2, 0).numpy(), i.permute(1, 2, 0).numpy())
        for r, i in zip(renders, scene.images, strict=True)
    ]
    t_cost1 = time.time()
    cost1 = _image_metrics(pairs, lpips_model)
    side = {
        "cost1": cost1,
        "cost1_seconds": round(time.time() - t_cost1, 2),
        "views": len(scene.cameras),
        "init_points": int(len(scene.points)),
        "gaussians": result.gaussians.count,
        "iterations": result.iterations,
        "train_seconds": round(result.seconds, 2),
        "final_loss": result.losses[-1] if result.losses else None,
    }
    return side, scene, renders


def _cost2(
    clean_images: Path, poisoned_images: Path, names: list[str], options: Any, lpips_model: Any
) -> dict[str, Any]:
    import PIL.Image

    from verifier.splat.scenes import load_rgb

    bg = (1.0, 1.0, 1.0) if options.white_background else (0.0, 0.0, 0.0)
    pairs = []
    for name in names:
        c, p = clean_images / name, poisoned_images / name
        if not (c.is_file() and p.is_file()):
            continue
        with PIL.Image.open(c) as im:
            w, h = im.size
        s = min(1.0, options.cost2_long_edge / max(w, h))
        size = (max(1, round(w * s)), max(1, round(h * s)))
        pairs.append((load_rgb(c, size, bg), load_rgb(p, size, bg)))
    if not pairs:
        return {"ssim": None, "psnr": None, "lpips": None, "images": 0}
    return {**_image_metrics(pairs, lpips_model), "images": len(pairs)}


def _save_previews(path: Path, clean: tuple[Any, Any], poisoned: tuple[Any, Any], count: int) -> list[str]:
    """One PNG: per row, clean render | poisoned render | poisoned input, for views in both models."""
    import numpy as np
    import PIL.Image

    from verifier.splat.render import to_uint8

    clean_scene, clean_renders = clean
    pois_scene, pois_renders = poisoned
    common = [n for n in pois_scene.names if n in set(clean_scene.names)]
    if not common or count <= 0:
        return []
    picks = [common[round(i * (len(common) - 1) / max(1, count - 1))] for i in range(min(count, len(common)))]
    rows = []
    for name in dict.fromkeys(picks):
        ci, pi = clean_scene.names.index(name), pois_scene.names.index(name)
        panels = [to_uint8(clean_renders[ci]), to_uint8(pois_renders[pi]), to_uint8(pois_scene.images[pi])]
        h = max(p.shape[0] for p in panels)
        panels = [np.pad(p, ((0, h - p.shape[0]), (0, 2), (0, 0)), constant_values=255) for p in panels]
        rows.append(np.concatenate(panels, axis=1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 2), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    PIL.Image.fromarray(np.concatenate(rows, axis=0)).save(path)
    return list(dict.fromkeys(picks))


def execute(job: SplatJob) -> dict[str, Any]:
    import PIL.Image  # noqa: F401  (before pycolmap)
    import torch

    from verifier.lpips import Lpips, lpips_available
    from verifier.splat.train import SplatOptions

    options = SplatOptions(**job.options)
    if options.threads:
        torch.set_num_threads(options.threads)
    out_dir = Path(job.out_dir)
    started = time.time()
    ok, reason = lpips_available(options.lpips_net)
    lpips_model = Lpips(options.lpips_net) if ok else None
    clean, clean_scene, clean_renders = _train_side(
        Path(job.clean_model_dir), Path(job.clean_images), options, lpips_model
    )
    poisoned, pois_scene, pois_renders = _train_side(
        Path(job.poisoned_model_dir), Path(job.poisoned_images), options, lpips_model
    )
    names = sorted(set(clean_scene.names) | set(pois_scene.names))
    all_names = sorted(p.name for p in Path(job.poisoned_images).iterdir() if p.is_file()) or names
    t_cost2 = time.time()
    cost2 = _cost2(Path(job.clean_images), Path(job.poisoned_images), all_names, options, lpips_model)
    cost2["seconds"] = round(time.time() - t_cost2, 2)
    preview = out_dir / PREVIEW_NAME
    views = _save_previews(
        preview, (clean_scene, clean_renders), (pois_scene, pois_renders), options.preview_views
    )
    return {
        "outcome": "ok",
        "clean": clean,
        "poisoned": poisoned,
        "cost1": poisoned["cost1"],
        "cost2": cost2,
        "lpips_net": options.lpips_net if ok else None,
        "lpips_unavailable": None if ok else reason,
        "preview": str(preview) if views else None,
        "preview_views": views,
        "preview_layout": "clean render | poisoned render | poisoned input",
        "seconds": round(time.time() - started, 2),
        "options": dataclasses.asdict(options),
    }


def _write_atomic(path: Path, data: dict[str, Any]) -> None:
    from poisoner.atomic import atomic_write_bytes

    atomic_write_bytes(path, json.dumps(data, indent=1).encode())


def main() -> int:
    from verifier.supervise import adopt_child_setup

    adopt_child_setup()
    with __import__("contextlib").suppress(OSError):
        os.nice(10)  # a verification child yields to the machine's other work
    job = msgspec.json.decode(sys.stdin.buffer.read(), type=SplatJob)
    out_dir = Path(job.out_dir)
    try:
        result = execute(job)
    except Exception as exc:  # any error is a result the parent records
        log.exception("splat stage failed")
        result = {"outcome": "failed", "error": f"{type(exc).__name__}: {exc}".splitlines()[0]}
    _write_atomic(out_dir / RESULT_NAME, result)
    return 0


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO)
    raise SystemExit(main())
