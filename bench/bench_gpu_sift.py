"""SIFT extraction and raw matching on the GPU against the CPU, on one folder, one machine (issue 30).

`python -m bench.bench_gpu_sift [FOLDER] [--out FILE]` (no folder: 6 synthetic views of 1200 x 800) runs
verifier.sfm's own features-only job (the one `ppd verify` shares between profiles: SIFT at COLMAP's
3200 px, exhaustive raw matching) twice in child processes, PPD_SFM_DEVICE=auto (the GPU when
this pycolmap is a CUDA build and a device is present) and then cpu, each into a fresh database, and reports
wall seconds, features and raw matches per side. A child that crashes is reported as a crash. Needs the
`[gpu]` extra (pycolmap-cuda12) and a CUDA device for the GPU side; without them the second run is the
CPU again and says so.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sqlite3
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def counts(db: Path) -> dict[str, int]:
    """Keypoints and raw matches in a COLMAP database."""
    with sqlite3.connect(db) as con:
        keypoints = con.execute("SELECT COALESCE(SUM(rows), 0) FROM keypoints").fetchone()[0]
        matches = con.execute("SELECT COALESCE(SUM(rows), 0) FROM matches").fetchone()[0]
        images = con.execute("SELECT COUNT(*) FROM images").fetchone()[0]
    return {"images": int(images), "keypoints": int(keypoints), "raw_matches": int(matches)}


def features_run(folder: Path, work: Path, device: str, timeout_s: float) -> dict[str, Any]:
    """One features-only child (fresh database) with PPD_SFM_DEVICE=device, timed whole."""
    from verifier.sfm import SfmJob, run_sfm_job

    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    os.environ["PPD_SFM_DEVICE"] = device  # the child inherits it
    t0 = time.monotonic()
    result = run_sfm_job(
        SfmJob(str(folder), str(work / "cache.db"), str(work / "model"), stop_after="features"),
        timeout_s=timeout_s,
    )
    wall = round(time.monotonic() - t0, 1)
    row: dict[str, Any] = {"device": device, "wall_s": wall, "outcome": result.get("outcome"),
                           "timings": result.get("timings", {})}  # fmt: skip
    if (work / "cache.db").exists():
        row.update(counts(work / "cache.db"))
    return row


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, nargs="?", help="photos (default: 6 synthetic views rendered here)")
    ap.add_argument("--out", type=Path, help="also write the rows here as JSON")
    ap.add_argument("--timeout", type=float, default=600.0)
    args = ap.parse_args(argv if argv is not None else [])  # `python -m bench` runs it with defaults
    import pycolmap

    from verifier.sift_device import cuda_device_count, sift_device

    env = {"pycolmap": pycolmap.__version__, "has_cuda": bool(getattr(pycolmap, "has_cuda", False)),
           "cuda_devices": cuda_device_count(), "sift_device_auto": str(sift_device()),
           "cores": os.cpu_count()}  # fmt: skip
    print(json.dumps(env), flush=True)
    work = Path(tempfile.mkdtemp(prefix="ppd-gpu-sift-"))
    if args.folder is None:
        from verifier.synthetic import SyntheticOptions, render_scene

        args.folder = work / "synthetic"
        render_scene(args.folder, SyntheticOptions(num_views=6, width=1200, height=800, focal=1440))
    rows = [env]
    for device in ("auto", "cpu"):  # the GPU first: the CPU side is the slow one, stopped first
        row = features_run(args.folder, work / device, device, args.timeout)
        print(json.dumps(row), flush=True)
        rows.append(row)
        if args.out:
            args.out.write_text(json.dumps(rows, indent=1) + "\n")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main(sys.argv[1:])
