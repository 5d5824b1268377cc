"""Does a moving patch survive COLMAP's hardened profile on frames extracted from a video?

    nice -n 19 python -m bench.bench_video_motion [--every 4 8 12]

Renders verifier.synthetic's object scene (a textured box on a plain floor and wall, the scene
kind where the patch wins the vote: tests/verifier/test_auto.py) as an H.264 video from a camera moving
along a 90 deg arc, poisons it four ways (the paper's static checkerboard; ppd's default moving
texture gliding at 2 and at 6 photo-steps per second; the same texture held still), samples
every k-th frame as an attacker would, and runs Verifier I (default and hardened profiles, true
intrinsics) on clean vs poisoned frames. Writes bench/results/video_motion.md.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from PIL import Image  # noqa: F401  (PIL before pycolmap, which the verifier's children import)

from bench.bench_video import render_scene_video
from poisoner.ladder import default_spec, named_spec
from poisoner.spec import PatchSpec
from poisoner.video import VideoOptions, poison_video, sample_frames
from verifier.synthetic import SyntheticOptions, write_ground_truth
from verifier.verification import VerifyOptions, verify_folders

RESULTS = Path(__file__).resolve().parent / "results" / "video_motion.md"
FPS = 24
SCENE = SyntheticOptions(num_views=96, width=320, height=320, backdrop="plain", arc_deg=90.0)
ROAMING = named_spec("roaming")  # ppd's default before issue 14; video_motion.md calls it "ppd default"
CASES = {
    "paper checkerboard, static": (PatchSpec(), VideoOptions()),
    "roaming, gliding 2 steps/s": (ROAMING, VideoOptions(motion_steps_per_second=2)),
    "roaming, gliding 6 steps/s": (ROAMING, VideoOptions(motion_steps_per_second=6)),
    "roaming, held still": (ROAMING, VideoOptions(motion_steps_per_second=0)),
    "ppd default (watermark-lanes-2), 2 steps/s": (default_spec(), VideoOptions(motion_steps_per_second=2)),
    "ppd default (watermark-lanes-2), 6 steps/s": (default_spec(), VideoOptions(motion_steps_per_second=6)),
}


def _cell(profiles: list[object]) -> str:
    """Over repeated SfM runs: how many said protected, and each run's % within 5° of clean."""
    fracs = []
    for p in profiles:
        frac = (getattr(p, "vs_clean", None) or {}).get("frac_within_5deg")
        fracs.append("-" if frac is None else f"{100 * frac:.0f}%")
    n_protected = sum(getattr(p, "verdict", "") == "protected" for p in profiles)
    return f"protected {n_protected}/{len(profiles)} ({', '.join(fracs)})"


def _page(args: argparse.Namespace, started: float, rows: list[str]) -> list[str]:
    """The results page's lines: how it was made, then the table."""
    return [
        "# Moving patch in video vs COLMAP's stationary-match filter (bench/bench_video_motion.py)",
        "",
        f"`python -m bench.bench_video_motion --every {' '.join(map(str, args.every))} "
        f"--repeats {args.repeats}" + (f" --cases '{args.cases}'" if args.cases else "") + "`, "
        f"{time.strftime('%Y-%m-%d %H:%M')}, {time.time() - started:.0f} s. Video: verifier.synthetic's "
        f"object scene (plain backdrop), {SCENE.num_views} frames {SCENE.width}x{SCENE.height} at {FPS} fps "
        "(H.264 CRF 16), camera on a 90° arc. Verifier I on every k-th frame, clean vs poisoned, true "
        "intrinsics, each cell verified `--repeats` times with COLMAP random seeds 0, 1, ... (clean and "
        "poisoned SfM both re-run; within one invocation a seed repeated itself, between invocations "
        "it did not always). "
        "Cells: runs that said protected, then each run's share of cameras within 5° of the clean "
        "solution.",
        "",
        "| sampled every k frames | patch | patch contrast after encoding (min) | default | hardened |",
        "|---|---|---|---|---|",
        *rows,
        "",
    ]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_video_motion")
    ap.add_argument("--every", type=int, nargs="+", default=[2, 4, 12], help="sample every k-th frame")
    ap.add_argument("--repeats", type=int, default=3, help="COLMAP seeds (0, 1, ...) per cell")
    ap.add_argument("--cases", default="", help="comma-separated substrings of case labels ('' = all)")
    ap.add_argument("--out", type=Path, default=RESULTS, help="results file (rewritten)")
    args = ap.parse_args(argv)
    wanted = [w.strip() for w in args.cases.split(",") if w.strip()]
    cases = {k: v for k, v in CASES.items() if not wanted or any(w in k for w in wanted)}
    started = time.time()
    rows: list[str] = []
    with tempfile.TemporaryDirectory(prefix="ppd-bench-video-motion-") as tmp:
        work = Path(tmp)
        clean_video = work / "clean.mp4"
        poses = render_scene_video(clean_video, SCENE, fps=FPS, crf=16)
        poisoned = {}
        for label, (spec, options) in cases.items():
            dst = work / f"{len(poisoned)}.mp4"
            report = poison_video(clean_video, dst, spec, options=options)
            poisoned[label] = (dst, report)
        for k in args.every:
            clean_dir = work / f"clean-{k}"
            frames = sample_frames(clean_video, clean_dir, every_k=k)
            gt = work / f"gt-{k}.json"
            write_ground_truth(gt, {p.name: poses[int(p.stem.split("_")[1])] for p in frames}, SCENE)
            for case, (label, (dst, report)) in enumerate(poisoned.items()):
                pois_dir = work / f"pois-{k}-{case}"
                sample_frames(dst, pois_dir, every_k=k)
                runs = []
                for seed in range(args.repeats):  # an attacker who reruns COLMAP with other seeds
                    options = VerifyOptions(
                        ground_truth=gt, camera_params=SCENE.camera_params(), timeout_s=900, random_seed=seed
                    )
                    out = work / f"out-{k}-{len(rows)}-{seed}"
                    runs.append(verify_folders(clean_dir, pois_dir, out, ("default", "hardened"), options))
                line = (
                    f"| {k} ({FPS / k:g} fps, {len(frames)} frames) | {label} | "
                    f"{report.patch_contrast_min:.3f} | {_cell([r.profiles['default'] for r in runs])} | "
                    f"{_cell([r.profiles['hardened'] for r in runs])} |"
                )
                print(line, flush=True)
                rows.append(line)
    lines = _page(args, started, rows)
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
