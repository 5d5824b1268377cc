"""Verifier benchmark: real COLMAP (pycolmap 4.2.1) on lego (40 views) and fountain-P11.

`nice python -m bench.bench_verify [--quick]` writes bench/results/verify.md. For each dataset and
patch: clean vs poisoned under the default, hardened and published profiles, pose errors against
the clean solution and against ground truth, verdicts, and the time of each SfM run. Results are
rewritten after every case, so an interrupted run still leaves its numbers.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image  # PIL before anything that may load pycolmap

from poisoner.blend import poison_array
from poisoner.spec import PatchSpec
from verifier.poses import nerf_intrinsics
from verifier.shared_data import WORK, SharedDataMissing, prepare_fountain, prepare_lego, shared_root
from verifier.verification import VerificationReport, VerifyOptions, verify_folders

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "verify.md"


@dataclass(frozen=True)
class Case:
    dataset: str
    patch: str
    spec: PatchSpec
    profiles: tuple[str, ...]
    intrinsics: str  # "unknown (attacker default)" or "known"


def poison_folder(clean: Path, dst: Path, spec: PatchSpec) -> str:
    """Poison every image with poison_array; JPEGs are written as JPEG q=95 (a creator's export)."""
    dst.mkdir(parents=True, exist_ok=True)
    placement = None
    for p in sorted(clean.iterdir()):
        if p.suffix.lower() not in (".png", ".jpg", ".jpeg"):
            continue
        # the file name keys a moving spec's position (as poison_file does)
        arr, placement = poison_array(np.asarray(Image.open(p).convert("RGB")), spec, image_key=p.name)
        out = dst / p.name
        if p.suffix.lower() == ".png":
            Image.fromarray(arr).save(out)
        else:
            Image.fromarray(arr).save(out, quality=95)
    assert placement is not None
    pl = placement
    return f"P={pl.size}px b={pl.block}px alpha={pl.alpha8}/255 at ({pl.x},{pl.y})"


def fmt(x: object, pct: bool = False) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{100 * x:.0f}%" if pct else f"{x:.2f}"
    return str(x)


def rows_for(case: Case, placement: str, report: VerificationReport) -> list[str]:
    rows = []
    for prof in report.profiles.values():
        c, p = prof.clean, prof.poisoned
        vc = prof.vs_clean or {}
        cg, pg = prof.clean_vs_gt or {}, prof.poisoned_vs_gt or {}
        t_total = (c.get("elapsed_s") or 0) + (p.get("elapsed_s") or 0)
        rows.append(
            "| "
            + " | ".join(
                [
                    case.dataset,
                    f"{case.patch} ({placement})",
                    case.intrinsics,
                    prof.profile,
                    f"{c.get('registered', 0)}/{c.get('num_images', '-')} ({c.get('num_models', '-')})",
                    f"{p.get('registered', 0)}/{p.get('num_images', '-')} ({p.get('num_models', '-')})"
                    if p.get("outcome") == "ok"
                    else p.get("outcome", "-") + (f" {p.get('signal')}" if p.get("signal") else ""),
                    f"{fmt(c.get('mean_reprojection_error'))} / {fmt(p.get('mean_reprojection_error'))}",
                    f"{fmt(vc.get('frac_within_5deg'), True)} / {fmt(vc.get('frac_within_10deg'), True)} / "
                    f"{fmt(vc.get('frac_within_20deg'), True)}",
                    f"{fmt(vc.get('median_rotation_error_deg'))}",
                    f"{fmt(vc.get('auc_5'))} / {fmt(vc.get('auc_10'))} / {fmt(vc.get('auc_20'))}",
                    f"{fmt(cg.get('frac_within_5deg'), True)} / {fmt(pg.get('frac_within_5deg'), True)}",
                    f"{fmt(cg.get('auc_5'))} / {fmt(pg.get('auc_5'))}",
                    f"**{prof.verdict}**",
                    f"{fmt(c.get('elapsed_s'))} + {fmt(p.get('elapsed_s'))} = {t_total:.0f}",
                ]
            )
            + " |"
        )
    return rows


HEADER = [
    "| dataset | patch | intrinsics | profile | clean reg (models) | poisoned reg (models) "
    "| reproj px clean / pois | pois within 5/10/20° of clean | median rot err ° "
    "| pair AUC@5/10/20 vs clean | within 5° of GT clean / pois | AUC@5 vs GT clean / pois | verdict "
    "| SfM time s clean + pois |",
    "|" + "---|" * 14,
]


FRESH = False  # --fresh-clean
APPEND: dict[str, str] = {}  # --append: the existing file and this run's label


def write_results(rows: list[str], notes: list[str], started: float, done: bool) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    if APPEND:
        lines = [
            APPEND["base"].rstrip("\n"),
            "",
            f"## {APPEND['label']} ({time.strftime('%Y-%m-%d %H:%M')}, {time.time() - started:.0f} s"
            + (")" if done else ", INCOMPLETE)"),
            "",
            *HEADER,
            *rows,
            "",
            *notes,
        ]
        RESULTS.write_text("\n".join(lines) + "\n")
        return
    lines = [
        "# Verifier benchmark (real COLMAP, pycolmap 4.2.1)",
        "",
        f"Written by `nice python -m bench.bench_verify` on {platform.node()} "
        f"({platform.processor() or platform.machine()}, shared 2-core machine), "
        f"{time.strftime('%Y-%m-%d %H:%M')}, {time.time() - started:.0f} s so far"
        + ("." if done else " (INCOMPLETE: still running or interrupted)."),
        "",
        "Pose errors: rotation error after a robust similarity alignment of camera centres (RANSAC +",
        "Umeyama); unregistered cameras count as failures. 'within X° of clean' = fraction of the clean",
        "run's registered cameras; pair AUC = AUC of max(relative rotation, relative translation angle)",
        "over all image pairs. SfM time includes feature extraction when the profile computed features",
        "(hardened reuses default's features and raw matches; the clean side is reused across patches).",
        "",
        *HEADER,
        *rows,
        "",
        *notes,
    ]
    RESULTS.write_text("\n".join(lines) + "\n")


def run_case(
    case: Case, clean: Path, gt: Path, camera_params: str | None, rows: list[str], notes: list[str]
) -> VerificationReport:
    pois = WORK / case.dataset / f"poisoned-{case.spec.spec_id}"
    shutil.rmtree(pois, ignore_errors=True)
    placement = poison_folder(clean, pois, case.spec)
    tag = "known" if camera_params else "unknown"
    out = (
        WORK
        / case.dataset
        / f"run-{case.spec.spec_id}-{tag}{'-' + APPEND['label'][:12].replace(' ', '_') if APPEND else ''}"
    )
    shutil.rmtree(out, ignore_errors=True)
    opts = VerifyOptions(
        ground_truth=gt,
        camera_params=camera_params,
        clean_cache_dir=None if FRESH else WORK / case.dataset / f"clean-cache-{tag}",
        keep_cache=False,
        timeout_s=1200,
    )
    t = time.time()
    report = verify_folders(clean, pois, out, case.profiles, opts)
    print(f"{case.dataset} {case.patch} {tag}: {report.verdict} in {time.time() - t:.0f} s", flush=True)
    rows.extend(rows_for(case, placement, report))
    (out / "bench_report.json").write_text(json.dumps(report.to_dict(), indent=1))
    return report


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_verify")
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--only", choices=["lego", "fountain"], default=None)
    ap.add_argument("--skip-known", action="store_true", help="skip the known-intrinsics lego variant")
    ap.add_argument("--profiles", default="default,hardened,published", help="comma-separated profiles")
    ap.add_argument("--fresh-clean", action="store_true", help="recompute the clean side (timing runs)")
    ap.add_argument("--append", default=None, metavar="LABEL", help="append a section to verify.md")
    args = ap.parse_args(argv if argv is not None else [])
    try:
        shared_root()  # $PPD_SHARED_DATA, set by bench/__init__.py to the checkout's ../shared/datasets
    except SharedDataMissing as exc:
        raise SystemExit(str(exc)) from None
    started = time.time()
    rows: list[str] = []
    notes: list[str] = []
    all_profiles = tuple(args.profiles.split(","))
    global FRESH
    FRESH = args.fresh_clean
    if args.append:
        APPEND.update(base=RESULTS.read_text() if RESULTS.exists() else "", label=args.append)
    p48 = PatchSpec(patch_size=48, block_size=4, alpha=1.0)
    default_spec = PatchSpec()
    if args.only in (None, "lego"):
        clean, gt, width = prepare_lego(args.views)
        f = nerf_intrinsics(gt, width)
        same = p48.resolve(800, 800) == default_spec.resolve(800, 800)
        if same:
            notes.append(
                "- lego: the default PatchSpec() resolves to exactly P=48 px, b=4 px, alpha=1 at (0,0) on "
                "800x800 (6% of width, block 0.5% -> 4 px), so the two lego patches are one case."
            )
        cases = [
            Case("lego", "P48 b4 a1 = PatchSpec()" if same else "P48 b4 a1", p48, all_profiles, "unknown")
        ]
        if not same:
            cases.append(Case("lego", "PatchSpec()", default_spec, all_profiles, "unknown"))
        for case in cases:
            run_case(case, clean, gt, None, rows, notes)
            write_results(rows, notes, started, False)
        if not args.skip_known:
            params = f"{f},{f},400,400,0,0,0,0"
            notes.append(f"- known intrinsics: OPENCV fx=fy={f:.1f}, cx=cy=400, no distortion, fixed in BA.")
            run_case(
                Case("lego", cases[0].patch, p48, ("default", "hardened"), "known"),
                clean,
                gt,
                params,
                rows,
                notes,
            )
            write_results(rows, notes, started, False)
    if args.only in (None, "fountain"):
        clean, gt = prepare_fountain()
        for case in (
            Case("fountain-P11", "PatchSpec() (6% width)", default_spec, all_profiles, "unknown"),
            Case("fountain-P11", "P48 b4 a1", p48, all_profiles, "unknown"),
        ):
            run_case(case, clean, gt, None, rows, notes)
            write_results(rows, notes, started, False)
    write_results(rows, notes, started, True)
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main(sys.argv[1:])
