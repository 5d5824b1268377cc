"""SIGKILL loops on `ppd poison` (a real CLI process killed at random instants), two daemons plus a
CLI on one outbox, and a deleted store (issues 15, 20): bench/bench_kill_loops.py runs them at
length, tests/reliability/test_reliability_kill_loops.py a few rounds. Each returns its figures as a dict."""

from __future__ import annotations

import contextlib
import os
import random
import signal
import statistics
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import PIL.Image  # before anything that could load pycolmap

from daemon.states import FileState
from daemon.store import Store
from poisoner.atomic import TEMP_PREFIX
from testkit.photos import texture
from testkit.reliability import (
    DAEMON_ARGS,
    app_paths,
    check_invariants,
    kill_daemon,
    make_video,
    protected_counts,
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
                    full_runs: list[float], figures: Counter[str],
                    pid_only: bool = False) -> None:  # fmt: skip
    """SIGKILL the run's process group (a terminal, systemd) or, pid_only, ppd's own pid (`kill -9
    PID`, the OOM killer): then whatever it started must end by itself within 15 s."""
    delay = rng.uniform(*(w * statistics.median(full_runs) for w in window))
    try:
        proc.wait(delay)
        figures["finished before the kill"] += 1
    except subprocess.TimeoutExpired:
        (os.kill if pid_only else os.killpg)(proc.pid, signal.SIGKILL)
        proc.wait()
        figures["kills"] += 1
        if pid_only:
            figures["kills of ppd's pid only"] += 1
            figures["pid-only kills after which its processes ran on"] += not _group_ends(proc.pid, 15.0)


def _group_ends(pgid: int, within_s: float) -> bool:
    """Whether process group pgid has no running process left within within_s (zombies have ended:
    a PID 1 that reaps nobody keeps them); then SIGKILLs what is left."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        if not _running_in_group(pgid):
            return True
        time.sleep(0.05)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(pgid, signal.SIGKILL)
    return False


def running_processes() -> dict[int, tuple[int, int]]:
    """pid -> (parent pid, process group) of every process that has not ended, from /proc
    (zombies left out: a PID 1 that reaps nobody keeps them, ended)."""
    table = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, IndexError):
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                if fields[0] != "Z":
                    table[int(entry.name)] = (int(fields[1]), int(fields[2]))
    return table


def _running_in_group(pgid: int) -> list[int]:
    return [pid for pid, (_, group) in running_processes().items() if group == pgid]


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
                window: tuple[float, float] = (0.0, 1.2),
                pid_only_every: int = 0) -> dict[str, object]:  # fmt: skip
    """Each trial adds `per_kill` photos (and a 1 s video every `video_every`-th trial) to one
    folder, starts `ppd poison FOLDER`, SIGKILLs its process group at a uniform random instant in
    `window` x the median run of a whole trial (every 10th trial runs uncut to measure it) until
    `kills` runs were killed, checks no original was lost, then runs `ppd poison` again
    to completion and audits the folder. pid_only_every N: every Nth trial kills ppd's pid alone."""
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
        pid_only = pid_only_every > 0 and trial % pid_only_every == 0
        _kill_at_random(proc, rng, window, full_runs, figures, pid_only)
        _count_kill_state(root, folder, names, originals, figures)
        _recover_and_audit(root, folder, trial, originals, figures, findings)
        if trial % 10 == 9:
            print(f"poison loop: {trial + 1} trials, {dict(figures)}, {time.monotonic() - started:.0f} s",
                  flush=True)  # fmt: skip
    return {"scenario": "poison", "trials": trial + 1, "files": len(originals), **figures,
            "median_whole_trial_run_s": round(statistics.median(full_runs), 2),
            "seconds": round(time.monotonic() - started), "findings": findings[:20]}  # fmt: skip


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
