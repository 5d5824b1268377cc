"""CPU Gaussian splat benchmark: `nice python -m bench.bench_splat [--budget S] [--compare-budget S]`.

1. lego (NeRF-Synthetic), ground-truth poses, 200 px, 40 views on white, random initial points:
   iterations, wall time and training-view PSNR/SSIM within a time budget.
2. Training iterations per second at 200 px with 10k and 50k Gaussians on 2 threads, and peak
   memory (each in its own child process, so ru_maxrss is that measurement's peak).
3. If engineer D's lego SfM models (clean / poisoned P=48 b=4) exist, the paper's two costs.
Writes bench/results/splat.md.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads libgomp: verifier/splat/__init__.py

import numpy as np
import PIL.Image  # before pycolmap
import torch

from verifier.metrics import psnr, ssim
from verifier.splat.camera import scene_extent
from verifier.splat.gaussians import from_points
from verifier.splat.scenes import load_blender_scene
from verifier.splat.train import SplatOptions, render_views, train_splat

ROOT = Path(__file__).resolve().parents[1]
LEGO = ROOT.parent / "shared" / "datasets" / "nerf_synthetic_lego"
RESULTS = ROOT / "bench" / "results" / "splat.md"
D_RUNS = Path("/tmp/ppd-bench-verify/lego")
WORK = Path("/tmp/ppd-bench-splat")


def lego_fit(budget_s: float, iterations: int, init_points: int, threads: int) -> dict:
    torch.set_num_threads(threads)
    scene = load_blender_scene(LEGO, 200, 40, init_points)
    opts = SplatOptions(
        iterations=iterations,
        time_budget_s=budget_s,
        white_background=True,
        threads=threads,
        densify_from=100,
        sh_degree_up_at=iterations // 3,
    )
    res = train_splat(
        from_points(scene.points, scene.colours),
        scene.cameras,
        scene.images,
        opts,
        scene_extent(scene.cameras),
    )
    renders = render_views(res.gaussians, scene.cameras, opts)
    pairs = [
        (r.clamp(0, 1).permute(1, 2, 0).numpy(), i.permute(1, 2, 0).numpy())
        for r, i in zip(renders, scene.images, strict=True)
    ]
    return {
        "iterations": res.iterations,
        "seconds": round(res.seconds, 1),
        "gaussians": res.gaussians.count,
        "psnr": float(np.mean([psnr(a, b) for a, b in pairs])),
        "ssim": float(np.mean([ssim(a, b) for a, b in pairs])),
        "threads": threads,
        "init_points": init_points,
        "peak_rss_mb": _peak_mb(),
    }


def speed(n: int, iters: int, threads: int) -> dict:
    """Iterations/s with n Gaussians (no densification), fitted for a few steps first so sizes are sane."""
    torch.set_num_threads(threads)
    scene = load_blender_scene(LEGO, 200, 40, n)
    g = from_points(scene.points, scene.colours)
    with torch.no_grad():  # keep the count fixed at n, sized like a fitted scene (about 1-2 px)
        g.log_scales.clamp_(max=float(np.log(0.02)))
    opts = SplatOptions(iterations=iters, white_background=True, densify_from=10**9, threads=threads)
    res = train_splat(g, scene.cameras, scene.images, opts, scene_extent(scene.cameras))
    return {
        "gaussians": n,
        "iterations": res.iterations,
        "it_per_s": res.iterations_per_second,
        "threads": threads,
        "peak_rss_mb": _peak_mb(),
    }


def _peak_mb() -> float:
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)


def _child(args: list[str]) -> dict:
    out = subprocess.run(
        [sys.executable, "-m", "bench.bench_splat", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=False,
    )
    if out.returncode != 0:
        return {"error": (out.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def find_d_models() -> tuple[Path, Path] | None:
    """The first profile (default, published, then hardened) where both sides have a model, over
    D's unknown-focal runs (including labelled reruns: run-<hash>-unknown-<label>)."""
    for profile in ("default", "published", "hardened"):
        for run in sorted(D_RUNS.glob("run-*-unknown*")):
            clean, pois = run / profile / "clean", run / profile / "poisoned"
            if (clean / "cameras.bin").is_file() and (pois / "cameras.bin").is_file():
                return clean, pois
    return None


def poisoned_lego(clean_dir: Path) -> Path:
    """The P=48, b=4 poisoned copies of D's clean lego PNGs (deterministic, so equal to D's)."""
    from poisoner.blend import poison_array
    from poisoner.spec import PatchSpec

    dst = WORK / "lego_poisoned_P48"
    dst.mkdir(parents=True, exist_ok=True)
    for src in sorted(clean_dir.glob("*.png")):
        if not (dst / src.name).exists():
            arr = np.asarray(PIL.Image.open(src).convert("RGB"))
            PIL.Image.fromarray(poison_array(arr, PatchSpec(patch_size=48, block_size=4))[0]).save(
                dst / src.name
            )
    return dst


def compare(budget_s: float, iterations: int, threads: int) -> dict:
    from verifier.splat.stage import run_splat_stage

    models = find_d_models()
    if models is None:
        return {"pending": True}
    clean_imgs = D_RUNS / "clean"
    opts = SplatOptions(
        iterations=iterations,
        time_budget_s=budget_s,
        white_background=True,
        threads=threads,
        densify_from=100,
        sh_degree_up_at=iterations // 3,
    )
    result = run_splat_stage(
        models[0], clean_imgs, models[1], poisoned_lego(clean_imgs), WORK / "compare", opts
    )
    result["models"] = [str(m) for m in models]
    return result


def _fmt(x: object, nd: int = 3) -> str:
    return "n/a" if x is None else (f"{x:.{nd}f}" if isinstance(x, float) else str(x))


def write_report(fit: dict, speeds: list[dict], cmp: dict, argv: str) -> None:
    lines = [
        "# CPU Gaussian splat benchmark",
        "",
        f"Command: `{argv}` (machine: 2 cores shared with other work; figures are wall-clock).",
        "",
        "## lego, ground-truth poses, 200 px, 40 views on white",
        "",
        "| init points | threads | iterations | seconds | Gaussians at end | train-view PSNR | SSIM | peak RSS MB |",  # noqa: E501
        "|---|---|---|---|---|---|---|---|",
        f"| {fit.get('init_points')} | {fit.get('threads')} | {fit.get('iterations')} | {fit.get('seconds')} | "  # noqa: E501
        f"{fit.get('gaussians')} | {_fmt(fit.get('psnr'), 2)} | {_fmt(fit.get('ssim'))} | {fit.get('peak_rss_mb')} |",  # noqa: E501
        "",
        "## Training speed at 200 px (fixed Gaussian count, no densification)",
        "",
        "| Gaussians | threads | iterations | it/s | peak RSS MB |",
        "|---|---|---|---|---|",
    ]
    for s in speeds:
        if "error" in s:
            lines.append(f"| ? | ? | ? | error: {s['error']} | |")
        else:
            lines.append(
                f"| {s['gaussians']} | {s['threads']} | {s['iterations']} | {s['it_per_s']:.2f} | "
                f"{s['peak_rss_mb']} |"
            )
    lines += [
        "",
        "## Paper comparison: lego 40 views, clean vs poisoned P=48 b=4 (SfM poses from engineer D)",
        "",
    ]
    if cmp.get("pending"):
        lines.append(
            "Pending: no SfM models under /tmp/ppd-bench-verify/lego yet. Run `nice python -m bench.bench_verify "  # noqa: E501
            "--only lego` then `nice python -m bench.bench_splat`."
        )
    elif cmp.get("outcome") != "ok":
        lines.append(f"Stage {cmp.get('outcome')}: {cmp.get('error')}")
    else:
        c1c, c1p, c2 = cmp["clean"]["cost1"], cmp["poisoned"]["cost1"], cmp["cost2"]
        lines += [
            f"Models: {', '.join(cmp['models'])}. LPIPS: {cmp['lpips_net'] or 'n/a: ' + str(cmp['lpips_unavailable'])}.",  # noqa: E501
            f"Training: clean {cmp['clean']['iterations']} it / {cmp['clean']['train_seconds']} s on "
            f"{cmp['clean']['views']} registered views ({cmp['clean']['gaussians']} Gaussians); poisoned "
            f"{cmp['poisoned']['iterations']} it / {cmp['poisoned']['train_seconds']} s on "
            f"{cmp['poisoned']['views']} views ({cmp['poisoned']['gaussians']} Gaussians). Whole stage "
            f"(both trainings, renders, SSIM/PSNR/LPIPS, cost2 at 800 px, preview): {cmp['seconds']} s.",
            "",
            "| | render SSIM | render PSNR | render LPIPS | clean-vs-poisoned SSIM | PSNR | LPIPS |",
            "|---|---|---|---|---|---|---|",
            f"| ours, clean | {_fmt(c1c['ssim'])} | {_fmt(c1c['psnr'], 2)} | {_fmt(c1c['lpips'])} | 1 | inf | 0 |",  # noqa: E501
            f"| ours, P=48 | {_fmt(c1p['ssim'])} | {_fmt(c1p['psnr'], 2)} | {_fmt(c1p['lpips'])} | {_fmt(c2['ssim'], 4)} | "  # noqa: E501
            f"{_fmt(c2['psnr'], 2)} | {_fmt(c2['lpips'], 4)} |",
            "| paper, clean (8 scenes, 30k it) | 0.969 | 32.96 | 0.050 | 1.000 | inf | 0.000 |",
            "| paper, P=48 | 0.775 | 16.91 | 0.354 | 0.9958 | 27.45 | 0.0083 |",
            "",
            f"Preview (clean render | poisoned render | poisoned input): {cmp.get('preview')}",
        ]
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--budget", type=float, default=900.0, help="lego fit time budget, s")
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--init-points", type=int, default=5000)
    ap.add_argument("--speed-iters", type=int, default=5)
    ap.add_argument("--compare-budget", type=float, default=600.0, help="per side, s")
    ap.add_argument("--compare-iterations", type=int, default=1500, help="per side (SplatOptions default)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--part", choices=["fit", "speed"], default=None, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=10_000, help=argparse.SUPPRESS)
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.part == "fit":
        print(json.dumps(lego_fit(args.budget, args.iterations, args.init_points, args.threads)))
        return
    if args.part == "speed":
        print(json.dumps(speed(args.n, args.speed_iters, args.threads)))
        return
    t0 = time.time()
    speeds = [
        _child(
            [
                "--part",
                "speed",
                "--n",
                str(n),
                "--speed-iters",
                str(args.speed_iters),
                "--threads",
                str(args.threads),
            ]
        )
        for n in (10_000, 50_000)
    ]
    print("speed", speeds, flush=True)
    fit = _child(
        [
            "--part",
            "fit",
            "--budget",
            str(args.budget),
            "--iterations",
            str(args.iterations),
            "--init-points",
            str(args.init_points),
            "--threads",
            str(args.threads),
        ]
    )
    print("fit", fit, flush=True)
    cmp = compare(args.compare_budget, args.compare_iterations, args.threads)
    print("compare", {k: v for k, v in cmp.items() if k != "options"}, flush=True)
    write_report(fit, speeds, cmp, "nice python -m bench.bench_splat " + " ".join(sys.argv[1:]))
    print(f"wrote {RESULTS} in {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
