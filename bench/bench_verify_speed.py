"""Verification at a creator's scale (issue 30): whole `ppd verify --profile all` against one default
COLMAP run of the same poisoned set, back to back, on one machine; wall time, as ratios.

`nice python -m bench.bench_verify_speed --tree PATH --label NAME [--second]` times, in this order:
1. one default COLMAP run of the poisoned set (the official 3DGS convert.py pipeline: SIFT, exhaustive
   matching, geometric verification, incremental mapping; `python -m verifier.child` of this checkout,
   fresh database), the baseline;
2. the whole command `ppd verify POISONED --clean CLEAN --profile all` of the code at --tree (this
   checkout, or a worktree of an older commit for "before"), with empty data and cache folders: a
   first verification, the clean reference included;
3. with --second: the same command again with the same cache folder (the clean reference cached: a
   second verification of the same originals, as after a re-poison).
Each run's load average is recorded next to its time; per-stage seconds (features + raw matches,
geometric verification, mapping) come from the command's report.json. Results are appended to
bench/results/verify_speed.json and the page bench/results/verify_speed.md is rewritten from it.

Sets (`--set`):
- `lego` (default): NeRF-Synthetic lego's first `--views` views on white, at 800 px (real renders);
- `lego-upscaled`: the same views padded to 3:2 and upscaled (Lanczos) to `--width` (6000 x 4000 for a
  creator's 24 MP): creator-sized files, but no fine detail beyond the 800 px source;
- `synthetic`: verifier.synthetic's textured scene rendered at `--width` (real multi-scale texture at
  full resolution, a box on a textured floor; not a real photo);
- `creator`: testkit/creator_set.py: a box with real photographs (fountain-P11 crops) as its textures
  on a plain backdrop, `--width` x 2/3 (6000 x 4000: 24 MP), camera-like JPEG, poisoned by ppd's own
  file path (real fine detail at full size; synthetic geometry).
`--profile NAME` times `ppd verify --profile NAME` instead of all (what fits at 24 MP).
The poisoned set is ppd's default mark (poison_array, default_spec) on each view, PNG.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
# PPD_BENCH_RESULTS: another folder for the two files (a lent GPU machine writes them where they come back)
RESULTS = Path(os.environ.get("PPD_BENCH_RESULTS") or ROOT / "bench" / "results")
RESULTS_JSON = RESULTS / "verify_speed.json"
RESULTS_MD = RESULTS / "verify_speed.md"
# PPD_BENCH_WORK: a folder of its own (engineers sharing a machine each set theirs)
WORK = Path(os.environ.get("PPD_BENCH_WORK") or Path(tempfile.gettempdir()) / "ppd-bench-verify-speed")


def load() -> float:
    return os.getloadavg()[0]


def make_sets(kind: str, views: int, width: int) -> tuple[Path, Path]:
    """(clean folder, poisoned folder) for the set, made once and reused."""
    import numpy as np
    from PIL import Image

    from poisoner.blend import poison_array
    from poisoner.ladder import default_spec

    root = WORK / f"{kind}-{views}-{width}"
    if kind == "creator":  # real photo textures at full size, JPEG (testkit/creator_set.py)
        from testkit.creator_set import make_creator_set

        clean, poisoned, _ = make_creator_set(root, views, width, width * 2 // 3)
        return clean, poisoned
    clean, poisoned = root / "clean", root / "poisoned"
    if (poisoned / ".done").exists():
        return clean, poisoned
    shutil.rmtree(root, ignore_errors=True)
    clean.mkdir(parents=True)
    poisoned.mkdir()
    if kind == "synthetic":
        from verifier.synthetic import SyntheticOptions, render_scene

        render_scene(clean, SyntheticOptions(num_views=views, width=width, height=width * 2 // 3,
                                             focal=1.2 * width))  # fmt: skip
    else:
        from verifier.shared_data import prepare_lego

        src, _, size = prepare_lego(views)
        for i in range(views):
            im = Image.open(src / f"r_{i}.png").convert("RGB")
            if kind == "lego-upscaled":
                canvas = Image.new("RGB", (size * 3 // 2, size), (255, 255, 255))
                canvas.paste(im, (size // 4, 0))  # 3:2 like a camera, lego in the middle
                im = canvas.resize((width, width * 2 // 3), Image.Resampling.LANCZOS)
            im.save(clean / f"r_{i}.png")
    spec = default_spec()
    for p in sorted(clean.glob("*.png")):
        arr, _ = poison_array(np.asarray(Image.open(p).convert("RGB")), spec, image_key=p.name)
        Image.fromarray(arr).save(poisoned / p.name)
    (poisoned / ".done").touch()  # a dot-file: no image reader lists it
    return clean, poisoned


def baseline_run(poisoned: Path, work: Path, timeout_s: float) -> dict[str, Any]:
    """One default COLMAP run of the poisoned set in a child (fresh database), timed whole."""
    from verifier.sfm import SfmJob, run_sfm_job

    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    before = load()
    t0 = time.monotonic()
    result = run_sfm_job(
        SfmJob(str(poisoned), str(work / "cache.db"), str(work / "model")), timeout_s=timeout_s
    )
    wall = time.monotonic() - t0
    return {"wall_s": wall, "load_before": before, "load_after": load(), "outcome": result.get("outcome"),
            "registered": result.get("registered"), "timings": result.get("timings", {})}  # fmt: skip


def verify_command(
    tree: Path, clean: Path, poisoned: Path, out: Path, env_root: Path, timeout_s: float, profile: str = "all"
) -> dict[str, Any]:
    """The whole `ppd verify --profile PROFILE` (all: every profile) of the code at tree, timed as
    one process."""
    env = dict(os.environ)
    for var, name in (("PPD_DATA_DIR", "data"), ("PPD_CONFIG_DIR", "config"), ("PPD_CACHE_DIR", "cache"),
                      ("PPD_OUTBOX", "outbox")):  # fmt: skip
        env[var] = str(env_root / name)
    # the tree first; what the caller's path holds (e.g. a carried pycolmap build) after it
    env["PYTHONPATH"] = os.pathsep.join([str(tree), *filter(None, [os.environ.get("PYTHONPATH")])])
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "daemon.cli", "verify", str(poisoned), "--clean", str(clean),
           "--out", str(out), "--profile", profile, "--json"]  # fmt: skip
    before = load()
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:  # at least this long: the page shows ">"
        return {"wall_s": time.monotonic() - t0, "load_before": before, "load_after": load(),
                "stopped": True, "error": f"stopped at its {timeout_s:.0f} s limit"}  # fmt: skip
    wall = time.monotonic() - t0
    row: dict[str, Any] = {
        "wall_s": wall,
        "load_before": before,
        "load_after": load(),
        "exit": proc.returncode,
    }
    try:
        report = json.loads(proc.stdout)
    except json.JSONDecodeError:
        row["error"] = (proc.stderr or proc.stdout)[-500:]
        return row
    row["verdict"] = report.get("verdict")
    row["profiles"] = profile_stages(report["profiles"])
    return row


def profile_stages(profiles: dict[str, Any]) -> dict[str, Any]:
    """Per profile: verdict, cameras within 5 degrees, seconds per stage and side (report.json)."""
    rows = {}
    for name, p in profiles.items():
        stages: dict[str, float] = {}
        for side in ("clean", "poisoned"):
            for k, v in (p[side].get("timings") or {}).items():
                stages[f"{side}_{k}"] = round(float(v), 1)
            stages[f"{side}_elapsed_s"] = round(float(p[side].get("elapsed_s") or 0.0), 1)
        frac = (p.get("vs_clean") or {}).get("frac_within_5deg")
        rows[name] = {"verdict": p["verdict"], "frac_within_5deg": frac, "stages": stages}
    return rows


PER_STAGE = "## Per profile and stage (seconds, from each run's report.json)"
REPO_MD = ROOT / "bench" / "results" / "verify_speed.md"


def kept_notes(page: Path) -> list[str]:
    """The hand-written rounds of a page as it stands: from its first `## ` heading to the per-stage
    tables. Each round's findings are written once, by hand, under the table; every rewrite keeps them
    (where RESULTS points elsewhere and holds no page yet, a lent machine's $OUT, the repository's)."""
    if not page.exists():
        page = REPO_MD
    if not page.exists():
        return []
    lines = page.read_text(encoding="utf-8").splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith("## ")), len(lines))
    end = next((i for i, line in enumerate(lines) if line == PER_STAGE), len(lines))
    notes = lines[start:max(start, end)]
    while notes and not notes[-1].strip():
        notes.pop()
    return notes


def write_page(rows: list[dict[str, Any]]) -> None:
    lines = [
        "# Verification speed: whole `ppd verify --profile all` vs one default COLMAP run",
        "",
        "Written by `bench/bench_verify_speed.py` (its docstring says what each lane runs). Wall seconds,",
        "one run each, niced, back to back on the machine named; ratio = the verification / the default",
        "COLMAP run of the same poisoned set timed just before it. Load = 1-minute load average before /",
        "after each run (baseline, first, second).",
        "",
        "| when | code | set | default COLMAP run | first verification | ratio | second (clean cached) |"
        " ratio | verdict | load |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        b, f, s = r["baseline"], r["first"], r.get("second") or {}
        loads = ", ".join(f"{x['load_before']:.1f}/{x['load_after']:.1f}" for x in (b, f, s) if x)
        second = f"{s['wall_s']:.0f} s | {s['wall_s'] / b['wall_s']:.2f}x" if s else "- | -"
        more = ">" if f.get("stopped") else ""  # stopped before the end: at least this long
        verdict = f.get("verdict", f.get("error", "-"))
        if s and s.get("verdict") != f.get("verdict"):
            verdict += f"; second: {s.get('verdict', s.get('error', '-'))}"
        lines.append(
            f"| {r['date']} | {r['label']} | {r['set']} | {b['wall_s']:.0f} s | {more}{f['wall_s']:.0f} s | "
            f"{more}{f['wall_s'] / b['wall_s']:.2f}x | {second} | {verdict} | "
            f"{loads} |"
        )
    notes = kept_notes(RESULTS_MD)
    lines += ["", *notes, ""] if notes else [""]
    lines += [PER_STAGE, ""]
    for r in rows:
        for lane in ("first", "second"):
            run = r.get(lane)
            if not run or not run.get("profiles"):
                continue
            lines.append(
                f"### {r['date']} {r['label']} {r['set']}: {lane} verification ({run['wall_s']:.0f} s)"
            )
            lines.append("")
            lines.append("| profile | verdict | within 5° | stages |")
            lines.append("|---|---|---|---|")
            for name, p in run["profiles"].items():
                frac = p["frac_within_5deg"]
                shown = "-" if frac is None else f"{100 * frac:.0f}%"
                stages = ", ".join(f"{k} {v}" for k, v in p["stages"].items())
                lines.append(f"| {name} | {p['verdict']} | {shown} | {stages} |")
            lines.append("")
    RESULTS_MD.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout whose `ppd verify` is timed")
    ap.add_argument("--label", default="after")
    ap.add_argument("--set", default="lego", choices=("lego", "lego-upscaled", "synthetic", "creator"))
    ap.add_argument("--profile", default="all", help="the profile `ppd verify` runs (all: every profile)")
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--width", type=int, default=800, help="lego-upscaled / synthetic: image width")
    ap.add_argument(
        "--second", action="store_true", help="also a second verification, clean reference cached"
    )
    ap.add_argument("--timeout", type=float, default=3600.0)
    ap.add_argument("--sift-device", default="", help="a note for the page: where SIFT ran (cpu, cuda)")
    args = ap.parse_args(argv if argv is not None else [])  # `python -m bench` runs it with defaults
    clean, poisoned = make_sets(args.set, args.views, args.width)
    env_root = Path(tempfile.mkdtemp(prefix="ppd-bench-env-"))
    row: dict[str, Any] = {"date": time.strftime("%Y-%m-%d %H:%M"), "label": args.label,
                           "set": f"{args.set} {args.views} views, width {args.width}"
                                  + ("" if args.profile == "all" else f", --profile {args.profile}"),
                           "machine": f"{platform.node()} {os.cpu_count()} cores"}  # fmt: skip
    if args.sift_device:
        row["sift_device"] = args.sift_device
    rows = json.loads(RESULTS_JSON.read_text()) if RESULTS_JSON.exists() else []
    row["baseline"] = baseline_run(poisoned, WORK / "baseline", args.timeout)
    print("baseline", row["baseline"], flush=True)
    save(rows, row)  # each lane as it ends: a run stopped from outside keeps what it measured
    row["first"] = verify_command(args.tree, clean, poisoned, WORK / "out1", env_root, args.timeout,
                                  args.profile)  # fmt: skip
    print("first", row["first"]["wall_s"], row["first"].get("verdict"), flush=True)
    save(rows, row)
    if args.second:
        row["second"] = verify_command(args.tree, clean, poisoned, WORK / "out2", env_root, args.timeout,
                                       args.profile)  # fmt: skip
        print("second", row["second"]["wall_s"], row["second"].get("verdict"), flush=True)
        save(rows, row)
    shutil.rmtree(env_root, ignore_errors=True)


def save(rows: list[dict[str, Any]], row: dict[str, Any]) -> None:
    """rows plus this run's row so far, to the JSON file and the page."""
    done = [*rows, row]
    RESULTS.mkdir(parents=True, exist_ok=True)
    RESULTS_JSON.write_text(json.dumps(done, indent=1) + "\n")
    write_page([r for r in done if "first" in r])


if __name__ == "__main__":
    main(sys.argv[1:])
