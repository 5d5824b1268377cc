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
Writes the `load` section of bench/results/reliability.md. The scenarios are testkit/load.py's (the
tests run them small).
"""

from __future__ import annotations

import argparse
import json
import shutil
from dataclasses import asdict
from pathlib import Path

from testkit.load import FloodOptions, FloodResult, SoakOptions, SoakResult, run_flood, run_soak
from testkit.reliability import write_results_section


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
