"""Issue 25's visibility at 1920 px: every (original, protected) pair of a set judged shown 1920 px
wide (a full-HD screen; smaller photos are enlarged to it, as that screen would), FLIP p99.9, the
share of the screen above FLIP 0.5, the changed share of the pixels, and the JPEG q85 budget.

`nice python -m bench.bench_flip_1920 NAME CLEAN_DIR PROTECTED_DIR [NAME CLEAN_DIR PROTECTED_DIR ...]`
(the folders hold the same file names; bench_placement's `colmap` part writes such pairs under its
work folder's `sfm/<set>/clean` and `sfm/<set>/per-photo-*/images`). Worst and median over the
pairs; results: bench/results/placement_flip_1920.md.
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from verifier.visibility import visibility_report

RESULTS = Path(__file__).resolve().parent / "results" / "placement_flip_1920.md"
WIDTH = 1920


def rgb(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def measure(name: str, clean: Path, protected: Path) -> str:
    rows = []
    for original in sorted(clean.iterdir()):
        other = protected / original.name
        if other.is_file():
            rows.append(visibility_report(rgb(original), rgb(other), display_width=WIDTH))
    if not rows:
        raise SystemExit(f"no pairs: {clean} vs {protected}")
    p999 = [r.flip_p999 for r in rows]
    area = [r.area_above_half for r in rows]
    changed = [r.changed_area for r in rows]
    budget = [r.p999_vs_jpeg for r in rows if r.p999_vs_jpeg is not None]
    size = rgb(next(iter(sorted(clean.iterdir())))).shape
    return (f"| {name} | {size[1]}x{size[0]} | {len(rows)} | {max(p999):.2f} ({statistics.median(p999):.2f}) "
            f"| {100 * max(area):.2f}% ({100 * statistics.median(area):.2f}%) | {100 * max(changed):.2f}% "
            f"| {max(budget):.2f} |")  # fmt: skip


def main(argv: list[str]) -> None:
    if not argv or len(argv) % 3:
        raise SystemExit(__doc__.splitlines()[3] if __doc__ else "usage: NAME CLEAN PROTECTED ...")
    lines = [
        "# Visibility of the per-photo default at 1920 px (issue 25)",
        "",
        "Written by `bench/bench_flip_1920.py`: every pair shown 1920 px wide; worst (median) over the",
        "pairs.",
        "",
        "| set | stored size | pairs | FLIP p99.9 | FLIP > 0.5 area | changed area max "
        "| p99.9 / JPEG q85 max |",
        "|---|---|---|---|---|---|---|",
    ]
    for i in range(0, len(argv), 3):
        lines.append(measure(argv[i], Path(argv[i + 1]), Path(argv[i + 2])))
        print(lines[-1], flush=True)
    RESULTS.write_text("\n".join(lines) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main(sys.argv[1:])
