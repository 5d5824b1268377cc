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


ROUND9_NOTES = [
    "## Round 9: hardened and masked take the default's pairs, failed ones included (2026-11-28)",
    "",
    "No device was lent this session: this 2-core CPU, lego 40, two lanes back to back, each its own",
    "baseline: 1bd9bc7 (after) and a `git archive` of 7515e0f (before: the verifier of 33e9201).",
    "- **What was found.** COLMAP's verifier skips a pair whose two-view row has inliers but verifies",
    "  again a pair whose row is empty (its verification failed), and failed pairs are a clean side's",
    "  costliest: clean lego 40 has 284 of its 474 matched pairs failed, mostly outliers, so RANSAC runs",
    "  every trial. hardened's verification made from the default's (round 4) kept those rows, so it",
    "  verified all 284 again where 32 pairs differ: 57-73 s of clean verification in rounds 4-6.",
    "- **What changed.** hardened and masked set the default's failed rows aside while COLMAP verifies",
    "  the rest, and put them back (`verifier.reuse.failed_pairs_set_aside`). masked also takes, for",
    "  every pair of images its corner masks took no keypoint from (29 of lego 40's views: 406 of 780",
    "  pairs), the default's raw-match row (015f279: empty rows too, 306 of clean lego's 780, which",
    "  COLMAP writes for pairs with too few matches and its readers leave out) and its two-view row.",
    "  Equal pair by pair, every row, to a whole masked or hardened matching and verification",
    "  (tests/verifier/test_verify_masked_reuse.py and test_verify_stationary.py: generated sets at",
    "  two seeds, lego 16 clean and poisoned under `integration`).",
    "- **Measured, first verification** (sides' own seconds from report.json):",
    "",
    "  | stage | before (7515e0f) | after (1bd9bc7) |",
    "  |---|---|---|",
    "  | hardened, clean verification | 66.9 s | **3.0 s** |",
    "  | masked, clean features + matches / verification | 36.1 / 71.8 s | 25.9 / **38.5 s** |",
    "  | masked, poisoned features + matches / verification | 25.8 / 7.4 s | 15.7 / 3.0 s |",
    "  | every side's seconds added up | 887 s | 713 s |",
    "  | wall (ratio to the baseline) | 482 s (6.29x; baseline 77 s) | **388 s (5.76x**; baseline 67 s) |",
    "  | second verification, clean cached | 257 s (3.35x) | 232 s (3.45x) |",
    "",
    "  A third lane, 015f279 (masked takes empty raw-match rows too), ran after both: baseline 57 s, first",
    "  388 s (6.80x), second 164 s (2.87x); masked's features + matches 17.2 s clean (25.9 s at",
    "  1bd9bc7, 36.1 s before) and 9.7 s poisoned (15.7, 25.8). The baseline alone moved 57-77 s between",
    "  these lanes, so each ratio here is one draw; the stages' seconds are the evidence.",
    "",
    "  Every profile said protected, 0% within 5 deg, in both lanes. A lane of 2fd7836 (masked taking",
    "  only rows with inliers) ran first, not kept in the table: baseline 121 s, first 597 s, second",
    "  335 s, masked's clean verification 78.7 s, no gain: which is how the empty rows were found.",
    "  A second verification is not",
    "  helped (its clean sides are cached; the poisoned sides' pairs hardly ever fail).",
    "- **Goals (first <= 3x, second <= 2x): still missed on 2 cores.** What is left of a first",
    "  verification is mostly the attacker's own work on other inputs: the default's clean",
    "  verification (79 s: the 284 failed pairs, which the default cannot take from anyone) and",
    "  published's own features, matches and verification of both sides (288 s of sides' time).",
    "",
]


ROUND8_NOTES = [
    "## Round 8: lego 40 on a lent H200's 16 cores, CPU SIFT as ppd picks it for 800 px (2026-11-27)",
    "",
    "What round 7 left unrun: `bash bench/gpu_device.sh verdicts` on one NVIDIA H200 (16 cores,",
    "pycolmap-cuda12 4.2.1), code 7515e0f. `ppd verify` kept the CPU's SIFT for lego's 800 px renders",
    "(`gpu_sift_suits`); the baseline, one default COLMAP run (`run_sfm_job`), took the GPU's SIFT that",
    "an attacker's COLMAP takes there (its extraction and matching 1.3 s against 14.5 s on the CPU), so",
    "the ratio is against the faster of the two baselines.",
    "- **Measured:** baseline 37 s; first verification 69 s (**1.85x**), second, clean reference",
    "  cached, 61 s (**1.64x**). Both goals (first <= 3x, second <= 2x) are **met for lego 40 on this",
    "  16-core machine**. On this 2-core CPU they stay missed (5.1-8.3x first, 2.4-5.1x second, rounds 4-6).",
    "- Every profile said protected, 0% of the cameras within 5 deg, in both verifications (default,",
    "  hardened, published, global, masked; COLMAP seed 0). Round 5's *inconclusive* `published` and",
    "  `masked` (GPU SIFT on 800 px renders) are gone with the CPU SIFT there.",
    "- The GPU-vs-CPU test (`tests/verifier/test_sfm_gpu.py`, all markers): 6 passed in 25 s, the first",
    "  run of its redesigned decisive set on a GPU.",
    "- The creator set (12 x 24 MP) was not run again: rounds 5 and 7 give 3.31-3.85x first (missed),",
    "  1.52-2.07x second. 40 x 24 MP: see bench/results/protection_24mp.md round 6 (global only).",
    "",
]


ROUND7_NOTES = [
    "## Round 7: a thread cap per side, tried and taken back; small photos' SIFT on the CPU (2026-11-27)",
    "",
    "A lent H200 (16 cores, pycolmap-cuda12 4.2.1), creator 12 x 24 MP, two lanes back to back in one",
    "call, each its own baseline: c4dbdc6 (each side's geometric verification and mapping started",
    "`2 x cores / sides` threads: 4 with 8 sides on 16 cores, where COLMAP starts 16 each) and c58c994",
    "(without it, a `git archive`).",
    "- **Measured:** baseline 31 s / 37 s; first 120 s (**3.85x**) / 140 s (**3.79x**); second 65 s",
    "  (**2.07x**) / not run (the call's time ran out). The clean mappings took 86-88 s against 100-105 s,",
    "  but the baseline's own mapping also took 22.6 s against 27.7 s: the machine ran about 20% slower in",
    "  the second lane, and the ratio, the goal's measure, did not move. **Taken back** (78c6d69).",
    "- Goals (first <= 3x, second <= 2x): **missed** on this lease (3.79-3.85x; 2.07x). Round 5's 3.31x /",
    "  1.52x were another H200 lease: the ratio moves by 15-35% between leases, so one lane per side",
    "  decides nothing smaller than that.",
    "- Protection at 24 MP (every lane): default, hardened, published and masked 67% within 5 deg, global",
    "  0%: NOT protected, as in rounds 3-5.",
    "- **Landed:** photos up to 1600 px get the CPU's SIFT on a GPU machine (`gpu_sift_suits`; published",
    "  judged at its 2048 px round trip): with GPU SIFT, lego's 800 px renders cost `published` and",
    "  `masked` their clean control (round 5). CPU feature and clean-result keys are unchanged. Not run",
    "  again on lego with a GPU (no device time left); on this CPU nothing changes.",
    "",
]


ROUND6_NOTES = [
    "## Round 6: one mapping where two sides' input is the same, tried and taken back (2026-11-27)",
    "",
    "No device was lent this session: this 2-core CPU only, lego 40, two back-to-back pairs, each lane",
    "its own baseline, both trees `git archive`s (f30a2a5 with the change, 87ca9fa without it).",
    "- **The idea** (the last round's open item): hardened's clean side maps exactly the default's input",
    "  wherever its stationary filter changes no pair and no pair is flagged a watermark, so key each",
    "  mapping by the content of the verified database it reads and map once per key. It fired on the",
    "  6-view synthetic test set (0 pairs verified again), and **never on lego 40**: 32 of its 780 clean",
    "  pairs hold a raw match at the same position in both views (within COLMAP's stationary error), so",
    "  hardened verifies them again and its geometries differ from the default's. On lego a clean",
    "  mapping is 5 s anyway; the clean side's cost is its geometric verification (56-85 s: 780 pairs,",
    "  most of them mostly outliers, so RANSAC runs long), done three times (default's, shared with",
    "  hardened and global; masked's own matches; published's own pixels).",
    "- **Measured:** first 399 s (8.17x, the clean run 2) against 408-409 s (6.76x, 8.34x) without it;",
    "  second 201 s against 160-161 s (the change does not touch a second verification: poisoned",
    "  mappings alone varied 33-110 s between runs). Within this machine's noise; **taken back**",
    "  (09c33eb). f30a2a5 run 1 started while another job used the CPU (its baseline 93 s).",
    "- Goals (first <= 3x, second <= 2x) **missed** on 2 cores, as before: the sides' own seconds add up",
    "  to about 750 s, against a 49-60 s baseline.",
    "",
]


ROUND5_NOTES = [
    "## Round 5: every side its own task, clean sides first (2026-11-27, a lent H200)",
    "",
    "One NVIDIA H200, 16 cores, pycolmap-cuda12 4.2.1 (SIFT and matching on the GPU, mapping on the CPU),",
    "`bash bench/gpu_device.sh setup` then `main` (`PPD_GPU_VIEWS=12`), each lane's baseline in the same",
    "call. The rows' code: dba0926 (a profile's clean and poisoned sides run at once, 8 SfM children at",
    "once on 16 cores where round 3 ran 4 profiles, each side after the other) and 892b578 (the same, and",
    "every clean side takes its slot before any poisoned one: `verifier.verification.side_order`).",
    "- **12 photos of 24 MP (creator set):** first verification 3.65x (dba0926) and **3.31x** (892b578)",
    "  one default COLMAP run (32 s / 34 s); second, clean reference cached, 1.79x and **1.52x**. Goal",
    "  <= 3x first: **missed**; <= 2x second: met. Round 3's 5.10x / 1.90x were on an H100, another",
    "  machine, with the code before both changes: not a ratio to compare row by row.",
    "- **What is left of the first:** the clean references' mappings, 60-82 s each with eight children",
    "  sharing 16 cores (default 80 s, hardened 82 s, masked 79 s, global 60 s, published 47 s), against",
    "  26 s for the baseline's poisoned mapping alone (9 of 12 images registered; a clean one registers",
    "  12). Three of them (default, hardened, masked) map almost the same matches; sharing a clean mapping",
    "  between profiles would change what each profile's own control is, and was not done.",
    "- **lego 40 (dba0926):** baseline 47 s, first **2.66x**, second **1.13x**: both goals met on this",
    "  machine, but with GPU SIFT `published` and `masked` said *inconclusive* (their clean control did not",
    "  hold on 800 px renders; round 4 of gpu.md saw GPU SIFT part from the CPU's on small images), so",
    "  this is not a lego verdict; its baseline started at load 15, right after the creator lane, so",
    "  the ratios may be low. On this 2-core CPU lego stays 6.50x / 2.89x (round 4).",
    "- **lego 40 on this 2-core CPU, before and after, back to back** (2026-11-27 08:45 and 08:57, load",
    "  0.3-2.6; 272104a, then `--tree` a `git archive` of 3098d53): baseline 50 s / 58 s; first 395 s",
    "  (**7.96x**) against 447 s (7.77x): the same within this machine's noise (2 slots either way, the",
    "  CPU saturated: the sides' own seconds add up to 733 s, 366 s on two cores); second 185 s",
    "  (**3.73x**) against 293 s (5.10x). Every profile protected, 0% within 5 deg, in all four runs.",
    "  Goals (<= 3x, <= 2x): **missed** on 2 cores.",
    "- Protection at 24 MP, these runs: default 50-67%, hardened 50-67%, published 67%, masked 0-67%,",
    "  global 0% within 5 deg: NOT protected, as before (`protection_24mp.md`).",
    "",
]


ROUND4_NOTES = [
    "## Round 4: lego 40 on this machine (2026-11-26 14:26, code b9ef0a3, load 1.4-3.5)",
    "",
    "The first lego 40 lane to finish both verifications. The default COLMAP run of the poisoned set: 131 s",
    "(SIFT + raw matching 80 s, verification 18 s, mapping 32 s; 40 of 40 registered). `ppd verify --profile",
    "all`, first: **850 s = 6.50x** (goal <= 3x: missed); second, clean reference cached: **378 s = 2.89x**",
    "(goal <= 2x: missed). Every profile said protected, 0% of the cameras within 5 deg (default, hardened,",
    "published, global, masked; COLMAP seed 0).",
    "- **The first** is the clean references: geometric verification of the clean originals' 780 pairs",
    "  (default 114 s, hardened 99 s, published 138 s, masked 95 s: pairs with few true matches run RANSAC",
    "  to its trial limit) and the clean features (default 127 s, published 138 s, masked 46 s). Each is",
    "  an attacker pipeline's control on the originals and is kept.",
    "- **The second** is five attackers' own runs on the poisoned set: their elapsed seconds add up to",
    "  644 s (default 201 incl. SIFT and matching, published 231 incl. its own SIFT of its own pixels,",
    "  masked 122, hardened 74, global 16), two profiles at a time on 2 cores: even perfectly parallel",
    "  that is 322 s = 2.46x the baseline. On this machine, five pipelines cannot fit in 2x one pipeline",
    "  without dropping work a verdict uses; the measured floor is set by the attackers' own runs.",
    "",
]


ROUND3_NOTES = [
    "## Round 3: a lent GPU machine (2026-11-26, code 3e10615; bench/gpu_device.sh, bench/results/gpu.md)",
    "",
    "One NVIDIA H100 80GB, 16 cores, pycolmap-cuda12 4.2.1 (the `[gpu]` extra) carried there; SIFT",
    "extraction and matching on the GPU (`sift_device()` said `Device.cuda`), everything else on the CPU.",
    "- **40 views of 6000 x 4000 (creator set):** made in 16 s; the default COLMAP run of the poisoned set",
    "  (the baseline) did not finish in its 300 s limit: a timeout, not a figure. The two verification",
    "  lanes after it failed at start-up (the machine lacked pydantic, which typer 0.29 imports): no",
    "  figure. Not measured.",
    "- **12 views of 6000 x 4000 (creator set, made there in 6 s):** the default COLMAP run 26 s (SIFT and",
    "  raw matching 5.2 s on the GPU, mapping 19.6 s); `ppd verify --profile all` first **134 s = 5.10x**",
    "  (goal <= 3x: missed), second (clean reference cached) **50 s = 1.90x** (goal <= 2x: met on this",
    "  set). What the first spends: each profile's clean mapping (default 55 s, hardened 61 s, masked 49 s,",
    "  published 34 s, global 21 s), four profiles at once; SIFT is no longer the cost.",
    "- **Protection at 24 MP: the default mark does NOT hold on this set** (cameras within 5 deg, first /",
    "  second verification, same files and seed): default 42% / 67%, hardened 42% / 67%, published 67% /",
    "  67%, masked 50% / 67%, global 0% / 0%. A separate `--profile default` run: 9 of 12 poisoned cameras",
    "  registered, median rotation error 0.7 deg, NOT protected.",
    "",
]

ROUND2_NOTES = [
    "## Round 2 (2026-11-26 08:20-10:00; the machine shared with four other engineers, load 6-9)",
    "",
    "Code: hardened's geometric verification is made from the default's (COLMAP's stationary filter",
    "drops a pair's matches *before* its RANSAC, and RANSAC with a fixed seed is a function of its input,",
    "so only the pairs holding a stationary match are verified again: lego 20 clean 8 of 190 pairs,",
    "poisoned 24 of 190; lego 40 poisoned 113 of 780; equal pair by pair to a whole hardened verification",
    "on a generated set and on lego 16 at seeds 0 and 1: tests/verifier/test_verify_stationary.py); shared",
    "verifications are built by verify-only children under their own lock, so a profile waits for a",
    "verification, never for another profile's mapping; two profiles at once from 2 cores up;",
    "`published` starts first (added after the lego 20 lane below, not measured).",
    "",
    "Measured: lego 20 (the first lane stopped): the default COLMAP run 106 s; the verification was",
    "stopped after 1137 s (**>10.7x**). Default and hardened ran side by side (245 s), then global (30 s)",
    "and masked (170 s): all four were done 784 s after the start. `published`, started third, spent",
    "more than 11 minutes in **one** call of COLMAP's incremental mapper on its poisoned side: the",
    "structure-less registration fallback (`Registering image with structure-less fallback`, `Image sees",
    "751 / 4584 correspondences`, then no log line, one core busy). That is the attacker's own COLMAP run",
    "(COLMAP 4.2.1's default mapper options, as convert.py runs them), so it counts; no sharing removes",
    "it. Hardened's clean verification (8 pairs verified again) took 52 s against the default's 47 s for",
    "all 190: the pairs the filter changes are the expensive ones (fewer inliers left, RANSAC runs to its",
    "trial limit); what a whole hardened verification costs here was not measured.",
    "Lego 40: not measured this round: its default COLMAP run alone (the baseline) did not finish in 12",
    "minutes at load 6-9 (two tries, stopped at 8 and 12 min): its mapping is in the same fallback",
    "(7215 registration attempts in the first 7 minutes). The goals (first <= 3x, second <= 2x) are",
    "**not shown**: on these poisoned sets the attacker's mapping, not shared work, sets the time.",
    "",
    "Creator scale (testkit/creator_set.py, `--set creator`: a box whose faces are real photographs,",
    "2048 px crops of fountain-P11, about 1.2 image px per texture px on a 6000 px view, on a plain",
    "backdrop; synthetic geometry and light; camera-like JPEG q92, poisoned by ppd's own poison_file):",
    "40 views of 6000 x 4000 were made in 635 s wall (one worker at nice 19, load ~8), 12 in 156 s;",
    "about 5 s of CPU a photo. What ran: **8 views of 6000 x 4000, the default profile only** (with its",
    "clean reference), `--views 8 --width 6000 --profile default --second`: the default COLMAP run",
    "227 s (SIFT extraction at COLMAP's 3200 px: 185 s of it), first verification 390 s (**1.72x**),",
    "second, clean cached, 260 s (**1.15x**). Protection at 24 MP is **not** established: the first",
    "verification said protected (0 of 8 cameras within 5 degrees, 7 registered, median rotation error",
    "6.9 degrees, 4 of 8 within 10), the second, same seed and the same poisoned files, NOT protected",
    "(5 of 8 within 5 degrees, median 4.5 degrees): COLMAP's mapping is not bit-reproducible and this",
    "set sits at the edge. Not run: 40 views at 24 MP, and hardened, published, global and masked at",
    "24 MP (a 12-view default lane was stopped at its baseline: its time limits were too short for the",
    "load; the rest did not fit in the session).",
    "",
    "## Round 1",
    "",
]

NOTES = [
    "Before (main at 9ea1f7c, four profiles, nothing shared but features between default and hardened,",
    "no clean cache in folder mode): issue 30 measured 547 s for `ppd verify --profile all` vs 76 s for one",
    "default COLMAP run on this machine idle, **7.2x**. The same lane was started again here (2026-11-26",
    "05:54, load ~10: its default COLMAP run took 404 s) and stopped: at that load its verification would",
    "have taken about 40 minutes, which this session's time could not hold next to the after lane. The",
    "after lanes add the `global` profile (five profiles against four before).",
    "",
    "Result: the goals are **not met** on this machine. First verification 2413 s = **4.71x** one default",
    "COLMAP run (512 s) at load 6-10 (before: 7.2x idle, four profiles). The second lane (clean cached)",
    "was stopped to leave time for the tests; from the first lane's own figures it would be the poisoned",
    "sides' runs (81 + 295 + 153 + 44 + 147 = 720 s) plus the children they do not count: the poisoned",
    "extraction and raw matching (~270 s in the baseline), published's own (~150 s), masked's re-matching",
    "(~130 s), visibility and hashing (~30 s): about 1300 s, **~2.5x**, an estimate, not a measurement.",
    "Where the time goes (first lane, per profile below): COLMAP's geometric verification of the *clean*",
    "originals (182 s default, 159 s hardened, 261 s published, 162 s masked, against 26-41 s on the",
    "poisoned set) and hardened's poisoned mapping (253 s, 18 of 40 images in pieces). Sharing saved:",
    "global's verification (0 s, copied from default's) and its features; masked's extraction (filtered",
    "by position); hardened's and global's extraction and raw matching. Profiles ran one at a time",
    "(2 cores: `workers` = 1). In the stage table, the first lane's features-only children are not listed:",
    "the code that counts them in a side's timings came after this run.",
    "",
    "Creator scale (40 x 6000x4000), round 1: not run. The driver makes the sets",
    "(`--set lego-upscaled --width 6000`:",
    "lego padded to 3:2 and upscaled, no detail beyond its 800 px; `--set synthetic --width 6000`:",
    "verifier.synthetic's textured scene rendered at full size, whose 512 px noise textures also carry no",
    "fine detail at that size); making 5 such images took 5 minutes here under load ~10, so 40 of them",
    "plus the runs did not fit. Protection at 24 MP with real fine detail is still unmeasured.",
]


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
    rounds = (ROUND9_NOTES, ROUND8_NOTES, ROUND7_NOTES, ROUND6_NOTES, ROUND5_NOTES, ROUND4_NOTES,
              ROUND3_NOTES, ROUND2_NOTES, NOTES)
    lines += ["", *(line for notes in rounds for line in notes), ""]
    lines += ["## Per profile and stage (seconds, from each run's report.json)", ""]
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
