"""Ctrl-C at random moments during `ppd poison` of 23 photos (issue 28): after each, `ppd status`
must be true (its file count equal to the folder's photos, patched + not patched yet = all of
them, exactly as many files changed on disk as it calls patched), the run's one line must name
the command that finishes, a resume run must complete, and no process may print a traceback.

    python -m bench.bench_interrupt [--moments 10] [--serial 5] [--seed 28]

The photos: dtu_scan37's first 23 views as JPEG q90 (1600x1200) when the shared datasets are
there, else 23 synthetic photos of that size. The Ctrl-C is a terminal's: SIGINT to the whole
process group (ppd, its forkserver and its workers). The moments are drawn uniformly over the
length of an uninterrupted run measured first, in the same process (one that came after the run
had ended is drawn again, below it). Results:
bench/results/interrupt.md.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import PIL.Image

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "datasets" / "dtu_scan37" / "images"
RESULTS = REPO / "bench" / "results" / "interrupt.md"
N_PHOTOS = 23


def make_photos(folder: Path) -> str:
    folder.mkdir(parents=True)
    sources = sorted(SHARED.glob("*.png"))[:N_PHOTOS] if SHARED.is_dir() else []
    if len(sources) == N_PHOTOS:
        for i, src in enumerate(sources):
            PIL.Image.open(src).convert("RGB").save(folder / f"IMG_{i:04d}.jpg", quality=90)
        return "dtu_scan37 views 0-22, JPEG q90, 1600x1200"
    rng = np.random.default_rng(28)
    base = rng.integers(0, 256, (1200, 1600, 3), dtype=np.uint8)
    for i in range(N_PHOTOS):
        PIL.Image.fromarray(np.roll(base, 41 * i, axis=1)).save(folder / f"IMG_{i:04d}.jpg", quality=90)
    return "synthetic noise, JPEG q90, 1600x1200 (shared datasets not found)"


def digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.glob("*.jpg"))}


def ppd_env(home: Path) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    for var, name in (
        ("PPD_DATA_DIR", "data"),
        ("PPD_CONFIG_DIR", "config"),
        ("PPD_OUTBOX", "outbox"),
    ):
        (home / name).mkdir(parents=True, exist_ok=True)
        env[var] = str(home / name)
    return env


def ppd(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", *args], env=env, cwd=REPO, capture_output=True,
                          text=True, timeout=600)  # fmt: skip


def fresh(work: Path, photos: Path, name: str) -> tuple[Path, dict[str, str]]:
    home = work / name
    shutil.rmtree(home, ignore_errors=True)
    shutil.copytree(photos, home / "shoot")
    return home / "shoot", ppd_env(home)


def full_run(work: Path, photos: Path) -> float:
    shoot, env = fresh(work, photos, "full")
    started = time.monotonic()
    done = ppd(env, "poison", str(shoot))
    if done.returncode != 0:
        raise RuntimeError(f"uninterrupted run failed: {done.stderr.strip()}")
    return time.monotonic() - started


def trial(work: Path, photos: Path, originals: dict[str, str], moment: float, workers: str) -> dict:
    shoot, env = fresh(work, photos, "trial")
    command = [sys.executable, "-m", "daemon.cli", "poison", str(shoot), "--workers", workers]
    proc = subprocess.Popen(command, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)  # fmt: skip
    time.sleep(moment)
    signalled = proc.poll() is None
    if signalled:
        os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C: the whole foreground group
    out, err = proc.communicate(timeout=600)
    status = ppd(env, "status", "shoot", "--json")
    d = json.loads(status.stdout)["datasets"][0] if status.returncode == 0 else None
    changed = sum(1 for name, sha in digests(shoot).items() if originals.get(name) != sha)
    lines = [x for x in out.splitlines() if x.startswith("interrupted:")]
    lines += [x for x in err.splitlines() if x.startswith("ppd: interrupted")]  # during start-up
    resumed = ppd(env, "poison", str(shoot))
    after = ppd(env, "status", "shoot", "--json")
    d2 = json.loads(after.stdout)["datasets"][0] if after.returncode == 0 else None
    tracebacks = sum(text.count("Traceback") for text in (out, err, status.stderr, resumed.stdout,
                                                          resumed.stderr, after.stderr))  # fmt: skip
    on_disk = len(list(shoot.glob("*.jpg")))
    if d is None:  # stopped before the dataset existed: true only if nothing changed on disk
        true = status.returncode == 2 and changed == 0
    else:
        true = d["counts"]["files"] == on_disk and d["patched"] + d["not_patched_yet"] == on_disk
        true = true and changed == d["patched"]
    return {
        "moment_s": round(moment, 2), "workers": workers, "signalled": signalled, "rc": proc.returncode,
        "line": lines[0] if lines else None, "patched": None if d is None else d["patched"],
        "not_patched_yet": None if d is None else d["not_patched_yet"],
        "status_files": None if d is None else d["counts"]["files"], "on_disk": on_disk, "changed": changed,
        "status_true": true, "resume_rc": resumed.returncode,
        "resumed_all": d2 is not None and d2["patched"] == d2["counts"]["files"] == on_disk
        and sum(1 for n, s in digests(shoot).items() if originals.get(n) != s) == on_disk,
        "tracebacks": tracebacks, "temporaries": len(list(shoot.glob(".ppd-tmp-*"))),
    }  # fmt: skip


def render(rows: list[dict], full_s: float, source: str, seed: int) -> str:
    ok_status = sum(r["status_true"] for r in rows)
    ok_resume = sum(r["resume_rc"] == 0 and r["resumed_all"] for r in rows)
    n, cmd = len(rows), f"python -m bench.bench_interrupt --seed {seed}"
    header = ["moment (s)", "workers", "exit", "patched", "not patched yet", "status files", "photos",
              "changed on disk", "status true", "resume", "tracebacks"]  # fmt: skip
    lines = [
        "# Ctrl-C during `ppd poison` (issue 28)",
        "",
        f"`{cmd}`: {n} runs of `ppd poison` on {N_PHOTOS} photos ({source}), each sent a "
        "terminal's Ctrl-C (SIGINT to the process group: ppd, its forkserver and workers) at a "
        f"moment drawn uniformly over an uninterrupted run's {full_s:.1f} s (measured first, in the "
        "same process; a moment after the run had ended is drawn again below it; a 2-core machine "
        "shared with other work).",
        "",
        f"- status true after the interruption: **{ok_status} of {n}** (its file count = the "
        "folder's photos, patched + not patched yet = all of them, and exactly as many files "
        "changed on disk as it calls patched)",
        f"- resume run (`ppd poison FOLDER`) completed, every photo patched: **{ok_resume} of {n}**",
        f"- tracebacks printed by any process: **{sum(r['tracebacks'] for r in rows)}**; "
        f"temporaries left: **{sum(r['temporaries'] for r in rows)}**",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for r in rows:
        exit_text = f"{r['rc']}{'' if r['signalled'] else ' (done first)'}{'' if r['line'] else ', no line'}"
        if r["signalled"] and r["rc"] == 0:  # the files were all done: the usual summary, no scene notes
            exit_text = "0 (signal after the last file)"
        resume = "done" if r["resume_rc"] == 0 and r["resumed_all"] else "**failed**"
        cells = [r["moment_s"], r["workers"], exit_text, r["patched"], r["not_patched_yet"],
                 r["status_files"], r["on_disk"], r["changed"], "yes" if r["status_true"] else "**no**",
                 resume, r["tracebacks"]]  # fmt: skip
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    lines += [
        "",
        "A run stopped before its dataset existed (during start-up) has no status row: it counts as",
        "true when `ppd status DATASET` says there is no such dataset and no file changed on disk.",
        "",
        "The line each interrupted run ended with (first three):",
        "",
    ]
    lines += [f"    {r['line']}" for r in rows if r["line"]][:3]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moments", type=int, default=10, help="interrupted runs with --workers 2")
    parser.add_argument("--serial", type=int, default=0, help="more interrupted runs with --workers 1")
    parser.add_argument("--seed", type=int, default=28)
    args = parser.parse_args(argv if argv is not None else [])
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="ppd-bench-interrupt-") as tmp:
        work = Path(tmp)
        source = make_photos(work / "photos")
        originals = digests(work / "photos")
        full_s = full_run(work, work / "photos")
        plan = [("2", rng.uniform(0.0, full_s)) for _ in range(args.moments)]
        plan += [("1", rng.uniform(0.0, full_s)) for _ in range(args.serial)]
        rows = []
        for workers, moment in plan:
            for _ in range(4):  # a moment after the run ended (the machine was faster) is drawn again
                row = trial(work, work / "photos", originals, moment, workers)
                if row["signalled"]:
                    break
                moment = rng.uniform(0.0, moment)
            rows.append(row)
            print(json.dumps(rows[-1]), flush=True)
    RESULTS.write_text(render(rows, full_s, source, args.seed))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main(sys.argv[1:])
