"""Start-up of the `ppd` commands a person runs most (issue 19: ≤ 150 ms CPU for `ppd poison
--help` and `ppd status`), whole process, measured the same way every time.

`python -m bench.bench_startup [--runs 9] [--baseline /work/main]` runs each command in pairs,
alternating: this checkout's ppd and, for the ratio, a floor (the interpreter importing typer,
the least any typer CLI pays) or, with --baseline, the same command from another checkout
(before/after). It prints medians of user+sys CPU, wall time and peak RSS per command, the ratio
within each pair, and the load average before and after (the machine is shared: read the ratios).
Each run gets fresh empty PPD_DATA_DIR/PPD_CONFIG_DIR/PPD_OUTBOX folders, except
`ppd status (1 dataset)`, which reads a store that each side's own `ppd poison` filled once with
one patched 160×120 PNG (status then also reads verdicts, the automatic-mode line, report links).
"""

from __future__ import annotations

import argparse
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

from bench.bytecode import compile_bytecode

REPO = Path(__file__).resolve().parents[1]
COMMANDS = {
    "ppd poison --help": ["-m", "daemon.cli", "poison", "--help"],
    "ppd status": ["-m", "daemon.cli", "status"],
    "ppd --help": ["-m", "daemon.cli", "--help"],
    "ppd watch --help": ["-m", "daemon.cli", "watch", "--help"],
}
FLOOR = ["-c", "import typer"]
WITH_DATASET = "ppd status (1 dataset)"
PYCACHE = str(Path(tempfile.gettempdir()) / "ppd-bench-startup-pycache")


def environment(checkout: Path, folders: Path) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(checkout), COLUMNS="80")
    # as installed: bytecode cached (a warm-up run writes it), not compiled from source each time;
    # kept in a folder of the bench's own, so no checkout gets __pycache__ folders
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = PYCACHE
    for var in ("PPD_DATA_DIR", "PPD_CONFIG_DIR", "PPD_OUTBOX"):
        env[var] = str(folders / var.lower())
    return env


def one_dataset(checkout: Path, folders: Path) -> Path:
    """folders with a store holding one dataset, patched by that checkout's own ppd."""
    shoot = folders / "shoot"
    shoot.mkdir(parents=True)
    # a PNG of noise, written by the standard library (zlib), so the bench needs no numpy here
    width, height = 160, 120
    raw = b"".join(b"\0" + os.urandom(width * 3) for _ in range(height))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw))
    png += chunk(b"IEND", b"")
    (shoot / "a.png").write_bytes(png)
    subprocess.run([sys.executable, "-m", "daemon.cli", "poison", str(shoot)], cwd=checkout,
                   env=environment(checkout, folders), check=True, capture_output=True)  # fmt: skip
    return folders


def run_once(argv: list[str], checkout: Path, folders: Path) -> dict[str, float]:
    """One whole process: user+sys CPU (s), wall (s), peak RSS (MB), from wait4's rusage."""
    env = environment(checkout, folders)
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, *argv], cwd=checkout, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} in {checkout} exited {proc.returncode}")
    return {"cpu": usage.ru_utime + usage.ru_stime, "wall": wall, "rss": usage.ru_maxrss / 1024}


def pair(argv: list[str], other: tuple[list[str], Path], runs: int, filled: tuple[Path, Path] | None = None
         ) -> tuple[list[dict], list[dict]]:  # fmt: skip
    """runs × (this checkout's command, the other side), alternating; fresh folders each time
    unless filled gives each side its folders."""
    mine: list[dict] = []
    theirs: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="ppd-startup-") as tmp:  # warm-up: writes the bytecode
        run_once(argv, REPO, filled[0] if filled else Path(tmp) / "a")
        run_once(other[0], other[1], filled[1] if filled else Path(tmp) / "b")
    for _ in range(runs):
        with tempfile.TemporaryDirectory(prefix="ppd-startup-") as tmp:
            mine.append(run_once(argv, REPO, filled[0] if filled else Path(tmp) / "a"))
            theirs.append(run_once(other[0], other[1], filled[1] if filled else Path(tmp) / "b"))
    return mine, theirs


def median(rows: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=9)
    parser.add_argument("--baseline", type=Path, help="Another checkout to compare with (before/after).")
    args = parser.parse_args(argv)
    compile_bytecode([REPO, *([args.baseline] if args.baseline else [])])  # as an install leaves it
    other_name = f"baseline {args.baseline}" if args.baseline else "floor: python -c 'import typer'"
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {os.cpu_count()} CPUs")
    print(f"| command | CPU ms | wall ms | RSS MB | {other_name}: CPU ms | CPU ratio |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="ppd-startup-filled-") as tmp:
        filled = (one_dataset(REPO, Path(tmp) / "a"), one_dataset(args.baseline or REPO, Path(tmp) / "b"))
        for label, command in [*COMMANDS.items(), (WITH_DATASET, COMMANDS["ppd status"])]:
            other = (command, args.baseline) if args.baseline else (FLOOR, REPO)
            mine, theirs = pair(command, other, args.runs, filled if label == WITH_DATASET else None)
            cpu, other_cpu, wall = median(mine, "cpu"), median(theirs, "cpu"), median(mine, "wall")
            print(f"| `{label}` | {cpu * 1000:.0f} | {wall * 1000:.0f} | {median(mine, 'rss'):.0f} | "
                  f"{other_cpu * 1000:.0f} | {cpu / other_cpu:.2f} |")  # fmt: skip
    print(f"medians of {args.runs} alternating pairs; load average after: "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")  # fmt: skip


if __name__ == "__main__":
    main()
