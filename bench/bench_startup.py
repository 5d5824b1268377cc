"""Start-up of the `ppd` commands a person runs most (issue 19: ≤ 150 ms CPU for `ppd poison
--help` and `ppd status`), whole process, measured the same way every time.

`python -m bench.bench_startup [--runs 9] [--baseline /work/main]` runs each command in pairs,
alternating: this checkout's ppd and, for the ratio, a floor (the interpreter importing typer,
the least any typer CLI pays) or, with --baseline, the same command from another checkout
(before/after). It prints medians of user+sys CPU, wall time and peak RSS per command, the ratio
within each pair, and the load average before and after (the machine is shared: read the ratios).
Each run gets fresh empty PPD_DATA_DIR/PPD_CONFIG_DIR/PPD_OUTBOX folders.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COMMANDS = {
    "ppd poison --help": ["-m", "daemon.cli", "poison", "--help"],
    "ppd status": ["-m", "daemon.cli", "status"],
    "ppd --help": ["-m", "daemon.cli", "--help"],
    "ppd watch --help": ["-m", "daemon.cli", "watch", "--help"],
}
FLOOR = ["-c", "import typer"]


def run_once(argv: list[str], checkout: Path, folders: Path) -> dict[str, float]:
    """One whole process: user+sys CPU (s), wall (s), peak RSS (MB), from wait4's rusage."""
    env = dict(os.environ, PYTHONPATH=str(checkout), COLUMNS="80")
    for var in ("PPD_DATA_DIR", "PPD_CONFIG_DIR", "PPD_OUTBOX"):
        env[var] = str(folders / var.lower())
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, *argv], cwd=checkout, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} in {checkout} exited {proc.returncode}")
    return {"cpu": usage.ru_utime + usage.ru_stime, "wall": wall, "rss": usage.ru_maxrss / 1024}


def pair(argv: list[str], other: tuple[list[str], Path], runs: int) -> tuple[list[dict], list[dict]]:
    """runs × (this checkout's command, the other side), alternating, fresh folders each time."""
    mine: list[dict] = []
    theirs: list[dict] = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory(prefix="ppd-startup-") as tmp:
            mine.append(run_once(argv, REPO, Path(tmp) / "a"))
            theirs.append(run_once(other[0], other[1], Path(tmp) / "b"))
    return mine, theirs


def median(rows: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=9)
    parser.add_argument("--baseline", type=Path, help="Another checkout to compare with (before/after).")
    args = parser.parse_args(argv)
    other_name = f"baseline {args.baseline}" if args.baseline else "floor: python -c 'import typer'"
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {os.cpu_count()} CPUs")
    print(f"| command | CPU ms | wall ms | RSS MB | {other_name}: CPU ms | CPU ratio |")
    print("|---|---|---|---|---|---|")
    for label, command in COMMANDS.items():
        other = (command, args.baseline) if args.baseline else (FLOOR, REPO)
        mine, theirs = pair(command, other, args.runs)
        cpu, cpu_other = median(mine, "cpu"), median(theirs, "cpu")
        print(f"| `{label}` | {cpu * 1000:.0f} | {median(mine, 'wall') * 1000:.0f} | "
              f"{median(mine, 'rss'):.0f} | {cpu_other * 1000:.0f} | {cpu / cpu_other:.2f} |")  # fmt: skip
    print(f"medians of {args.runs} alternating pairs; load average after: "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")  # fmt: skip


if __name__ == "__main__":
    main()
