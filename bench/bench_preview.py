"""`ppd preview` against `ppd poison` on one 12 MP JPEG, whole processes, paired (issue 28: the
preview must take at most twice as long as patching the same photo).

    python -m bench.bench_preview [--pairs 5]          paired runs, results in bench/results/preview.md
    python -m bench.bench_preview --one poison|preview --photo F.jpg   one run (for an outside timer)

Each run is a fresh process with fresh ppd folders (a second `ppd poison` of a patched file would
be a no-op): `ppd poison FILE` patches it in place (vault copy, store row), `ppd preview FILE`
renders the side-by-side PNG and measures the visibility. The two alternate, A B A B, so a drift
of the shared machine's speed hits both; the figures are each run's wall time and its CPU time
(user + system, from the OS's accounting of the finished child), and the ratio preview / poison
pair by pair. The photo: fountain-P11's first view upscaled to 4000 x 3000 (JPEG q92), a stand-in
for a phone photo, when the shared datasets are there, else a synthetic one.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import PIL.Image

REPO = Path(__file__).resolve().parents[1]
FOUNTAIN = REPO.parent / "shared" / "datasets" / "fountain_P11" / "images" / "0000.jpg"
RESULTS = REPO / "bench" / "results" / "preview.md"
SIZE = (4000, 3000)


def make_photo(path: Path) -> str:
    if FOUNTAIN.is_file():
        with PIL.Image.open(FOUNTAIN) as im:
            im.convert("RGB").resize(SIZE, PIL.Image.Resampling.LANCZOS).save(path, quality=92)
        return "fountain-P11 view 0 upscaled to 4000x3000, JPEG q92"
    rng = np.random.default_rng(28)
    yy, xx = np.mgrid[0 : SIZE[1], 0 : SIZE[0]]
    base = 128 + 60 * np.sin(xx / 53.0) * np.cos(yy / 41.0)
    noise = rng.normal(0, 10, (SIZE[1], SIZE[0], 1))
    PIL.Image.fromarray(np.clip(base[..., None] + noise, 0, 255).astype(np.uint8).repeat(3, 2)).save(
        path, quality=92
    )
    return "synthetic 4000x3000, JPEG q92 (shared datasets not found)"


def one_run(kind: str, photo: Path) -> int:
    """One whole `ppd` process of that kind on a fresh copy of the photo, in fresh ppd folders."""
    with tempfile.TemporaryDirectory(prefix="ppd-bench-preview-") as tmp:
        home = Path(tmp)
        env = dict(os.environ, PYTHONPATH=str(REPO), OMP_WAIT_POLICY="PASSIVE")
        for var, name in (("PPD_DATA_DIR", "data"), ("PPD_CONFIG_DIR", "config"), ("PPD_OUTBOX", "outbox")):
            (home / name).mkdir()
            env[var] = str(home / name)
        (home / "set").mkdir()
        target = home / "set" / "IMG_0001.jpg"
        shutil.copyfile(photo, target)
        args = (
            ["poison", str(target)]
            if kind == "poison"
            else ["preview", str(target), "--out", str(home / "p.png")]
        )
        done = subprocess.run(
            [sys.executable, "-m", "daemon.cli", *args], env=env, capture_output=True, text=True
        )
        if done.returncode != 0:
            print(done.stderr, file=sys.stderr)
        return done.returncode


def timed(kind: str, photo: Path) -> tuple[float, float]:
    """(wall s, CPU s of the child process tree) of one run."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    code = subprocess.run([sys.executable, "-m", "bench.bench_preview", "--one", kind, "--photo", str(photo)],
                          cwd=REPO).returncode  # fmt: skip
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if code != 0:
        raise RuntimeError(f"ppd {kind} failed")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def render(rows: list[dict], source: str) -> str:
    def med(key: str) -> float:
        return statistics.median(r[key] for r in rows)

    lines = [
        "# `ppd preview` vs `ppd poison` on one 12 MP JPEG (issue 28)",
        "",
        f"`python -m bench.bench_preview --pairs {len(rows)}`: whole processes, fresh ppd folders each run, "
        f"alternating poison / preview; photo: {source}. A 2-core machine shared with other work: the "
        "ratios, pair by pair, are the figures to read.",
        "",
        "| pair | poison wall s | preview wall s | wall ratio | poison CPU s | preview CPU s | CPU ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(rows, 1):
        lines.append(
            f"| {i} | {r['poison_wall']:.2f} | {r['preview_wall']:.2f} | {r['wall_ratio']:.2f} | "
            f"{r['poison_cpu']:.2f} | {r['preview_cpu']:.2f} | {r['cpu_ratio']:.2f} |"
        )
    lines += [
        f"| median | {med('poison_wall'):.2f} | {med('preview_wall'):.2f} | **{med('wall_ratio'):.2f}** | "
        f"{med('poison_cpu'):.2f} | {med('preview_cpu'):.2f} | **{med('cpu_ratio'):.2f}** |",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=5)
    parser.add_argument("--one", choices=("poison", "preview"), help="one run of that kind, then exit")
    parser.add_argument("--photo", type=Path, help="the photo (default: made here)")
    parser.add_argument("--make-photo", type=Path, help="write the bench's 12 MP photo there, then exit")
    args = parser.parse_args(argv if argv is not None else [])
    if args.make_photo:
        print(make_photo(args.make_photo))
        return
    if args.one:
        sys.exit(one_run(args.one, args.photo))
    with tempfile.TemporaryDirectory(prefix="ppd-bench-preview-") as tmp:
        photo = args.photo or Path(tmp) / "photo.jpg"
        source = make_photo(photo) if args.photo is None else str(args.photo)
        timed("preview", photo)  # warm-up: file caches, compiled bytecode
        rows = []
        for _ in range(args.pairs):
            pw, pc = timed("poison", photo)
            vw, vc = timed("preview", photo)
            rows.append({"poison_wall": pw, "poison_cpu": pc, "preview_wall": vw, "preview_cpu": vc,
                         "wall_ratio": vw / pw, "cpu_ratio": vc / pc})  # fmt: skip
            print(rows[-1], flush=True)
    RESULTS.write_text(render(rows, source))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main(sys.argv[1:])
