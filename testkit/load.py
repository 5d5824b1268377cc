"""The load scenarios on `ppd watch` as a real process (bench/bench_load.py times them at full size,
tests/reliability/test_reliability_crash.py runs a small flood): a flood of files moved in at once, and a
soak with a steady trickle. Every file must be protected exactly once; RSS is sampled from /proc."""

from __future__ import annotations

import os
import shutil
import signal
import sqlite3
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from daemon.states import FileState
from testkit.reliability import (
    DAEMON_ARGS,
    app_paths,
    check_invariants,
    kill_daemon,
    make_media,
    percentile,
    protected_counts,
    sha256,
    start_daemon,
    status_kb,
    write_image,
)


@dataclass(frozen=True)
class FloodOptions:
    files: int = 10_000
    size: int = 128  # px; small files (the smallest the mark fits): the flood measures the pipeline
    timeout_s: float = 3600.0


@dataclass
class FloodResult:
    files: int
    protected: int = 0
    failed: int = 0
    seconds: float = 0.0
    latency_s: dict[str, float] = field(default_factory=dict)
    rss_mb: dict[str, float] = field(default_factory=dict)
    not_exactly_once: list[str] = field(default_factory=list)
    violations: list[str] = field(default_factory=list)
    daemon_exit_code: int | None = None


@dataclass(frozen=True)
class SoakOptions:
    minutes: float = 30.0
    interval_s: float = 2.0
    video_every: int = 50
    sample_every_s: float = 5.0


@dataclass
class SoakResult:
    minutes: float
    interval_s: float
    files: int = 0
    protected: int = 0
    failed: int = 0
    latency_s: dict[str, float] = field(default_factory=dict)
    rss_mb: dict[str, float] = field(default_factory=dict)
    rss_series: list[tuple[float, float]] = field(default_factory=list)  # (seconds, MB)
    not_exactly_once: list[str] = field(default_factory=list)
    violations: list[str] = field(default_factory=list)
    daemon_exit_code: int | None = None


class RssSampler:
    """RSS of one process every `every` seconds, in a thread."""

    def __init__(self, pid: int, every: float) -> None:
        self.pid, self.every = pid, every
        self.samples: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._started = time.monotonic()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                mb = status_kb(self.pid, "VmRSS") / 1024
            except (FileNotFoundError, ProcessLookupError, KeyError):
                return
            self.samples.append((time.monotonic() - self._started, mb))
            self._stop.wait(self.every)


def _state_counts(db_path: Path) -> dict[str, int]:
    with sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=30) as conn:
        return dict(conn.execute("SELECT state, COUNT(*) FROM files GROUP BY state").fetchall())


def _protected_times(db_path: Path) -> dict[str, float]:
    """Per path: the time of its 'protected' (or 'recovered') event."""
    with sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=30) as conn:
        rows = conn.execute("SELECT path, ts FROM events WHERE kind IN ('patched', 'recovered')").fetchall()
    return dict(rows)


def _wait_done(db_path: Path, total: int, timeout: float) -> dict[str, int]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        counts = _state_counts(db_path) if db_path.exists() else {}
        if counts.get(FileState.PATCHED, 0) + counts.get("failed", 0) >= total:
            return counts
        time.sleep(0.5)
    raise TimeoutError(f"not all {total} files done within {timeout} s: {counts}")


def _latency_summary(latencies: list[float]) -> dict[str, float]:
    if not latencies:
        return {}
    summary = {f"p{q}": round(percentile(latencies, q), 3) for q in (50, 95, 99)}
    return summary | {"max": round(max(latencies), 3), "n": len(latencies)}


def _rss_summary(samples: list[tuple[float, float]]) -> dict[str, float]:
    if not samples:
        return {}
    values = [mb for _, mb in samples]
    return {"start": round(values[0], 1), "peak": round(max(values), 1), "end": round(values[-1], 1)}


def run_flood(root: Path, options: FloodOptions) -> FloodResult:
    paths = app_paths(root)
    stage = root / "stage" / "flood"
    originals = {}
    for i in range(options.files):
        src = write_image(stage / f"f{i:05d}.png", seed=i, size=options.size)
        originals[paths.outbox / "flood" / src.name] = sha256(src)
    result = FloodResult(files=options.files)
    daemon = start_daemon(root, *DAEMON_ARGS)
    try:
        with RssSampler(daemon.pid, 1.0) as rss:
            dropped = time.time()
            os.rename(stage, paths.outbox / "flood")  # 10k files arrive in one instant
            counts = _wait_done(paths.db_path, options.files, options.timeout_s)
            result.seconds = time.time() - dropped
    finally:
        result.daemon_exit_code = kill_daemon(daemon, signal.SIGTERM)
    result.protected, result.failed = counts.get(FileState.PATCHED, 0), counts.get("failed", 0)
    times = _protected_times(paths.db_path)
    result.latency_s = _latency_summary([times[str(p)] - dropped for p in originals if str(p) in times])
    result.rss_mb = _rss_summary(rss.samples)
    exact = protected_counts(paths)
    result.not_exactly_once = [p.name for p in originals if exact[str(p)] != 1]
    result.violations = check_invariants(paths, originals)
    return result


def run_soak(root: Path, options: SoakOptions, progress: bool = True) -> SoakResult:
    paths = app_paths(root)
    root.mkdir(parents=True, exist_ok=True)
    result = SoakResult(minutes=options.minutes, interval_s=options.interval_s)
    originals: dict[Path, str] = {}
    dropped_at: dict[str, float] = {}
    stage = root / "stage" / "soak"
    daemon = start_daemon(root, "--no-verify", "-j", "2")  # the default 2 s debounce: real writers
    end = time.monotonic() + options.minutes * 60
    try:
        with RssSampler(daemon.pid, options.sample_every_s) as rss:
            i = 0
            while time.monotonic() < end:
                tick = time.monotonic()
                video = options.video_every and i % options.video_every == options.video_every - 1
                name = f"s{i:05d}" + (".mp4" if video else (".png", ".jpg")[i % 2])
                src = make_media(stage / name, seed=10_000 + i, size=256)
                dst = paths.outbox / f"soak{i // 200}" / name
                dst.parent.mkdir(parents=True, exist_ok=True)
                originals[dst] = sha256(src)
                shutil.copyfile(src, dst)  # open, write, close: IN_CLOSE_WRITE
                dropped_at[str(dst)] = time.time()
                src.unlink()
                i += 1
                if progress and i % 60 == 0:
                    mb = rss.samples[-1][1] if rss.samples else float("nan")
                    print(f"soak: {i} files, {(end - time.monotonic()) / 60:.1f} min left, rss {mb:.1f} MB",
                          flush=True)  # fmt: skip
                time.sleep(max(0.0, options.interval_s - (time.monotonic() - tick)))
            counts = _wait_done(paths.db_path, len(originals), 600)
    finally:
        result.daemon_exit_code = kill_daemon(daemon, signal.SIGTERM)
    result.files = len(originals)
    result.protected, result.failed = counts.get(FileState.PATCHED, 0), counts.get("failed", 0)
    times = _protected_times(paths.db_path)
    result.latency_s = _latency_summary([times[p] - t for p, t in dropped_at.items() if p in times])
    result.rss_series = [(round(t, 1), round(mb, 1)) for t, mb in rss.samples]
    result.rss_mb = _rss_summary(rss.samples)
    window = max(1, len(rss.samples) // 6)  # first and last sixth (5 min of a 30 min soak)
    result.rss_mb["mean_first_sixth"] = round(sum(mb for _, mb in rss.samples[:window]) / window, 1)
    result.rss_mb["mean_last_sixth"] = round(sum(mb for _, mb in rss.samples[-window:]) / window, 1)
    exact = protected_counts(paths)
    result.not_exactly_once = [p.name for p in originals if exact[str(p)] != 1]
    result.violations = check_invariants(paths, originals)
    return result
