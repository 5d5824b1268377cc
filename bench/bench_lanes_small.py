"""The default mark under ~730 px wide, two code trees side by side (black-box review 9, F8).

Below ~730 px each lane's slide rounds to one lattice unit a photo, so both squares move as one block
(one translation: what COLMAP's watermark test removes). A fix (lane k moves at least k + 1 units) was
merged and reverted when the poisoned COLMAP run of a small set took minutes. This measures both: each
tree's own `ppd poison` (its default spec) and `ppd verify -p default -p hardened --seeds 3 --json`
on the same photos, per set and width, protection per COLMAP seed and the wall time.

    python -m bench.bench_lanes_small --tree /work/main --tree /tmp/fix --set dtu:25 --set lego:40 \
        --width 640 --width 480 [--parallel 2]

A tree is a checkout whose poisoner/*.so are built (run with PYTHONPATH=TREE and this interpreter).
Sets: `dtu` (dtu_scan37's views), `lego` (its train views on white) or `fill` (testkit.fill_set: a box
with fountain-P11 faces filling 2/3 of the frame, textured wall and floor), the first N, scaled to the
width (Lanczos), JPEG q92; no masks given.
Rows: bench/results/lanes_small.json; the page, lanes_small.md, by hand.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from verifier.shared_data import shared_root

HERE = Path(__file__).resolve().parent
SOURCES = {"dtu": ("dtu_scan37", "images"), "lego": ("nerf_synthetic_lego", "train")}
FILL = Path(tempfile.gettempdir()) / "ppd-lanes-small-fill"  # testkit.fill_set's capture, made once
ROWS = HERE / "results" / "lanes_small.json"


def make_set(name: str, count: int, width: int, out: Path) -> None:
    """The first `count` views of a shared set at `width` px, JPEG q92 (lego composited on white)."""
    out.mkdir(parents=True)
    if name == "fill":
        from testkit.fill_set import make_fill_set

        source = make_fill_set(FILL)[0]  # made once, the same bytes every time
    else:
        source = shared_root().joinpath(*SOURCES[name])  # $PPD_SHARED_DATA: bench/__init__.py sets it
    files = sorted(source.glob("*.png"), key=lambda p: int("".join(c for c in p.stem if c.isdigit())))
    for path in files[:count]:
        im = Image.open(path)
        if im.mode == "RGBA":
            white = Image.new("RGB", im.size, "white")
            white.paste(im, mask=im.split()[3])
            im = white
        height = round(im.height * width / im.width)
        im.convert("RGB").resize((width, height), Image.Resampling.LANCZOS).save(
            out / f"{path.stem}.jpg", quality=92
        )


def run_one(tree: Path, name: str, count: int, width: int, work: Path, timeout: float) -> dict[str, Any]:
    """One tree's poison and verification of one set; its row."""
    home = work / f"{tree.name}-{name}{count}-{width}"
    shutil.rmtree(home, ignore_errors=True)
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}
    for folder, var in (("data", "PPD_DATA_DIR"), ("config", "PPD_CONFIG_DIR"), ("outbox", "PPD_OUTBOX")):
        (home / folder).mkdir(parents=True, exist_ok=True)
        env[var] = str(home / folder)
    make_set(name, count, width, home / "clean")
    shutil.copytree(home / "clean", home / "outbox" / "set")  # the copy ppd patches in place
    ppd = [sys.executable, "-m", "daemon.cli"]
    subprocess.run([*ppd, "poison", str(home / "outbox" / "set")], env=env, cwd=tree, check=True,
                   capture_output=True)  # fmt: skip
    in_band = mark_in_border_band(home / "clean", home / "outbox" / "set")
    started = time.monotonic()
    row: dict[str, Any] = {
        "tree": str(tree),
        "set": f"{name}{count}",
        "width": width,
        "mark_in_band": in_band,
    }
    # SIGTERM at the limit: ppd's verify ends its COLMAP children as at Ctrl-C (TermAsInterrupt)
    limit = ["timeout", "-s", "TERM", "-k", "60", str(int(timeout))]
    verify = [*ppd, "verify", "set", "-p", "default", "-p", "hardened", "--seeds", "3", "--json"]
    done = subprocess.run([*limit, *verify], env=env, cwd=tree, capture_output=True, text=True)
    if done.returncode in (124, 137):
        return {**row, "wall_s": round(time.monotonic() - started), "outcome": f"stopped at {timeout:.0f} s"}
    report = json.loads(done.stdout) if done.stdout.strip() else {}
    return {**row, **report_row(report), "wall_s": round(time.monotonic() - started)}


def mark_in_border_band(clean: Path, poisoned: Path) -> list[float]:
    """Per photo, the share of the mark's pixels (changed by more than 24 levels) that lie in the border
    band COLMAP's watermark test reads (`ignore_watermarks`: 10% of the diagonal from every edge)."""
    shares = []
    for path in sorted(clean.glob("*.jpg")):
        a = np.asarray(Image.open(path).convert("RGB"), dtype=np.int16)
        b = np.asarray(Image.open(poisoned / path.name).convert("RGB"), dtype=np.int16)
        changed = np.abs(a - b).max(axis=2) > 24
        h, w = changed.shape
        band = int(0.1 * np.hypot(w, h))
        inner = changed[band : h - band, band : w - band].sum() if h > 2 * band and w > 2 * band else 0
        total = int(changed.sum())
        shares.append(round(float(1 - inner / total), 2) if total else 0.0)
    return shares


def report_row(report: dict[str, Any]) -> dict[str, Any]:
    """Per profile of a `ppd verify --json` report: verdict, clean cameras, each seed's (share within
    5 deg, poisoned cameras registered, outcome) and the first seed's mapping time."""
    row = {}
    for profile, p in report.get("profiles", {}).items():
        poisoned = p.get("poisoned") or {}
        row[profile] = {
            "verdict": p["verdict"],
            "clean_registered": (p.get("clean") or {}).get("registered"),
            "seeds": [
                (s["seed"], s.get("frac_within"), s.get("registered"), s["outcome"])
                for s in p.get("seeds") or []
            ],
            "mapping_s": round((poisoned.get("timings") or {}).get("mapping_s", 0)),
        }
    return row


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", action="append", type=Path, default=None)
    parser.add_argument("--set", action="append", default=None, help="NAME:COUNT (dtu, lego or fill)")
    parser.add_argument("--width", action="append", type=int, default=None)
    parser.add_argument("--parallel", type=int, default=2)
    parser.add_argument("--timeout", type=float, default=900.0)
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "ppd-lanes-small")
    args = parser.parse_args(argv if argv is not None else sys.argv[1:] if __name__ == "__main__" else [])
    trees = args.tree or [HERE.parent]
    sets = [(s.split(":")[0], int(s.split(":")[1])) for s in args.set or ["dtu:25"]]
    jobs = [(t, n, c, w) for n, c in sets for w in args.width or [640] for t in trees]
    if any(name == "fill" for name, _ in sets):  # made before the jobs share it
        from testkit.fill_set import make_fill_set

        make_fill_set(FILL)
    with ThreadPoolExecutor(args.parallel) as pool:
        rows = list(pool.map(lambda j: run_one(*j, args.work, args.timeout), jobs))
    old = json.loads(ROWS.read_text()) if ROWS.exists() else []
    ROWS.write_text(json.dumps(old + rows, indent=1) + "\n")
    for row in rows:
        print(json.dumps(row))


if __name__ == "__main__":
    main()
