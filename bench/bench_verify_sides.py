"""A profile's clean and poisoned SfM side by side against one after the other (issue 30).

`nice python -m bench.bench_verify_sides [--set lego] [--views 12] [--profile default] [--rounds 3]`
times the whole command `ppd verify POISONED --clean CLEAN --profile P` as a first verification (empty
data and cache folders each run), PPD_VERIFY_SIDES=1 and =2 in turn (1 2 1 2 ...), on this machine,
and writes bench/results/verify_sides.md: wall seconds per run, the median of each and the median of
the pair-by-pair ratios (2 / 1), and each run's verdict and cameras within 5 degrees. The sets are
bench_verify_speed's (lego: NeRF-Synthetic's first views on white, ppd's default mark).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS_MD = Path(os.environ.get("PPD_BENCH_RESULTS") or ROOT / "bench" / "results") / "verify_sides.md"


def one_run(clean: Path, poisoned: Path, profile: str, sides: str, timeout_s: float) -> dict[str, Any]:
    """One first verification in fresh folders (bench_verify_speed's whole command), timed."""
    from bench.bench_verify_speed import verify_command

    os.environ["PPD_VERIFY_SIDES"] = sides  # the command inherits it
    with tempfile.TemporaryDirectory(prefix="ppd-bench-sides-") as tmp:
        row = verify_command(ROOT, clean, poisoned, Path(tmp) / "out", Path(tmp), timeout_s, profile)
    p = (row.get("profiles") or {}).get(profile, {})
    return {"sides": sides, "wall_s": row["wall_s"], "verdict": p.get("verdict", row.get("error", "-")),
            "frac_within_5deg": p.get("frac_within_5deg"), "load": row["load_after"]}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="lego", choices=("lego", "synthetic"))
    ap.add_argument("--views", type=int, default=12)
    ap.add_argument("--width", type=int, default=800, help="synthetic: image width")
    ap.add_argument("--profile", default="default")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--timeout", type=float, default=1800.0)
    args = ap.parse_args(argv if argv is not None else [])  # `python -m bench` runs it with defaults
    from bench.bench_verify_speed import make_sets

    clean, poisoned = make_sets(args.set, args.views, args.width)
    runs = []
    for _ in range(args.rounds):
        for sides in ("1", "2"):
            runs.append(one_run(clean, poisoned, args.profile, sides, args.timeout))
            print(json.dumps(runs[-1]), flush=True)
    by = {s: [r["wall_s"] for r in runs if r["sides"] == s] for s in ("1", "2")}
    ratios = [b / a for a, b in zip(by["1"], by["2"], strict=True)]
    lines = [
        "# A profile's clean and poisoned SfM side by side (PPD_VERIFY_SIDES=2) vs one after the other (=1)",
        "",
        f"Written by `bench/bench_verify_sides.py`: `ppd verify --profile {args.profile}`, first",
        f"verification (empty folders each run), {args.set} {args.views} views, {os.cpu_count()} cores,",
        f"{args.rounds} rounds alternating 1 2 1 2; {time.strftime('%Y-%m-%d %H:%M')}.",
        "",
        f"- one after the other: median {statistics.median(by['1']):.0f} s",
        f"- side by side: median {statistics.median(by['2']):.0f} s",
        f"- side by side / one after the other, pair by pair: median **{statistics.median(ratios):.2f}x**"
        f" (min {min(ratios):.2f}, max {max(ratios):.2f})",
        "",
        "| run | sides | wall | verdict | within 5 deg | load (1 min, after) |",
        "|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(runs, 1):
        frac = r.get("frac_within_5deg")
        shown = "-" if frac is None else f"{100 * frac:.0f}%"
        load = r.get("load", 0.0)
        lines.append(f"| {i} | {r['sides']} | {r['wall_s']:.0f} s | {r['verdict']} | {shown} | {load:.1f} |")
    RESULTS_MD.parent.mkdir(parents=True, exist_ok=True)
    RESULTS_MD.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv[1:])
