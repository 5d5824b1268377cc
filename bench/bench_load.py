"""Load on `ppd watch` as a real process: a flood of files dropped at once, then a soak with a
steady trickle. Every file must be protected exactly once; memory must stay flat; latency
must stay bounded.

    python -m bench.bench_load [--files 10000] [--soak-minutes 30] [--interval 2.0]

Flood: N small PNGs written outside the outbox, then moved in as one folder (one rename).
Latency of a file = its 'patched' event time minus the instant of that rename (so it
includes the queueing behind the files before it). Soak: one file copied in (close-after-
write, the daemon's default 2 s debounce) every `interval` seconds, a 256x256 PNG or JPEG, and
a small MP4 every 50th file; latency = 'patched' event time minus the end of the copy.
RSS of the daemon process sampled every second (flood) or 5 s (soak) from /proc.
Writes the `load` section of bench/results/reliability.md.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sqlite3
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from daemon.states import FileState
from tests.reliability_harness import (
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
    write_results_section,
)


@dataclass(frozen=True)
class FloodOptions:
    files: int = 10_000
    size: int = 48  # px; small files: the flood measures the pipeline, not the codec
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


def render(flood: FloodResult | None, soak: SoakResult | None, command: str) -> str:
    lines = ["## Load (`bench_load`)", "", f"Command: `{command}`", ""]
    if flood is not None:
        lines += [
            f"### Flood: {flood.files} PNGs of {FloodOptions.size} px moved in as one folder",
            "",
            "| figure | value |",
            "|---|---|",
            f"| protected / failed | {flood.protected} / {flood.failed} |",
            f"| protected exactly once | {flood.files - len(flood.not_exactly_once)} of {flood.files} |",
            f"| invariant violations (lost, corrupted, store/disk) | {len(flood.violations)} |",
            f"| drop to last protected | {flood.seconds:.1f} s ({flood.files / flood.seconds:.0f} files/s) |",
            f"| latency from drop (queueing included) | {flood.latency_s} |",
            f"| daemon RSS MB (1 s samples) | {flood.rss_mb} |",
            f"| daemon exit status after SIGTERM | {flood.daemon_exit_code} |",
            "",
        ]  # fmt: skip
    if soak is not None:
        lines += [
            f"### Soak: {soak.minutes:g} min, one file every {soak.interval_s:g} s (copied in)",
            "",
            "| figure | value |",
            "|---|---|",
            f"| files / protected / failed | {soak.files} / {soak.protected} / {soak.failed} |",
            f"| protected exactly once | {soak.files - len(soak.not_exactly_once)} of {soak.files} |",
            f"| invariant violations | {len(soak.violations)} |",
            f"| latency copy-closed to protected (2 s debounce included) | {soak.latency_s} |",
            f"| daemon RSS MB | {soak.rss_mb} |",
            f"| daemon exit status after SIGTERM | {soak.daemon_exit_code} |",
            "",
            "RSS over time (MB, every ~5 min):",
            "",
            " ".join(f"{t / 60:.0f}m:{mb}" for t, mb in soak.rss_series[:: max(1, 300 // 5)]),
            "",
        ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=10_000, help="flood size (0: no flood)")
    parser.add_argument("--soak-minutes", type=float, default=30.0, help="soak length (0: no soak)")
    parser.add_argument("--interval", type=float, default=SoakOptions.interval_s)
    parser.add_argument("--root", type=Path, default=None, help="work folder (default: a new temp dir)")
    parser.add_argument("--json", type=Path, default=None, help="also write the raw results here")
    args = parser.parse_args(argv if argv is not None else [])
    import tempfile

    root = args.root or Path(tempfile.mkdtemp(prefix="ppd-bench-load-"))
    flood = soak = None
    if args.files:
        flood = run_flood(root / "flood", FloodOptions(files=args.files))
        print(json.dumps(asdict(flood), default=str)[:2000], flush=True)
    if args.soak_minutes:
        soak = run_soak(root / "soak", SoakOptions(minutes=args.soak_minutes, interval_s=args.interval))
        summary = {k: v for k, v in asdict(soak).items() if k != "rss_series"}
        print(json.dumps(summary, default=str), flush=True)
    if args.json:
        args.json.write_text(json.dumps({"flood": asdict(flood) if flood else None,
                                         "soak": asdict(soak) if soak else None}, default=str))  # fmt: skip
    command = "python -m bench.bench_load " + " ".join(argv or [])
    write_results_section("load", render(flood, soak, command.strip()))
    shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
