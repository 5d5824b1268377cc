"""Byte-identity check: the files this checkout's writers produce against another checkout's
(python -m bench.same_bytes --baseline /work/main).

Issue 30's patch pass may make `ppd poison` cheaper but must not change a single output byte: the
protection figures in bench/results were measured on those bytes. Each checkout poisons the same
inputs in its own child process (PYTHONPATH = that checkout, the shared interpreter), with
`poisoner.formats.poison_file` and the product's default spec (what `ppd poison` writes before its
provenance marker and seal, which carry a per-install key and so differ between any two runs), and
every output is compared byte for byte (`cmp`), the writer's report with it. With --cli, the whole
`ppd poison <folder>` too, from each checkout, both with the same seal key (marker and seal included).

Inputs (generated under --cache, never committed; the shared datasets are read in place):
- the bench folder: bench.bench_batch's 24 JPEGs (4240x2832 q92 4:2:0) and 24 PNGs (lego views);
- a dtu_scan37 view as JPEG (1600x1200 q90) with each EXIF orientation 2..8 (the per-photo mark is
  placed as the photo is shown, then turned into the stored pixels);
- the same view as 4:4:4, as progressive, and with its subject mask as keep-out (masked MCUs keep
  their coefficients);
- lego train views (800 px PNG) and dtu views (1600 px PNG, with and without their masks);
- two fountain_P11 photos (3072x2048, optimised Huffman tables: the jpegtran path).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.bench_batch import make_jpegs, make_pngs

SHARED = Path(__file__).resolve().parents[2] / "shared/datasets"
DTU = SHARED / "dtu_scan37"
LEGO = SHARED / "nerf_synthetic_lego/train"
DEFAULT_CACHE = Path(tempfile.gettempdir()) / "ppd-same-bytes"

# Run in each checkout's child: poison every (src, mask) into out/, print {name: the report's method,
# written pixels, notes, kept metadata, placement, lossless flag, size}: those must agree too.
CHILD = """
import json, sys
from pathlib import Path
import numpy as np
from PIL import Image
from poisoner.formats import poison_file
from poisoner.ladder import default_spec
cases, out = json.loads(sys.argv[1]), Path(sys.argv[2])
spec, methods = default_spec(), {}
for name, src, mask in cases:
    keep = None if mask is None else np.asarray(Image.open(mask).convert("L")) > 127
    try:
        r = poison_file(Path(src), out / name, spec, keep_out=keep)
        methods[name] = [r.method, r.written, r.notes, r.preserved, str(r.placement), r.lossless, r.dst_bytes]
    except Exception as exc:  # the same refusal on both sides is the same behaviour
        methods[name] = [f"error: {type(exc).__name__}: {exc}"]
print(json.dumps(methods))
"""


def make_inputs(cache: Path) -> list[tuple[str, str, str | None]]:
    """(output name, source path, keep-out mask path or None) for every case."""
    from PIL import Image

    cases: list[tuple[str, str, str | None]] = []
    jpegs = make_jpegs(cache / "jpeg", 24)
    pngs, _ = make_pngs(cache / "png", 24)
    cases += [(f"bench-{p.name}", str(p), None) for p in jpegs + pngs]
    extra = cache / "extra"
    extra.mkdir(parents=True, exist_ok=True)
    view, mask = DTU / "images/000000.png", DTU / "mask/000.png"
    if view.exists():
        rgb = Image.open(view).convert("RGB")
        for orientation in range(2, 9):
            path = extra / f"dtu-orient{orientation}.jpg"
            exif = Image.Exif()
            exif[0x0112] = orientation
            rgb.save(path, quality=90, exif=exif)
            cases.append((path.name, str(path), None))
        for name, opts in {"dtu-444.jpg": {"subsampling": 0}, "dtu-progressive.jpg": {"progressive": True},
                           "dtu-420.jpg": {"subsampling": 2}}.items():  # fmt: skip
            rgb.save(extra / name, quality=90, **opts)
            cases.append((name, str(extra / name), None))
        cases.append(("dtu-420-masked.jpg", str(extra / "dtu-420.jpg"), str(mask)))
        for i in (0, 12, 24, 36, 48):
            png = DTU / f"images/{i:06d}.png"
            cases.append((f"dtu-{i:03d}.png", str(png), None))
            cases.append((f"dtu-{i:03d}-masked.png", str(png), str(DTU / f"mask/{i:03d}.png")))
            dtu_jpeg = extra / f"dtu-{i:03d}.jpg"
            Image.open(png).convert("RGB").save(dtu_jpeg, quality=92)
            cases.append((dtu_jpeg.name, str(dtu_jpeg), None))
            cases.append((f"dtu-{i:03d}-masked.jpg", str(dtu_jpeg), str(DTU / f"mask/{i:03d}.png")))
    for i in (0, 5):  # optimised Huffman tables: the jpegtran path
        fountain = SHARED / f"fountain_P11/images/{i:04d}.jpg"
        if fountain.exists():
            cases.append((f"fountain-{i:04d}.jpg", str(fountain), None))
    for i in (3, 17, 42, 77, 99):
        if (LEGO / f"r_{i}.png").exists():
            cases.append((f"lego-r_{i}.png", str(LEGO / f"r_{i}.png"), None))
    return cases


def poison_with(tree: Path, cases: list[tuple[str, str, str | None]], out: Path) -> dict[str, list]:
    out.mkdir(parents=True, exist_ok=True)
    for old in out.iterdir():
        old.unlink()
    run = subprocess.run(
        ["nice", sys.executable, "-c", CHILD, json.dumps(cases), str(out)],
        env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"}, cwd=tree, capture_output=True, text=True,
        check=True,
    )  # fmt: skip
    return json.loads(run.stdout.strip().splitlines()[-1])


def cli_same_bytes(trees: dict[str, Path], cases: list[tuple[str, str, str | None]], cache: Path) -> list[str]:  # noqa: E501
    """The whole command: `ppd poison <folder> --workers 1` from each checkout on its own copy of one
    folder (every unmasked case), its own empty state, the same seal key (the first run makes it, the
    second gets a copy: the marker and the seal are keyed), then every file compared with `cmp`.
    Returns the names that differ."""
    import os
    import shutil

    differ = []
    keys: Path | None = None
    folders = {}
    for label, tree in trees.items():
        root = cache / f"cli-{label}"
        shutil.rmtree(root, ignore_errors=True)
        folder = root / "shoot"
        folder.mkdir(parents=True)
        for name, src, mask in cases:
            if mask is None:
                shutil.copyfile(src, folder / name)
        state = {v: root / d for v, d in (("PPD_DATA_DIR", "data"), ("PPD_CONFIG_DIR", "config"),
                                          ("PPD_OUTBOX", "outbox"), ("PPD_CACHE_DIR", "cache"))}  # fmt: skip
        for d in state.values():
            d.mkdir()
        if keys is not None:
            shutil.copyfile(keys, state["PPD_DATA_DIR"] / "seal.key")
            (state["PPD_DATA_DIR"] / "seal.key").chmod(0o600)  # ppd refuses a key others can read
        env = {**os.environ, "PYTHONPATH": str(tree), **{k: str(v) for k, v in state.items()}}
        command = ["nice", sys.executable, "-m", "daemon.cli", "poison", str(folder), "--workers", "1"]
        run = subprocess.run(command, env=env, cwd=tree, capture_output=True, text=True, check=False)
        if run.returncode != 0:
            raise SystemExit(f"ppd poison from {tree} failed: {run.stderr[-500:]}")
        keys = keys or state["PPD_DATA_DIR"] / "seal.key"
        folders[label] = folder
    for path in sorted(folders["baseline"].iterdir()):
        other = folders["this"] / path.name
        if subprocess.run(["cmp", "-s", str(path), str(other)], check=False).returncode != 0:
            differ.append(path.name)
    return differ


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="the other checkout (e.g. /work/main)")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    parser.add_argument("--cli", action="store_true", help="also `ppd poison` from each checkout, same key")
    args = parser.parse_args()
    here = Path(__file__).resolve().parents[1]
    cases = make_inputs(args.cache)
    sides = {}
    for label, tree in (("baseline", args.baseline.resolve()), ("this", here)):
        sides[label] = poison_with(tree, cases, args.cache / f"out-{label}")
    differ = []
    for name, _src, _mask in cases:
        a, b = args.cache / "out-baseline" / name, args.cache / "out-this" / name
        same_report = sides["baseline"][name] == sides["this"][name]
        if a.exists() != b.exists() or not same_report:
            differ.append(f"{name}: baseline {sides['baseline'][name]}, this {sides['this'][name]}")
        elif a.exists() and subprocess.run(["cmp", "-s", str(a), str(b)], check=False).returncode != 0:
            differ.append(f"{name}: bytes differ ({sides['this'][name][0]})")
    methods: dict[str, int] = {}
    for report in sides["this"].values():
        methods[report[0]] = methods.get(report[0], 0) + 1
    if args.cli:
        unmasked = [c for c in cases if c[2] is None]
        cli_differ = cli_same_bytes({"baseline": args.baseline.resolve(), "this": here}, unmasked, args.cache)
        same = len(unmasked) - len(cli_differ)
        print(f"ppd poison (whole command, same seal key): {same} of {len(unmasked)} files identical (cmp), "
              f"{len(cli_differ)} differ: {cli_differ}")  # fmt: skip
        differ += [f"{name}: ppd poison output differs" for name in cli_differ]
    print(f"{len(cases)} files, baseline {args.baseline} vs {here}: {len(cases) - len(differ)} identical "
          f"(cmp, and the same report: method, written pixels, notes, placement), {len(differ)} differ; "
          f"methods: {methods}")  # fmt: skip
    for line in differ:
        print("  DIFFER", line)
    raise SystemExit(1 if differ else 0)


if __name__ == "__main__":
    main()
