"""Benchmark: protecting a folder, whole process, against a codec floor (python -m bench.bench_batch).

Each measurement is one fresh Python process run under `/usr/bin/time` on a fresh copy of the
folder (the copy is made before the clock starts), so start-up, imports, child processes
(jpegtran, when the in-process libturbojpeg pass is not taken) and the durable write (fsync +
rename, poisoner.atomic) are all counted:

- ppd:   `--via library` (default): `poison_in_place` over every file of the folder (the
         product's default spec, poisoner.ladder.default_spec(): a moving texture inside the
         picture), serially, or with `--workers N` through poisoner.batch.poison_many;
         `--via cli`: the command a photographer runs, `ppd poison --workers N <folder>` (vault,
         store, provenance included), each run with a fresh, empty PPD_DATA_DIR/PPD_CONFIG_DIR;
         while the CLI has no `--workers`, N > 1 falls back to the library pool (the table says);
- floor: Pillow decode + re-encode of every file, through the same atomic_output: JPEG with the
         source's quantisation tables and subsampling (`qtables=`, `subsampling=`, Pillow's
         default Huffman tables, i.e. what "re-saving with the same settings" costs), PNG with
         Pillow's default settings.

Every tree timed (this one, --baseline) has its bytecode compiled first, as a pip install leaves it
(bench/bytecode.py says why).

Runs alternate in pairs (ppd, floor, then floor, ppd, ...); the table gives the median of each
side and the ratio of the medians, CPU (user + system, children included) and wall. The load
average is recorded before and after, because the machine is shared.

Inputs (generated, never committed; cached under --cache):
- JPEG: N x 4240x2832 q92 4:2:0 with an EXIF block, from one smooth synthetic texture with edges and
  noise (bench.bench_poison.camera_like), each file shifted and with its own noise;
- PNG: N x 800x800, NeRF-Synthetic lego train views when /work/shared/datasets is there, else
  synthetic RGB.

`python -m bench.bench_batch profile` prints where the time of one process goes (cProfile).
Writes bench/results/batch.md (the measure command).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.bytecode import compile_bytecode

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "batch.md"
LEGO = Path(__file__).resolve().parents[2] / "shared/datasets/nerf_synthetic_lego/train"
JPEG_SIZE = (4240, 2832)
DEFAULT_CACHE = Path(tempfile.gettempdir()) / "ppd-bench-batch"
TIME_FORMAT = "%e %U %S %M"  # wall s, user s, system s, max RSS KiB


# ---- inputs --------------------------------------------------------------------------------------
def make_jpegs(folder: Path, count: int) -> list[Path]:
    import numpy as np
    from PIL import Image

    from bench.bench_poison import camera_like

    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"IMG_{i:04d}.jpg" for i in range(count)]
    if all(p.exists() for p in paths):
        return paths
    w, h = JPEG_SIZE
    base = camera_like(h, w)
    rng = np.random.default_rng(1)
    tile = rng.integers(-4, 5, size=(256, 256, 3), dtype=np.int16)
    exif = Image.Exif()
    exif[0x010F] = "BenchCam"
    for i, path in enumerate(paths):
        shifted = np.roll(base, (i * 37, i * 53), axis=(0, 1)).astype(np.int16)
        noise = np.tile(np.roll(tile, i * 11, axis=0), (h // 256 + 1, w // 256 + 1, 1))[:h, :w]
        pixels = np.clip(shifted + noise, 0, 255).astype(np.uint8)
        Image.fromarray(pixels).save(path, quality=92, subsampling=2, exif=exif)
    return paths


def make_pngs(folder: Path, count: int) -> tuple[list[Path], str]:
    from PIL import Image

    from bench.bench_poison import camera_like

    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"view_{i:04d}.png" for i in range(count)]
    lego = [LEGO / f"r_{i}.png" for i in range(count)]
    source = "lego train views (800x800 RGBA)" if all(p.exists() for p in lego) else "synthetic 800x800 RGB"
    for i, path in enumerate(paths):
        if path.exists():
            continue
        if lego[i].exists():
            shutil.copyfile(lego[i], path)
        else:
            Image.fromarray(camera_like(800, 800, seed=i)).save(path)
    return paths, source


def make_camera_pngs(folder: Path, count: int) -> list[Path]:
    """The JPEG folder's pictures saved as PNG (RGB, Pillow's defaults): a camera's 12 MP, lossless."""
    from PIL import Image

    jpegs = make_jpegs(folder.parent / "jpeg", count)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{j.stem}.png" for j in jpegs]
    for jpeg, path in zip(jpegs, paths, strict=True):
        if not path.exists():
            with Image.open(jpeg) as im:
                im.convert("RGB").save(path)
    return paths


# ---- the measured processes ----------------------------------------------------------------------
def run_ppd(folder: Path, workers: int) -> None:
    from poisoner.ladder import default_spec

    spec = default_spec()
    files = sorted(p for p in folder.iterdir() if p.is_file())
    if workers > 1:
        from poisoner.batch import poison_many

        results = poison_many([(p, p) for p in files], spec, workers=workers)
        # Workers are children of the forkserver: stop and reap it so that /usr/bin/time counts
        # their CPU (private API, bench only).
        from multiprocessing import forkserver

        forkserver._forkserver._stop()
        failed = [r for r in results if r.error]
        if failed:
            raise SystemExit(f"{len(failed)} failed: {failed[0].error}")
        return
    from poisoner.formats import poison_in_place

    for path in files:
        poison_in_place(path, spec)


def run_floor(folder: Path) -> None:
    from PIL import Image, JpegImagePlugin

    from poisoner.atomic import atomic_output

    for path in sorted(p for p in folder.iterdir() if p.is_file()):
        im = Image.open(path)
        im.load()
        with atomic_output(path) as tmp:
            if im.format == "JPEG":
                opts: dict[str, object] = {"qtables": im.quantization, "exif": im.info.get("exif", b"")}
                sampling = JpegImagePlugin.get_sampling(im)
                if sampling != -1:
                    opts["subsampling"] = sampling
                im.save(tmp, "JPEG", **opts)
            else:
                im.save(tmp, "PNG")


# ---- timing --------------------------------------------------------------------------------------
def timed(
    argv: list[str], quiet: bool = False, env: dict[str, str] | None = None, cwd: str | None = None
) -> dict[str, float]:
    """One whole process under /usr/bin/time: wall, cpu (user+sys, children included), rss MB."""
    with tempfile.NamedTemporaryFile("r", suffix=".time") as out:
        subprocess.run(
            ["/usr/bin/time", "-f", TIME_FORMAT, "-o", out.name, sys.executable, "-m", "bench.bench_batch",
             "_reap", *argv],  # fmt: skip
            check=True,
            stdout=subprocess.DEVNULL if quiet else None,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), **(env or {})},
            cwd=cwd,
        )
        wall, user, system, rss = out.read().split()[-4:]
    return {"wall": float(wall), "cpu": float(user) + float(system), "rss": int(rss) / 1024}


def run_reaping(argv: list[str]) -> int:
    """Run argv and wait for every process it leaves behind (a pool's forkserver and its workers
    outlive their parent): as the subreaper, their CPU lands in this process's children usage,
    which /usr/bin/time reports."""
    import ctypes

    pr_set_child_subreaper = 36
    ctypes.CDLL(None, use_errno=True).prctl(pr_set_child_subreaper, 1, 0, 0, 0)
    rc = subprocess.run(argv, check=False).returncode
    while True:
        try:
            os.wait()
        except ChildProcessError:
            return rc


def fresh_copy(src: Path, work: Path, count: int | None = None) -> Path:
    """work = the first `count` files of src (all when None): the cache may hold more."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    for path in sorted(p for p in src.iterdir() if p.is_file())[:count]:
        shutil.copyfile(path, work / path.name)
    return work


def cli_has_workers() -> bool:
    """Whether `ppd poison` takes --workers (the pool behind the CLI)."""
    out = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "poison", "--help"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "COLUMNS": "200"},
    )
    return "--workers" in out.stdout


def ppd_command(work: Path, workers: int, via: str) -> tuple[list[str], str]:
    """The measured ppd process and how it was run (for the table)."""
    if via == "cli" and (workers == 1 or cli_has_workers()):
        cmd = [sys.executable, "-m", "daemon.cli", "poison", str(work), "--workers", str(workers)]
        return cmd, "ppd poison"
    how = "poison_in_place" if workers == 1 else "poison_many pool"
    if via == "cli":
        how += " (CLI has no --workers yet)"
    return [sys.executable, "-m", "bench.bench_batch", "_ppd", str(work), "--workers", str(workers)], how


def fresh_state(root: Path) -> dict[str, str]:
    """An empty ppd data/config/outbox/cache: every CLI run starts from nothing (no vault, no store)."""
    if root.exists():
        shutil.rmtree(root)
    return {k: str(root / k) for k in ("PPD_DATA_DIR", "PPD_CONFIG_DIR", "PPD_OUTBOX", "PPD_CACHE_DIR")}


def paired(
    src: Path, work: Path, pairs: int, workers: int, via: str = "library", count: int | None = None,
    baseline: Path | None = None,
) -> tuple[dict, str]:
    """Runs alternating ppd / floor (/ the baseline checkout's same ppd command, when given), the
    order reversed every other round."""
    ppd_cmd, how = ppd_command(work, workers, via)
    floor_cmd = [sys.executable, "-m", "bench.bench_batch", "_floor", str(work)]
    runs: dict[str, list[dict[str, float]]] = {"ppd": [], "floor": []}
    order = [("ppd", ppd_cmd, None), ("floor", floor_cmd, None)]
    if baseline is not None:  # the same command from another checkout (PYTHONPATH), e.g. the start commit
        runs["base"] = []
        order.append(("base", ppd_cmd, str(baseline.resolve())))
    for i in range(pairs):
        for name, cmd, path in order if i % 2 == 0 else order[::-1]:
            fresh_copy(src, work, count)
            env = fresh_state(work.parent / "state") if name != "floor" and how == "ppd poison" else {}
            if path is not None:
                env = {**(env or {}), "PYTHONPATH": path}
            runs[name].append(timed(cmd, quiet=how == "ppd poison", env=env or None, cwd=path))
    return runs, how


def summarise(runs: dict[str, list[dict[str, float]]]) -> dict[str, float]:
    med = {
        f"{side}_{k}": statistics.median(r[k] for r in runs[side])
        for side in runs
        for k in ("wall", "cpu", "rss")
    }
    med["cpu_ratio"] = med["ppd_cpu"] / med["floor_cpu"]
    med["wall_ratio"] = med["ppd_wall"] / med["floor_wall"]
    if "base" in runs:
        med["base_cpu_ratio"] = med["base_cpu"] / med["floor_cpu"]
        med["base_wall_ratio"] = med["base_wall"] / med["floor_wall"]
    return med


def measure(args: argparse.Namespace) -> None:
    cache = Path(args.cache)
    jpeg_dir = cache / "jpeg"
    png_dir = cache / "png"
    make_jpegs(jpeg_dir, args.count)
    _, png_source = make_pngs(png_dir, args.count)
    work = cache / "work"
    rows = []
    load_before = os.getloadavg()
    folders = {
        "jpeg": (f"{args.count} x JPEG 4240x2832 q92 4:2:0", jpeg_dir),
        "png": (f"{args.count} x PNG {png_source}", png_dir),
    }
    if args.only == "png12":  # only when asked: its floor alone is minutes per run
        make_camera_pngs(cache / "png12", args.count)
        w, h = JPEG_SIZE
        folders["png12"] = (f"{args.count} x PNG {w}x{h} RGB (the JPEG folder's pictures)", cache / "png12")
    compile_bytecode([ROOT, *([args.baseline] if args.baseline else [])])
    for kind, (label, src) in folders.items():
        if args.only and kind != args.only:
            continue
        for workers in args.workers:
            t0 = time.perf_counter()
            load = os.getloadavg()[0]
            runs, how = paired(src, work, args.pairs, workers, args.via, args.count, args.baseline)
            med = summarise(runs)
            print(f"{label} workers={workers} ({how}): {med} ({time.perf_counter() - t0:.0f} s)", flush=True)
            rows.append((label, f"{workers} ({how})", med, (load, os.getloadavg()[0])))
    shutil.rmtree(work, ignore_errors=True)
    shutil.rmtree(cache / "state", ignore_errors=True)
    write_results(args, rows, load_before, os.getloadavg())


def write_results(args: argparse.Namespace, rows: list, load_before: tuple, load_after: tuple) -> None:
    import PIL

    from poisoner.jpeg import turbo_available

    jt = subprocess.run(["jpegtran", "-version"], capture_output=True, text=True)
    turbo = turbo_available() or "used where the file allows"
    lines = [
        "# Protecting a folder: whole process vs the codec floor",
        "",
        f"`python -m bench.bench_batch measure --count {args.count} --pairs {args.pairs} --workers "
        f"{' '.join(map(str, args.workers))} --via {args.via}` on {platform.machine()} "
        f"({os.cpu_count()} cores, shared with other jobs), Python {platform.python_version()}, "
        f"Pillow {PIL.__version__}, "
        f"jpegtran {jt.stderr.strip() or 'absent'}, in-process libturbojpeg: {turbo}.",
        f"Load average (1/5/15 min) before: {'/'.join(f'{x:.2f}' for x in load_before)}, after: "
        f"{'/'.join(f'{x:.2f}' for x in load_after)}; with more runnable jobs than cores, wall "
        "times stretch: read the CPU ratios first.",
        "",
        "Each cell: median of the runs; every run is one whole process on a fresh copy of the folder "
        "(ppd and floor alternate in pairs). CPU = user + system, children (jpegtran, pool workers) "
        "included.",
        "",
        "| files | ppd workers (how) | ppd CPU s | floor CPU s | **CPU ratio** | ppd wall s | floor wall s "
        "| wall ratio | ppd peak RSS MB | floor peak RSS MB | load (1 min) before / after |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, workers, m, load in rows:
        lines.append(
            f"| {label} | {workers} | {m['ppd_cpu']:.2f} | {m['floor_cpu']:.2f} | **{m['cpu_ratio']:.2f}x** "
            f"| {m['ppd_wall']:.2f} | {m['floor_wall']:.2f} | {m['wall_ratio']:.2f}x | {m['ppd_rss']:.0f} "
            f"| {m['floor_rss']:.0f} | {load[0]:.2f} / {load[1]:.2f} |"
        )
    if args.baseline is not None:
        lines += [
            "",
            f"The same ppd command from the baseline checkout `{args.baseline}` (PYTHONPATH), alternating "
            "with the two above in the same rounds:",
            "",
            "| files | ppd workers (how) | baseline CPU s | baseline CPU ratio to the floor "
            "| baseline wall s | baseline wall ratio | ppd CPU / baseline CPU | baseline peak RSS MB |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for label, workers, m, _load in rows:
            lines.append(
                f"| {label} | {workers} | {m['base_cpu']:.2f} | {m['base_cpu_ratio']:.2f}x "
                f"| {m['base_wall']:.2f} | {m['base_wall_ratio']:.2f}x | {m['ppd_cpu'] / m['base_cpu']:.2f}x "
                f"| {m['base_rss']:.0f} |"
            )
    lines.append("")
    text = "\n".join(lines)
    results = args.results
    if results.exists() and args.keep_notes:
        old = results.read_text()
        marker = "\n## Notes"
        if marker in old:
            text += old[old.index(marker) :]
    results.parent.mkdir(parents=True, exist_ok=True)
    results.write_text(text if text.endswith("\n") else text + "\n")
    print(f"wrote {results}")


def profile(args: argparse.Namespace) -> None:
    """cProfile one process poisoning the first --count JPEGs (in-process time only)."""
    import cProfile
    import pstats

    cache = Path(args.cache)
    src = cache / "jpeg"
    make_jpegs(src, max(args.count, 1))
    work = fresh_copy(src, cache / "work-profile")
    for p in sorted(work.iterdir())[args.count :]:
        p.unlink()
    prof = cProfile.Profile()
    prof.enable()
    run_ppd(work, 1)
    prof.disable()
    pstats.Stats(prof).sort_stats("cumulative").print_stats(args.top)
    shutil.rmtree(work, ignore_errors=True)


# What `spans` times inside each file's run, besides the stages themselves (module, function).
SPAN_CALLS = (
    ("daemon.protect.pool", "protect_many"),  # every file's stages
    ("daemon.cli.scene_note", "scene_line"),  # the summary's scene hint (reads a sample of the images)
    ("poisoner.formats", "plan_mark"),
    ("poisoner.formats", "_write_format"),
    ("daemon.protect.poisoning", "seal_output"),  # a work file's seal (videos, images over 64 MiB)
    ("daemon.protect.poisoning", "seal_in_memory"),  # an image's, made in memory
    ("daemon.store.vault", "Vault.keep_fd"),
    ("daemon.fsops", "sha256_fd"),
    ("daemon.store.vault", "sha256_file"),
    ("os", "fsync"),
)


def spans(args: argparse.Namespace) -> None:
    """Where the time of one `ppd poison --workers 1 <folder>` process goes: the command run in
    this process with every stage of daemon.protect.stages (and the calls in SPAN_CALLS) wrapped in
    a timer (CPU: time.process_time, wall: time.perf_counter; the kernel's share of the CPU and the
    minor page faults from getrusage); start-up = process start to the first stage. Nested spans are
    counted in each (a stage's time includes its calls')."""
    import importlib
    import resource
    from collections import defaultdict

    cache = Path(args.cache)
    src = cache / args.only
    if args.only == "jpeg":
        make_jpegs(src, args.count)
    else:
        make_pngs(src, args.count)
    work = fresh_copy(src, cache / "work-spans", args.count)
    env = fresh_state(cache / "state-spans")
    os.environ.update(env)
    totals: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0, 0.0, 0])

    def timed_call(label: str, fn: Any) -> Any:
        def wrapper(*a: Any, **kw: Any) -> Any:
            c0, w0, r0 = time.process_time(), time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
            try:
                return fn(*a, **kw)
            finally:
                r1 = resource.getrusage(resource.RUSAGE_SELF)
                t = totals[label]
                t[0] += time.process_time() - c0
                t[1] += time.perf_counter() - w0
                t[2] += 1
                t[3] += r1.ru_stime - r0.ru_stime
                t[4] += r1.ru_minflt - r0.ru_minflt

        return wrapper

    from daemon.protect import stages

    wrapped = tuple(timed_call(f"stage {s.__name__}", s) for s in stages.STAGES)
    stages.run_stages.__defaults__ = (wrapped,)
    users = [importlib.import_module(m) for m in ("daemon.protect.stages", "daemon.protect.one_file",
                                                  "daemon.cli.poison_cmd")]  # fmt: skip
    for module, name in SPAN_CALLS:
        mod = importlib.import_module(module)
        owner, attr = (getattr(mod, name.split(".")[0]), name.split(".")[1]) if "." in name else (mod, name)
        original = getattr(owner, attr)
        wrapper = timed_call(name, original)
        setattr(owner, attr, wrapper)
        for user in users:  # modules that imported the name itself
            if getattr(user, attr, None) is original:
                setattr(user, attr, wrapper)
    from daemon.cli import app

    c0, w0 = time.process_time(), time.perf_counter()
    with contextlib.suppress(SystemExit):
        app(["poison", str(work), "--workers", "1"], standalone_mode=False)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(f"{args.count} x {args.only}: the command in-process CPU {cpu:.2f} s, wall {wall:.2f} s; the whole "
          f"process (interpreter start and imports included) {usage.ru_utime + usage.ru_stime:.2f} s CPU")
    print("| span | calls | CPU ms per file | of which system | wall ms per file | minor faults per file |")
    print("|---|---|---|---|---|---|")
    for label, (c, w, n, sys_s, faults) in totals.items():
        per = args.count
        print(f"| {label} | {n} | {c * 1000 / per:.1f} | {sys_s * 1000 / per:.1f} | {w * 1000 / per:.1f} | "
              f"{faults / per:.0f} |")
    shutil.rmtree(work, ignore_errors=True)


STARTUP_COMMANDS = {
    "import daemon.cli": ["-c", "import daemon.cli"],
    "ppd poison --help": ["-m", "daemon.cli", "poison", "--help"],
    "ppd status": ["-m", "daemon.cli", "status"],
    "import poisoner.formats": ["-c", "import poisoner.formats"],
}


def startup(args: argparse.Namespace) -> None:
    """Whole-process CPU and peak RSS of CLI start-up (median of --runs), in a throwaway
    PPD_DATA_DIR/PPD_CONFIG_DIR/PPD_OUTBOX, and the biggest imports of `import daemon.cli`."""
    with tempfile.TemporaryDirectory(prefix="ppd-startup-") as tmp:
        env = {
            k: str(Path(tmp) / k) for k in ("PPD_DATA_DIR", "PPD_CONFIG_DIR", "PPD_OUTBOX", "PPD_CACHE_DIR")
        }
        os.environ.update(env)
        for label, argv in STARTUP_COMMANDS.items():
            runs = [timed([sys.executable, *argv], quiet=True) for _ in range(args.runs)]
            cpu = statistics.median(r["cpu"] for r in runs)
            rss = statistics.median(r["rss"] for r in runs)
            print(f"{label}: CPU {cpu * 1000:.0f} ms, peak RSS {rss:.0f} MB (median of {args.runs})")
        out = subprocess.run(
            [sys.executable, "-X", "importtime", "-c", "import daemon.cli"],
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
        )
    rows = []
    for line in out.stderr.splitlines()[1:]:
        parts = line.split("|")
        name = parts[2].rstrip()
        depth = (len(name) - len(name.lstrip()) - 1) // 2
        rows.append((depth, name.strip(), int(parts[1])))
    print("largest imports under `import daemon.cli` (cumulative us, chain to daemon.cli):")
    for depth, name, cumulative in sorted(rows, key=lambda r: -r[2])[: args.top]:
        i = rows.index((depth, name, cumulative))
        chain, d = [name], depth
        for later in rows[i + 1 :]:
            if later[0] < d:
                chain.append(later[1])
                d = later[0]
        print(f"  {cumulative:>8} {' <- '.join(chain)}")


def main() -> None:
    if sys.argv[1:2] == ["_reap"]:  # the wrapper around every timed process (run_reaping)
        sys.exit(run_reaping(sys.argv[2:]))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd")
    m = sub.add_parser("measure", help="paired whole-process runs; writes bench/results/batch.md")
    m.add_argument("--count", type=int, default=24)
    m.add_argument("--pairs", type=int, default=5)
    m.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    m.add_argument("--cache", default=str(DEFAULT_CACHE))
    m.add_argument("--keep-notes", action="store_true", default=True)
    m.add_argument("--via", choices=("library", "cli"), default="library", help="what the ppd side runs")
    m.add_argument("--only", choices=("jpeg", "png", "png12"),
                   help="one folder (png12: the JPEG folder's 12 MP pictures as PNG, only when asked)")
    m.add_argument("--results", type=Path, default=RESULTS, help="where the table goes")
    m.add_argument(
        "--baseline", type=Path, default=None, help="another checkout (an older commit): its ppd runs too"
    )
    p = sub.add_parser("profile", help="cProfile of one ppd process over --count JPEGs")
    p.add_argument("--count", type=int, default=8)
    p.add_argument("--top", type=int, default=30)
    p.add_argument("--cache", default=str(DEFAULT_CACHE))
    sp = sub.add_parser("spans", help="per-stage CPU and wall of one `ppd poison` process")
    sp.add_argument("--count", type=int, default=24)
    sp.add_argument("--only", choices=("jpeg", "png"), default="jpeg")
    sp.add_argument("--cache", default=str(DEFAULT_CACHE))
    s = sub.add_parser("startup", help="CPU of CLI start-up and the biggest imports")
    s.add_argument("--runs", type=int, default=5)
    s.add_argument("--top", type=int, default=25)
    r = sub.add_parser("_ppd")
    r.add_argument("folder", type=Path)
    r.add_argument("--workers", type=int, default=1)
    f = sub.add_parser("_floor")
    f.add_argument("folder", type=Path)
    args = parser.parse_args()
    if args.cmd == "_ppd":
        run_ppd(args.folder, args.workers)
    elif args.cmd == "_floor":
        run_floor(args.folder)
    elif args.cmd == "profile":
        profile(args)
    elif args.cmd == "spans":
        spans(args)
    elif args.cmd == "startup":
        startup(args)
    else:
        measure(parser.parse_args(["measure", *sys.argv[1:]]) if args.cmd is None else args)


if __name__ == "__main__":
    main()
