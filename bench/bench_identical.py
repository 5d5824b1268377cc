"""Issue 25, round 4: the sets whose COLMAP protection was measured stay byte-identical.

`nice -n 19 python -m bench.bench_identical --base DIR` poisons lego (40 views, 800 px, composited
on white), dtu_scan37 at 800x600 and at its own 1600x1200 (25 views each), the default design, no
masks, as `ppd poison` writes them (poisoner.formats.poison_file), once with the code in DIR (a
checkout of main: `git archive main | tar -x -C DIR`) and once with this checkout's, each in its own
process, and compares every output file byte for byte (`cmp`). Exit status 1 when any differs.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import subprocess
import sys
from pathlib import Path

from bench.bench_placement import ROOT

WORK = Path("/tmp") / "ppd-bench-identical"
SETS = ("lego", "dtu", "dtu-full")

# run in a child with PYTHONPATH set to one checkout: bench_watermark.setup makes the clean sets
CHILD = """
import sys
from pathlib import Path
from bench import bench_watermark as bw
from poisoner.formats import poison_file
from poisoner.ladder import default_spec
bw.WORK = Path(sys.argv[1])
out = Path(sys.argv[2])
for name in sys.argv[3].split(","):
    ds = bw.setup(name)
    (out / name).mkdir(parents=True, exist_ok=True)
    for f in sorted(ds.clean.iterdir()):
        poison_file(f, out / name / f.name, default_spec())
"""


def poison_with(checkout: Path, out: Path, sets: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    # the clean sets are made by this checkout's bench code, shared by both sides
    subprocess.run([sys.executable, "-c", CHILD, str(WORK / "clean"), str(out), sets], env=env, check=True,
                   cwd=checkout)  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="a checkout of main")
    ap.add_argument("--sets", default=",".join(SETS))
    args = ap.parse_args(argv)
    base_out, ours_out = WORK / "main", WORK / "ours"
    if not base_out.exists():  # main's outputs do not change: made once
        poison_with(args.base.resolve(), base_out, args.sets)
    poison_with(ROOT, ours_out, args.sets)
    bad = 0
    for name in args.sets.split(","):
        files = sorted(p.name for p in (base_out / name).iterdir())
        same = [filecmp.cmp(base_out / name / n, ours_out / name / n, shallow=False) for n in files]
        differ = [n for n, s in zip(files, same, strict=True) if not s]
        bad += len(differ)
        print(f"{name}: {len(files) - len(differ)} of {len(files)} files byte-identical to main's"
              + (f"; differ: {', '.join(differ)}" if differ else ""))  # fmt: skip
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
