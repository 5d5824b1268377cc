"""SIGKILL loops on `ppd poison` and `ppd watch`, the daemon under a real 1 GiB memory limit with
systemd-style restarts, two daemons plus a CLI on one outbox, and a deleted store (issues 15, 20).

    python -m bench.bench_kill_loops poison --kills 100
    python -m bench.bench_kill_loops watch --kills 104
    python -m bench.bench_kill_loops memory --seconds 120
    python -m bench.bench_kill_loops concurrency --rounds 5
    python -m bench.bench_kill_loops store-deleted --rounds 5
    python -m bench.bench_kill_loops render --inputs A.json B.json ...   (writes the results section)

Each prints one JSON line of figures (and writes it to --json when given); the tables are in
bench/results/reliability.md, section `kill-loops`, and docs/RELIABILITY.md. The poison loop, the
concurrency and store-deleted rounds are testkit/kill_loops.py's (the tests run them small).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import PIL.Image  # before anything that could load pycolmap

from daemon.paths import AppPaths
from daemon.states import FileState
from daemon.store import Store
from poisoner.atomic import TEMP_PREFIX
from testkit.daemon_proc import Daemon
from testkit.kill_loops import concurrency_round, poison_loop, store_deleted_round, write_photo
from testkit.photos import texture
from testkit.reliability import (
    DAEMON_ARGS,
    CrashTrialOptions,
    app_paths,
    kill_daemon,
    run_crash_trials,
    start_daemon,
    write_results_section,
)


# ---- SIGKILL loop on `ppd watch` ------------------------------------------------------------------
def watch_loop(root: Path, kills: int, chains: int) -> dict[str, object]:
    """bench_faults' crash trials, smaller: 4 photos of 256 px per kill, a 12-frame MP4 every 4th."""
    totals: Counter[str] = Counter()
    findings: list[str] = []
    started = time.monotonic()
    per_chain = -(-kills // chains)
    for chain in range(chains):
        options = CrashTrialOptions(trials=per_chain, images_per_trial=4, image_size=256, video_every=4,
                                    seed=100 + chain, kill_after_s=(0.05, 1.0))  # fmt: skip
        report = run_crash_trials(root / f"chain{chain}", options)
        totals["kills"] += report.trials
        totals["files"] += report.files
        totals["videos"] += report.videos
        totals["lost"] += report.lost
        totals["corrupt or store disagreeing"] += report.corrupted
        totals["not exactly once"] += len(report.not_exactly_once)
        totals["leftover .ppd-tmp-* after the next run"] += report.leftover_temporaries
        totals["kills that left pending work"] += report.killed_with_work_pending
        totals["exit -9"] += report.exit_codes[-9]
        findings += (report.violations_after_kill + report.violations_final + report.not_exactly_once)[:5]
        if report.leftover_temporaries:
            findings.append(f"chain {chain}: " + ", ".join(
                str(p) for p in (root / f"chain{chain}" / "outbox").rglob(f"{TEMP_PREFIX}*")))
        print(f"watch loop chain {chain}: {dict(totals)}", flush=True)
        shutil.rmtree(root / f"chain{chain}", ignore_errors=True)
    return {"scenario": "watch", **totals, "seconds": round(time.monotonic() - started),
            "findings": findings[:20]}  # fmt: skip


# ---- the daemon under a 1 GiB memory limit --------------------------------------------------------
CGROUP_V1 = Path("/sys/fs/cgroup/memory")
REFUSED = ("failed", "quarantined")
DECIDED = (FileState.PATCHED, "skipped", *REFUSED)


def memory_cgroup(limit: int) -> Path | None:
    """A child of this process's cgroup-v1 memory group with memory.limit_in_bytes = limit (and
    the same memsw limit, so swap cannot hide it); None where that cannot be made."""
    try:
        own = next(line.split(":", 2)[2] for line in Path("/proc/self/cgroup").read_text().splitlines()
                   if line.split(":")[1] == "memory")  # fmt: skip
        group = CGROUP_V1 / own.lstrip("/") / f"ppd-bench-{os.getpid()}"
        group.mkdir(exist_ok=True)
        (group / "memory.limit_in_bytes").write_text(str(limit))
        with contextlib.suppress(OSError):  # charge the daemon's start-up pages here too, not to the parent
            (group / "memory.move_charge_at_immigrate").write_text("3")
        with contextlib.suppress(OSError):
            (group / "memory.memsw.limit_in_bytes").write_text(str(limit))
        return group
    except (OSError, StopIteration, IndexError):
        return None


def write_memory_corpus(folder: Path, big_png_mp: int = 0) -> list[Path]:
    from testkit import hostile_images

    hostile = hostile_images.write_corpus(folder)
    large = []
    for i in range(3):  # legitimate large photos: 4000x3000 JPEG (12 MP)
        big = folder / f"legit-large-{i}.jpg"
        tile = texture(500 + i, 1000)
        PIL.Image.fromarray(tile).resize((4000, 3000)).save(big, quality=90)
        large.append(big)
    for i in range(4):
        large.append(write_photo(folder / f"legit-small-{i}.png", 900 + i))
    if big_png_mp:  # legitimate and under the pixel limit, but a decode of several hundred MB
        side = int((big_png_mp * 1e6) ** 0.5)
        ramp = np.linspace(0, 255, side, dtype=np.uint8)
        PIL.Image.fromarray(np.dstack([np.tile(ramp, (side, 1))] * 3)).save(folder / "legit-big.png")
        large.append(folder / "legit-big.png")
    return hostile + large


def _watch_until_decided(daemon: Daemon, paths: AppPaths, names: set[str], deadline: float,
                         rows: dict[str, dict]) -> tuple[int, dict[str, dict]]:  # fmt: skip
    """Poll the daemon's peak RSS (VmHWM, kB) and the store's rows until every file is decided,
    the daemon exits or the deadline passes; returns the peak and the latest rows."""
    peak = 0
    while daemon.proc.poll() is None and time.monotonic() < deadline:
        with contextlib.suppress(OSError, ValueError, StopIteration):
            status = Path(f"/proc/{daemon.pid}/status").read_text()
            hwm = next(x for x in status.splitlines() if x.startswith("VmHWM"))
            peak = max(peak, int(hwm.split()[1]))
        store = Store(paths.db_path)
        try:
            rows = {Path(r["path"]).name: r for r in store.files("hostile")}
        finally:
            store.close()
        if all(rows.get(n, {}).get("state") in DECIDED for n in names):
            break
        time.sleep(0.2)
    return peak, rows


def _supervise_in_cgroup(
    root: Path, group: Path | None, stage: Path, names: set[str], seconds: float,
    figures: Counter[str], peaks: list[int], exits: list[int],
) -> dict[str, dict]:  # fmt: skip
    """Start `ppd watch` in the cgroup, move the corpus in once, restart after any non-zero exit
    (systemd's Restart=on-failure) until every file is decided or `seconds` pass; returns the rows."""
    paths = app_paths(root)
    deadline = time.monotonic() + seconds
    moved = False
    rows: dict[str, dict] = {}
    while time.monotonic() < deadline:
        daemon = start_daemon(root, *DAEMON_ARGS)
        if group is not None:
            (group / "cgroup.procs").write_text(str(daemon.pid))
        figures["starts"] += 1
        if not moved:
            stage.rename(paths.outbox / "hostile")
            moved = True
        peak, rows = _watch_until_decided(daemon, paths, names, deadline, rows)
        peaks.append(peak)
        if daemon.proc.poll() is None:
            exits.append(kill_daemon(daemon, signal.SIGTERM))
            break
        exits.append(daemon.proc.returncode)
        kill_daemon(daemon, signal.SIGTERM)
        time.sleep(0.1)  # systemd's RestartSec, shortened
    return rows


def _finished_attempts(paths: AppPaths) -> Counter[str]:
    """Finished attempts per file name: one "patched" or "failed" event each."""
    attempts: Counter[str] = Counter()
    store = Store(paths.db_path)
    try:
        for event in store.events(limit=1_000_000):
            if event["kind"] in ("patched", "failed"):  # one per finished attempt
                attempts[Path(event["path"]).name] += 1
    finally:
        store.close()
    return attempts


def _cgroup_oom_kills(group: Path | None, figures: Counter[str]) -> int | None:
    """The cgroup's OOM kill count (None without one); records its peak usage in figures."""
    oom_kills = None
    if group is not None:
        with contextlib.suppress(OSError):
            control = (group / "memory.oom_control").read_text()
            counts = [int(x.split()[1]) for x in control.splitlines() if x.startswith("oom_kill ")]
            oom_kills = counts[0] if counts else None
        with contextlib.suppress(OSError):
            figures["cgroup max_usage MB"] = int((group / "memory.max_usage_in_bytes").read_text()) >> 20
    return oom_kills


def memory_run(root: Path, seconds: float, limit: int, big_png_mp: int = 0) -> dict[str, object]:
    """The hostile corpus plus legitimate large files moved into `ppd watch` running in a cgroup
    with memory.limit_in_bytes = limit; a supervisor restarts it after any non-zero exit, as
    systemd's Restart=on-failure would, until every file is decided or `seconds` pass."""
    paths = app_paths(root)
    group = memory_cgroup(limit)
    stage = root / "stage" / "hostile"
    stage.mkdir(parents=True)
    files = write_memory_corpus(stage, big_png_mp)
    from daemon.protect.one_file import media_kind

    ignored = sorted(p.name for p in files if media_kind(p) is None)  # e.g. GIF: not a ppd format
    names = {p.name for p in files if media_kind(p) is not None}
    (paths.outbox).mkdir(parents=True, exist_ok=True)
    figures: Counter[str] = Counter()
    peaks: list[int] = []
    exits: list[int] = []
    rows = _supervise_in_cgroup(root, group, stage, names, seconds, figures, peaks, exits)
    attempts = _finished_attempts(paths)
    oom_kills = _cgroup_oom_kills(group, figures)
    logs = "\n".join(p.read_text(errors="replace") for p in root.glob("daemon-*.log"))
    state = {n: (rows.get(n) or {}).get("state") for n in names}
    refused = {n: (rows.get(n) or {}).get("error") for n in names if state[n] in REFUSED}
    unnamed = [n for n, err in refused.items() if not err or "\n" in err or n not in (err + logs)]
    if group is not None:
        with contextlib.suppress(OSError):
            group.rmdir()
    return {
        "scenario": "memory",
        "limit": f"cgroup v1 memory.limit_in_bytes={limit}" if group else "none (VmHWM only)",
        "files": len(names), "ignored (not a ppd format)": ignored, "restarts": figures["starts"] - 1,
        "exit_codes": exits,
        "oom_kills": oom_kills, "peak_rss_mb": round(max(peaks) / 1024, 1) if peaks else None,
        "cgroup_max_usage_mb": figures["cgroup max_usage MB"],
        "states": dict(Counter(state.values())),
        "most finished attempts of one file": max(attempts.values(), default=0),
        "refused": {n: (e or "")[:160] for n, e in refused.items()}, "refused_without_named_reason": unnamed,
        "undecided": [n for n in names if state[n] not in DECIDED],
    }  # fmt: skip


def rounds(fn, root: Path, count: int, files: int, name: str) -> dict[str, object]:
    total: Counter[str] = Counter()
    started = time.monotonic()
    for i in range(count):
        sub = root / f"r{i}"
        sub.mkdir(parents=True)
        got = fn(sub, files, i + 1)
        print(f"{name} round {i}: {dict(got)}", flush=True)
        total.update(got)
    return {"scenario": name, "rounds": count, **total, "seconds": round(time.monotonic() - started)}


def render(results: list[dict[str, object]]) -> str:
    """The `kill-loops` section of bench/results/reliability.md: one block per scenario run."""
    lines = ["## SIGKILL loops, memory limit, two daemons, a deleted store (`bench_kill_loops`)", "",
             "2-core machine shared with other engineers' work. Each block: the command, then its figures."]
    for result in results:
        lines += ["", f"### {result['scenario']}: `{result['command']}`", ""]
        lines += ["| figure | value |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in result.items() if k not in ("scenario", "command")]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    scenarios = ["poison", "watch", "memory", "concurrency", "store-deleted", "render"]
    parser.add_argument("scenario", choices=scenarios)
    parser.add_argument("--kills", type=int, default=100)
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--per-kill", type=int, default=6)
    parser.add_argument("--video-every", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=180)
    parser.add_argument("--limit-mb", type=int, default=1024)
    parser.add_argument("--window", default="0,1.2", help="kill between these multiples of a whole run")
    parser.add_argument("--big-png-mp", type=int, default=0)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--files", type=int, default=12)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--pid-only-every", type=int, default=0,
                        help="poison: every Nth trial SIGKILLs ppd's pid alone, not its group")  # fmt: skip
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--inputs", type=Path, nargs="*", default=[], help="render: JSON files to tabulate")
    args = parser.parse_args(argv)
    if args.scenario == "render":
        write_results_section("kill-loops", render([json.loads(p.read_text()) for p in args.inputs]))
        return
    root = Path(tempfile.mkdtemp(prefix=f"ppd-bench-{args.scenario}-"))
    try:
        if args.scenario == "poison":
            window = tuple(float(x) for x in args.window.split(","))
            result = poison_loop(root, args.kills, args.seed, args.per_kill, args.video_every, window,
                                 args.pid_only_every)  # fmt: skip
        elif args.scenario == "watch":
            result = watch_loop(root, args.kills, args.chains)
        elif args.scenario == "memory":
            result = memory_run(root, args.seconds, args.limit_mb << 20, args.big_png_mp)
        elif args.scenario == "concurrency":
            result = rounds(concurrency_round, root, args.rounds, args.files, "concurrency")
        else:
            result = rounds(store_deleted_round, root, args.rounds, args.files, "store-deleted")
        result["command"] = "python -m bench.bench_kill_loops " + " ".join(argv or sys.argv[1:])
        print(json.dumps(result, default=str), flush=True)
        if args.json:
            args.json.write_text(json.dumps(result, default=str))
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main(sys.argv[1:])
