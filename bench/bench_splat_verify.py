"""A full splat verification of 40 lego views, timed: `python -m bench.bench_splat_verify`.

What `ppd verify PATH --clean DIR --profile default --splat --white-background` does, from
nothing cached: COLMAP on the clean and the poisoned set (PatchSpec() = P=48 px, b=4 px on
800 px lego; unknown focal, the attacker's default), then the splat stage (clean and poisoned
splats at 200 px, the paper's cost1 and cost2, a preview PNG). Also times cost2's LPIPS per
800 px pair over the changed region against the full pass. Writes bench/results/splat_verify.md.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads: verifier/splat/__init__.py

import numpy as np
from PIL import Image  # before pycolmap

from bench.bench_verify import WORK, poison_folder, prepare_lego
from poisoner.ladder import default_spec
from poisoner.spec import PatchSpec
from verifier.verification import VerifyOptions, verify_folders

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "splat_verify.md"
OUT = Path("/tmp/ppd-bench-splat-verify")
# --design: the paper's patch (PatchSpec(), the original run) or ppd's default (a moving texture);
# each writes its own results file and work folder
DESIGNS = {
    "paper": ("P=48 (PatchSpec())", RESULTS, OUT),
    "ppd-default": (
        "ppd default (texture-6pct-drift)",
        ROOT / "bench" / "results" / "splat_verify_ppd_default.md",
        Path("/tmp/ppd-bench-splat-verify-ppd-default"),
    ),
}
PAPER = {  # ../shared/PAPER.md, P=48 row and the clean reference (8 scenes, 30k iterations)
    "clean": (0.969, 32.96, 0.050),
    "P=48": (0.775, 16.91, 0.354),
    "cost2 P=48": (0.9958, 27.45, 0.0083),
}


def lpips_timing(clean: Path, poisoned: Path, pairs: int) -> dict[str, float]:
    """Seconds per 800 px pair: LPIPS-VGG over the changed region vs the full image."""
    from verifier.lpips import Lpips

    model = Lpips("vgg")
    names = sorted(p.name for p in clean.glob("*.png"))[:pairs]
    loc, full, worst = [], [], 0.0
    for n in names:
        a = np.asarray(Image.open(clean / n).convert("RGB"), dtype=np.float32) / 255
        b = np.asarray(Image.open(poisoned / n).convert("RGB"), dtype=np.float32) / 255
        t = time.perf_counter()
        d_local = model.distance(a, b)
        loc.append(time.perf_counter() - t)
        t = time.perf_counter()
        d_full = model.distance(a, b, local=False)
        full.append(time.perf_counter() - t)
        worst = max(worst, abs(d_local - d_full) / max(d_full, 1e-12))
    return {
        "pairs": len(names),
        "local_s": float(np.median(loc)),
        "full_s": float(np.median(full)),
        "max_rel_diff": worst,
    }


def _get(d: dict, *keys: str) -> object:
    value: Any = d  # JSON data: a dict at every key but the last
    for k in keys:
        value = (value or {}).get(k)
    return value


def _child_peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024


def _f(x: object, nd: int = 3) -> str:
    return "-" if x is None else (f"{x:.{nd}f}" if isinstance(x, float) else str(x))


def _cost1_rows(sp: dict, design_label: str) -> list[str]:
    """cost1 table rows: ours (clean and poisoned splats), then the paper's."""
    rows = []
    for label, side in (("ours, clean", sp.get("clean")), (f"ours, {design_label}", sp.get("poisoned"))):
        c1 = (side or {}).get("cost1") or {}
        rows.append(f"| {label} | {_f(c1.get('ssim'))} | {_f(c1.get('psnr'), 2)} | {_f(c1.get('lpips'))} |"
                    f" {_f((side or {}).get('iterations'))} | {_f((side or {}).get('train_seconds'), 1)} |")
    for label in ("clean", "P=48"):
        s, ps, lp = PAPER[label]
        rows.append(f"| paper, {label} (8 scenes, 30k it) | {s} | {ps} | {lp} | 30000 | - |")
    return rows


def _stage_lines(p: dict, seconds: float, argv: str, load_at_start: float, design_label: str) -> list[str]:
    """Title, command, the per-stage seconds table, peak memory and the SfM verdict."""
    sp = p.get("splat") or {}
    sfm_c, sfm_p = p["clean"].get("elapsed_s"), p["poisoned"].get("elapsed_s")
    vc = p.get("vs_clean") or {}
    return [
        f"# Full splat verification of 40 lego views: {design_label}",
        "",
        f"Command: `{argv}` (2-core machine; load average when it started: {load_at_start:.2f}; "
        "wall-clock figures include whatever else ran).",
        "",
        "| stage | seconds |",
        "|---|---|",
        f"| COLMAP clean (features, matching, mapping) | {_f(sfm_c, 1)} |",
        f"| COLMAP poisoned | {_f(sfm_p, 1)} |",
        f"| splat stage (both trainings, renders, cost1, cost2 on 40 pairs at 800 px, preview) | "
        f"{_f(sp.get('seconds'), 1)} |",
        f"| of which: training clean + poisoned | {_f(_get(sp, 'clean', 'train_seconds'), 1)} + "
        f"{_f(_get(sp, 'poisoned', 'train_seconds'), 1)} |",
        f"| of which: cost1 metrics clean + poisoned (SSIM/PSNR/LPIPS of renders, 200 px) | "
        f"{_f(_get(sp, 'clean', 'cost1_seconds'), 1)} + {_f(_get(sp, 'poisoned', 'cost1_seconds'), 1)} |",
        f"| of which: cost2 (40 pairs at 800 px) | {_f(_get(sp, 'cost2', 'seconds'), 1)} |",
        f"| **whole verification** | **{seconds:.1f}** |",
        "",
        f"Peak RSS of any child (SfM or splat): {_child_peak_mb():.0f} MB.",
        f"SfM verdict (default profile): **{p['verdict']}**, poisoned cameras within 5° of clean:"
        f" {_f(vc.get('frac_within_5deg'), 2)}.",
        "",
    ]


def write(
    report: dict, seconds: float, timing: dict, argv: str, load_at_start: float, design: str = "paper"
) -> None:
    design_label, results, _ = DESIGNS[design]
    p = report["profiles"]["default"]
    sp = p.get("splat") or {}
    rows = _cost1_rows(sp, design_label)
    c2 = sp.get("cost2") or {}
    lines = [
        *_stage_lines(p, seconds, argv, load_at_start, design_label),
        "## cost1: renders against their inputs at each side's own SfM poses (200 px)",
        "",
        "| | SSIM | PSNR | LPIPS | iterations | train s |",
        "|---|---|---|---|---|---|",
        *rows,
        "",
        "## cost2: poisoned vs clean images (800 px)",
        "",
        "| | SSIM | PSNR | LPIPS |",
        "|---|---|---|---|",
        f"| ours, {design_label} | {_f(c2.get('ssim'), 4)} | {_f(c2.get('psnr'), 2)} "
        f"| {_f(c2.get('lpips'), 4)} |",
        f"| paper, P=48 | {PAPER['cost2 P=48'][0]} | {PAPER['cost2 P=48'][1]} | {PAPER['cost2 P=48'][2]} |",
        "",
        f"LPIPS-VGG per 800 px pair (median of {timing['pairs']}): over the changed region "
        f"{timing['local_s']:.2f} s, full image {timing['full_s']:.2f} s; largest relative difference "
        f"{timing['max_rel_diff']:.1e} (the crop is exact: features that never see the patch add 0).",
        "",
        f"Preview: {sp.get('preview')} ({sp.get('preview_layout')}).",
        f"Reasons recorded: {'; '.join(p['reasons'])}",
        "",
    ]
    results.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--budget", type=float, default=150.0, help="splat training seconds per side")
    ap.add_argument("--lpips-pairs", type=int, default=5)
    ap.add_argument("--design", choices=sorted(DESIGNS), default="paper")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    _, results, out = DESIGNS[args.design]
    clean, gt, _ = prepare_lego(args.views)
    if args.design == "paper":
        poisoned, spec = WORK / "lego" / "poisoned-default-spec", PatchSpec()
    else:
        poisoned, spec = WORK / "lego" / "poisoned-ppd-default", default_spec()
    poison_folder(clean, poisoned, spec)
    shutil.rmtree(out, ignore_errors=True)
    options = VerifyOptions(ground_truth=gt, splat=True)
    options.splat_options.update(time_budget_s=args.budget, white_background=True)
    load_at_start = os.getloadavg()[0]
    started = time.time()
    report = verify_folders(clean, poisoned, out, ["default"], options).to_dict()
    seconds = time.time() - started
    (out / "report_full.json").write_text(json.dumps(report, indent=1, default=str))
    timing = lpips_timing(clean, poisoned, args.lpips_pairs)
    command = "python -m bench.bench_splat_verify " + " ".join(sys.argv[1:])
    write(report, seconds, timing, command, load_at_start, args.design)
    print(f"wrote {results}: whole verification {seconds:.0f} s")


if __name__ == "__main__":
    main()
