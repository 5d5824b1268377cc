"""Peak memory of poison_file per format and size, to choose poisoner.limits.DEFAULT_MAX_PIXELS.

Each image is written by one child process and protected by another, fresh one, which reports
its own peak RSS (resource.getrusage ru_maxrss): the figure is what protecting that file costs
a process that has imported ppd's poisoner, nothing else.

    python -m bench.bench_limits [--mp 50 100] [--formats png jpeg ...] [--out bench/results/limits.md]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

MAKE = textwrap.dedent(
    """
    import sys, numpy as np
    from PIL import Image
    fmt, mp, path = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    w = int((mp * 1e6 * 4 / 3) ** 0.5) // 16 * 16
    h = int(mp * 1e6 / w) // 16 * 16
    channels = 4 if fmt.endswith("rgba") else 3
    # a smooth gradient with mild noise: real-photo-like compressibility, quick to encode
    rows = []
    rng = np.random.default_rng(0)
    yy = np.arange(h, dtype=np.uint16)[:, None]
    base = ((np.arange(w, dtype=np.uint16)[None, :] + yy) % 256).astype(np.uint8)
    arr = np.repeat(base[:, :, None], channels, axis=2)
    arr[:: 7, :: 5] ^= 0x55
    im = Image.fromarray(arr, "RGBA" if channels == 4 else "RGB")
    kind = fmt.split("-")[0]
    opts = {"jpeg": {"quality": 92}, "png": {"compress_level": 1}, "webp": {"lossless": True, "method": 0},
            "tiff": {"compression": "tiff_lzw"}}.get(kind, {})
    if kind == "heif":
        import pillow_heif; pillow_heif.register_heif_opener(); opts = {"quality": 80}
    names = {"jpeg": "JPEG", "png": "PNG", "webp": "WEBP", "tiff": "TIFF", "heif": "HEIF"}
    im.save(path, names[kind], **opts)
    print(w, h)
    """
)

MEASURE = textwrap.dedent(
    """
    import resource, sys, time
    from pathlib import Path
    from poisoner.formats import poison_file
    from poisoner.spec import PatchSpec
    src, dst = Path(sys.argv[1]), Path(sys.argv[2])
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t = time.perf_counter()
    poison_file(src, dst, PatchSpec(), max_pixels=10**12)
    dt = time.perf_counter() - t
    print(base // 1024, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024, f"{dt:.1f}")
    """
)

SUFFIX = {"jpeg": ".jpg", "png": ".png", "webp": ".webp", "tiff": ".tif", "heif": ".heic"}


def measure(fmt: str, mp: float, work: Path) -> tuple[str, int, int, str]:
    src = work / f"{fmt}-{mp:g}{SUFFIX[fmt.split('-')[0]]}"
    made = subprocess.run(
        [sys.executable, "-c", MAKE, fmt, str(mp), str(src)], capture_output=True, text=True, check=True
    )
    run = subprocess.run(
        [sys.executable, "-c", MEASURE, str(src), str(work / f"out{src.suffix}")],
        capture_output=True,
        text=True,
        check=False,
    )
    if run.returncode != 0:
        return made.stdout.strip().replace(" ", "x"), -1, -1, run.stderr.strip().splitlines()[-1]
    base, peak, secs = run.stdout.split()
    src.unlink()
    return made.stdout.strip().replace(" ", "x"), int(base), int(peak), secs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--mp", type=float, nargs="+", default=[50.0, 100.0])
    ap.add_argument(
        "--formats", nargs="+", default=["jpeg", "png-rgb", "png-rgba", "webp-rgba", "tiff-rgb", "heif-rgb"]
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    lines = [
        "| format | MP | size | RSS after imports (MB) | peak RSS (MB) | seconds |",
        "|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="ppd-limits-") as tmp:
        for fmt in args.formats:
            for mp in args.mp:
                size, base, peak, secs = measure(fmt, mp, Path(tmp))
                line = f"| {fmt} | {mp:g} | {size} | {base} | {peak} | {secs} |"
                print(line, flush=True)
                lines.append(line)
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
