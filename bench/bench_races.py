"""Races against protect_file at random instants (issue 20, rows 1 and 3):

- symlink swaps: a dataset's sub-folder swapped for a symlink to a private folder, or the file
  itself swapped for a symlink to a private file, at a uniformly random instant during
  protection. A violation: any change under the private folder (a write outside the outbox), a
  symlink in the vault, a `.ppd-tmp-*` file left anywhere.
- replace during protect: a new version renamed over the file at a random instant. A violation:
  a version lost (neither at the path nor kept in the vault as an original), a temporary left.

    python -m bench.bench_races [--trials 120] [--videos 24]

Writes the `races` section of bench/results/reliability.md. The scenarios are testkit/races.py's (the
tests run them small).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

from testkit.races import RaceResult, run_replace_races, run_symlink_races
from testkit.reliability import write_results_section


def _markdown(results: list[RaceResult], command: str) -> str:
    lines = [
        "## Races (bench/bench_races.py)",
        "",
        f"Command: `{command}`. Each trial starts protect_file on a fresh file and acts once at a",
        "uniformly random instant in [0, window] (window = 1.3 x the median protect time here).",
        "",
        "| scenario | trials | window | violations | outcomes |",
        "|---|---|---|---|---|",
    ]
    for r in results:
        outcomes = ", ".join(f"{k} {v}" for k, v in sorted(r.outcomes.items()))
        lines.append(
            f"| {r.scenario} | {r.trials} | {r.window_s * 1000:.0f} ms | {len(r.violations)} | {outcomes} |"
        )
    for r in results:
        lines += [f"- {r.scenario}: {v}" for v in r.violations[:10]]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=120)
    parser.add_argument("--videos", type=int, default=24, help="symlink-swap trials on MP4s (0: none)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="ppd-races-"))
    try:
        results = [
            run_symlink_races(work / "symlink", args.trials, args.seed),
            run_replace_races(work / "replace", args.trials, args.seed),
        ]
        if args.videos:
            results.append(run_symlink_races(work / "video", args.videos, args.seed, ".mp4"))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    command = f"python -m bench.bench_races --trials {args.trials} --videos {args.videos} --seed {args.seed}"
    markdown = _markdown(results, command)
    print(markdown)
    write_results_section("races", markdown)


if __name__ == "__main__":
    main()
