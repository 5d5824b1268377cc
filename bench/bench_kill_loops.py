"""SIGKILL loops on `ppd poison` and `ppd watch`, the daemon under a real 1 GiB memory limit with
systemd-style restarts, two daemons plus a CLI on one outbox, and a deleted store (issues 15, 20).

    python -m bench.bench_kill_loops poison --kills 100
    python -m bench.bench_kill_loops watch --kills 104
    python -m bench.bench_kill_loops memory --seconds 120
    python -m bench.bench_kill_loops concurrency --rounds 5
    python -m bench.bench_kill_loops store-deleted --rounds 5
    python -m bench.bench_kill_loops render --inputs A.json B.json ...   (writes the results section)

Each prints one JSON line of figures (and writes it to --json when given); the tables are in
bench/results/reliability.md, section `kill-loops`, and docs/RELIABILITY.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import PIL.Image  # before anything that could load pycolmap

from bench.bench_daemon import Daemon
from daemon.paths import AppPaths
from daemon.states import FileState
from daemon.store import Store
from poisoner.atomic import TEMP_PREFIX
from tests.daemon.watch.test_watcher import texture
from tests.reliability_harness import (
    DAEMON_ARGS,
    CrashTrialOptions,
    app_paths,
    check_invariants,
    kill_daemon,
    make_video,
    protected_counts,
    run_crash_trials,
    sha256,
    start_daemon,
    subprocess_env,
    wait_for,
)

REPO = Path(__file__).resolve().parents[1]


def _ppd(root: Path, *args: str, **kw: object) -> subprocess.Popen[bytes]:
    log = open(root / "cli.log", "ab")  # noqa: SIM115 - closed by the child's exit
    return subprocess.Popen([sys.executable, "-m", "daemon.cli", *args], env=subprocess_env(root), cwd=REPO,
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True, **kw)  # fmt: skip


def write_photo(path: Path, seed: int) -> Path:
    """A 320x240 PNG or JPEG (by suffix), distinct per seed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    pixels = texture(seed, 320)[:240]
    fmt = "JPEG" if path.suffix.lower() in (".jpg", ".jpeg") else "PNG"
    PIL.Image.fromarray(pixels).save(path, format=fmt)
    return path


def leftovers(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob(f"{TEMP_PREFIX}*"))


def vault_has(root: Path, digest: str) -> bool:
    blob = app_paths(root).vault_dir / digest[:2] / digest
    return blob.is_file() and sha256(blob) == digest


def audit(root: Path, originals: dict[Path, str], folder: Path) -> dict[str, list[str]]:
    """After a completed run: every file patched once from its own original, every original in
    the vault, nothing of ppd's left in the user's folder."""
    paths = app_paths(root)
    store = Store(paths.db_path)
    try:
        rows = {r["path"]: r for ds in store.datasets() for r in store.files(ds["name"])}
    finally:
        store.close()
    counts = protected_counts(paths)
    out: dict[str, list[str]] = {"invariants": check_invariants(paths, originals), "not_patched": [],
                                 "double": [], "not_restorable": [], "corrupt": [],
                                 "leftovers": [str(p) for p in leftovers(folder)]}  # fmt: skip
    for path, original in originals.items():
        row = rows.get(str(path)) or {}
        if row.get("state") != FileState.PATCHED:
            out["not_patched"].append(f"{path.name}: {row.get('state')} {row.get('error')}")
        if counts[str(path)] > 1 or (row and row.get("original_sha256") not in (None, original)):
            out["double"].append(f"{path.name}: {counts[str(path)]} patches")
        if not vault_has(root, original):
            out["not_restorable"].append(path.name)
        if not path.is_file() or (row.get("poisoned_sha256") and sha256(path) != row["poisoned_sha256"]):
            out["corrupt"].append(path.name)
    return out


# ---- SIGKILL loop on `ppd poison` -----------------------------------------------------------------
def _add_trial_files(root: Path, rng: random.Random, trial: int, per_kill: int, video_every: int,
                     originals: dict[Path, str], figures: Counter[str]) -> list[str]:  # fmt: skip
    """Stage this trial's photos (and video) and move each into the folder; returns their names."""
    folder = root / "photos" / "trip"
    stage = root / "stage"
    names = [f"k{trial:03d}-{i}{rng.choice(('.png', '.jpg'))}" for i in range(per_kill)]
    if video_every and trial % video_every == 0:
        names.append(f"k{trial:03d}-clip.mp4")
    for i, name in enumerate(names):
        src = stage / name
        if name.endswith(".mp4"):
            stage.mkdir(parents=True, exist_ok=True)
            make_video(src, seed=trial * 100 + i, frames=20)  # 1 s at 20 fps
            figures["videos"] += 1
        else:
            write_photo(src, trial * 100 + i)
        originals[folder / name] = sha256(src)
        folder.mkdir(parents=True, exist_ok=True)
        os.rename(src, folder / name)
    return names


def _kill_at_random(proc: subprocess.Popen, rng: random.Random, window: tuple[float, float],
                    full_runs: list[float], figures: Counter[str]) -> None:  # fmt: skip
    delay = rng.uniform(*(w * statistics.median(full_runs) for w in window))
    try:
        proc.wait(delay)
        figures["finished before the kill"] += 1
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        figures["kills"] += 1


def _count_kill_state(root: Path, folder: Path, names: list[str], originals: dict[Path, str],
                      figures: Counter[str]) -> None:  # fmt: skip
    """Count what the kill interrupted: temporaries, a half-patched trial, pending rows."""
    paths = app_paths(root)
    figures["kills that left a .ppd-tmp-*"] += bool(leftovers(folder))
    done_now = sum(sha256(folder / n) != originals[folder / n] for n in names)
    partial = 0 < done_now < len(names)
    figures["kills after some of the trial's files were patched, before others"] += partial
    store = Store(paths.db_path)
    try:
        pending = any(r["state"] == "pending" for ds in store.datasets() for r in store.files(ds["name"]))
    finally:
        store.close()
    figures["kills that left a pending row"] += pending
    figures["kills in the middle of work (pending row, temporary, or part done)"] += (
        pending or partial or bool(leftovers(folder)))


def _recover_and_audit(root: Path, folder: Path, trial: int, originals: dict[Path, str],
                       figures: Counter[str], findings: list[str]) -> None:  # fmt: skip
    """Check no original was lost by the kill, run `ppd poison` again to completion, audit the folder."""
    after_kill = [v for v in check_invariants(app_paths(root), originals) if v.startswith("lost")]
    findings += [f"trial {trial} after kill: {v}" for v in after_kill]
    rerun = _ppd(root, "poison", str(folder))
    code = rerun.wait(300)
    if code != 0:
        findings.append(f"trial {trial}: next run exit {code}")
    result = audit(root, originals, folder)
    for key, items in result.items():
        figures[key] += len(items)
        findings += [f"trial {trial} {key}: {v}" for v in items[:3]]


def poison_loop(root: Path, kills: int, seed: int, per_kill: int, video_every: int,
                window: tuple[float, float] = (0.0, 1.2)) -> dict[str, object]:  # fmt: skip
    """Each trial adds `per_kill` photos (and a 1 s video every `video_every`-th trial) to one
    folder, starts `ppd poison FOLDER`, SIGKILLs its process group at a uniform random instant in
    `window` x the median run of a whole trial (every 10th trial runs uncut to measure it) until
    `kills` runs were killed, checks no original was lost, then runs `ppd poison` again
    to completion and audits the folder."""
    rng = random.Random(seed)
    folder = root / "photos" / "trip"
    originals: dict[Path, str] = {}
    full_runs: list[float] = []  # runs of a whole trial's files, never killed (every 10th trial)
    figures: Counter[str] = Counter()
    findings: list[str] = []
    started = time.monotonic()
    trial = -1
    while figures["kills"] < kills and trial < 3 * kills:
        trial += 1
        names = _add_trial_files(root, rng, trial, per_kill, video_every, originals, figures)
        t0 = time.monotonic()
        proc = _ppd(root, "poison", str(folder))
        if trial % 10 == 0:  # calibrate: the time a whole trial's run takes now, on this machine
            proc.wait(300)
            full_runs.append(time.monotonic() - t0)
            continue
        _kill_at_random(proc, rng, window, full_runs, figures)
        _count_kill_state(root, folder, names, originals, figures)
        _recover_and_audit(root, folder, trial, originals, figures, findings)
        if trial % 10 == 9:
            print(f"poison loop: {trial + 1} trials, {dict(figures)}, {time.monotonic() - started:.0f} s",
                  flush=True)  # fmt: skip
    return {"scenario": "poison", "trials": trial + 1, "files": len(originals), **figures,
            "median_whole_trial_run_s": round(statistics.median(full_runs), 2),
            "seconds": round(time.monotonic() - started), "findings": findings[:20]}  # fmt: skip


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
    from tests import hostile_images

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


# ---- two daemons + a CLI; store deleted -----------------------------------------------------------
def concurrency_round(root: Path, files: int, seed: int) -> dict[str, int]:
    paths = app_paths(root)
    stage = root / "stage"
    sources = [write_photo(stage / f"{seed}-{i:02d}.jpg", seed * 1000 + i) for i in range(files)]
    originals = {paths.outbox / "ds" / s.name: sha256(s) for s in sources}
    (paths.outbox / "ds").mkdir(parents=True, exist_ok=True)
    first = start_daemon(root, *DAEMON_ARGS)
    out: Counter[str] = Counter()
    try:
        second = _ppd(root, "watch", *DAEMON_ARGS)
        for src, dst in zip(sources, originals, strict=True):
            os.rename(src, dst)
        cli = _ppd(root, "poison", str(paths.outbox / "ds"))
        out["second daemon refused"] += second.wait(120) != 0
        out["cli exit non-zero"] += cli.wait(300) != 0
        store = Store(paths.db_path)
        with contextlib.suppress(AssertionError):  # the audit below says what is not patched
            wait_for(lambda: all(r["state"] == FileState.PATCHED for r in store.files("ds"))
                     and len(store.files("ds")) >= len(originals), 120, "all patched")  # fmt: skip
        store.close()
        time.sleep(1.0)
    finally:
        out["first daemon exit non-zero"] += kill_daemon(first, signal.SIGTERM) != 0
    result = audit(root, originals, paths.outbox)
    out["files"] = len(originals)
    out["stranded rows"] = len(result["not_patched"])
    out["double poisoned"] = len(result["double"])
    out["not restorable"] = len(result["not_restorable"])
    out["invariant violations"] = len(result["invariants"])
    out["leftovers"] = len(result["leftovers"])
    return out


def store_deleted_round(root: Path, files: int, seed: int) -> dict[str, int]:
    """Protect a folder with `ppd poison`, delete the store (db, WAL, SHM), run `ppd poison` again,
    then `ppd restore`: every file must come back to its original bytes."""
    paths = app_paths(root)
    folder = root / "photos" / f"set{seed}"
    originals = {}
    for i in range(files):
        name = f"{i:02d}{'.jpg' if i % 2 else '.png'}"
        originals[folder / name] = sha256(write_photo(folder / name, seed * 1000 + i))
    out: Counter[str] = Counter()
    out["files"] = files
    out["first run exit non-zero"] += _ppd(root, "poison", str(folder)).wait(300) != 0
    patched = {p: sha256(p) for p in originals}
    for suffix in ("", "-wal", "-shm"):
        Path(str(paths.db_path) + suffix).unlink(missing_ok=True)
    out["second run exit non-zero"] += _ppd(root, "poison", str(folder)).wait(300) != 0
    out["poisoned twice (bytes changed by the second run)"] = sum(sha256(p) != patched[p] for p in originals)
    out["originals not in the vault"] = sum(not vault_has(root, o) for o in originals.values())
    out["restore exit non-zero"] += _ppd(root, "restore", folder.name).wait(300) != 0
    out["not restored to the original bytes"] = sum(
        not p.is_file() or sha256(p) != o for p, o in originals.items())
    out["leftovers"] = len(leftovers(folder))
    return out


def rounds(fn, root: Path, count: int, files: int, name: str) -> dict[str, object]:  # noqa: ANN001
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
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--inputs", type=Path, nargs="*", default=[], help="render: JSON files to tabulate")
    args = parser.parse_args(argv)
    if args.scenario == "render":
        from tests.reliability_harness import write_results_section

        write_results_section("kill-loops", render([json.loads(p.read_text()) for p in args.inputs]))
        return
    root = Path(tempfile.mkdtemp(prefix=f"ppd-bench-{args.scenario}-"))
    try:
        if args.scenario == "poison":
            window = tuple(float(x) for x in args.window.split(","))
            result = poison_loop(root, args.kills, args.seed, args.per_kill, args.video_every, window)
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
