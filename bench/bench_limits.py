"""Peak memory of poison_file per format and size, to choose poisoner.limits.DEFAULT_MAX_PIXELS.

Each image is written by one child process and protected by another, fresh one, which reports
its own peak RSS (resource.getrusage ru_maxrss): the figure is what protecting that file costs
a process that has imported ppd's poisoner, nothing else.

    python -m bench.bench_limits [--mp 50 100] [--formats png jpeg ...] [--out bench/results/limits.md]
    python -m bench.bench_limits --video 3840x2160 [--lookahead 40]   (poison_video, 48 H.264 frames)
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
    channels = 4 if "rgba" in fmt else 3
    noise = fmt.endswith("-noise")  # what deflate cannot shrink: a photo's sensor noise, at its worst
    fmt = fmt.removesuffix("-noise")
    rng = np.random.default_rng(0)
    if fmt.endswith("16"):  # 16-bit PNG: Pillow cannot write it; rows streamed through zlib
        import struct, zlib
        def chunk(t, b):
            return struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b))
        z = zlib.compressobj(1)
        row = np.zeros((w, channels), np.uint16)
        row[:, 0] = np.arange(w, dtype=np.uint16) * 7
        with open(path, "wb") as f:
            ihdr = struct.pack(">IIBBBBB", w, h, 16, 6 if channels == 4 else 2, 0, 0, 0)
            f.write(b"\\x89PNG\\r\\n\\x1a\\n" + chunk(b"IHDR", ihdr))
            parts = []
            for y in range(h):
                line = rng.integers(0, 65536, (w, channels), dtype=np.uint16) if noise else row + y
                parts.append(z.compress(b"\\x00" + line.astype(">u2").tobytes()))
                if len(parts) > 256:
                    f.write(chunk(b"IDAT", b"".join(parts))); parts = []
            parts.append(z.flush())
            f.write(chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b""))
        print(w, h)
        sys.exit(0)
    # a smooth gradient with mild noise: real-photo-like compressibility, quick to encode
    rows = []
    yy = np.arange(h, dtype=np.uint16)[:, None]
    base = ((np.arange(w, dtype=np.uint16)[None, :] + yy) % 256).astype(np.uint8)
    arr = np.repeat(base[:, :, None], channels, axis=2)
    arr[:: 7, :: 5] ^= 0x55
    if noise:
        arr = rng.integers(0, 256, arr.shape, dtype=np.uint8)
        if channels == 4:
            arr[..., 3] = 255
    im = Image.fromarray(arr, "RGBA" if channels == 4 else "RGB")
    kind = fmt.split("-")[0]
    opts = {"jpeg": {"quality": 92}, "png": {"compress_level": 1}, "webp": {"lossless": True, "method": 0},
            "webpq": {"quality": 90, "method": 0}, "tiff": {"compression": "tiff_lzw"}}.get(kind, {})
    if kind == "heif":
        import pillow_heif; pillow_heif.register_heif_opener(); opts = {"quality": 80}
    names = {"jpeg": "JPEG", "png": "PNG", "webp": "WEBP", "webpq": "WEBP", "tiff": "TIFF", "heif": "HEIF"}
    im.save(path, names[kind], **opts)
    print(w, h)
    """
)

MEASURE = textwrap.dedent(
    """
    import resource, sys, time
    from pathlib import Path
    from poisoner.formats import poison_file
    from poisoner.ladder import default_spec
    src, dst = Path(sys.argv[1]), Path(sys.argv[2])
    from poisoner.limits import decoded_size
    estimate = decoded_size(src).peak_bytes // 2**20
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t = time.perf_counter()
    poison_file(src, dst, default_spec(), max_pixels=10**12)  # ppd's own mark: two squares, per photo
    dt = time.perf_counter() - t
    print(base // 1024, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024, f"{dt:.1f}", estimate)
    """
)

MAKE_VIDEO = textwrap.dedent(
    """
    import sys, av, numpy as np
    w, h, path = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    with av.open(path, "w") as out:
        vs = out.add_stream("libx264", rate=30, options={"preset": "ultrafast", "crf": "23"})
        vs.width, vs.height, vs.pix_fmt = w, h, "yuv420p"
        rng = np.random.default_rng(0)
        tex = rng.integers(0, 255, size=(h // 8 + 64, w // 8 + 64, 3), dtype=np.uint8)
        tex = tex.repeat(8, 0).repeat(8, 1)
        for i in range(48):
            rgb = np.ascontiguousarray(tex[i : i + h, 2 * i : 2 * i + w])
            f = av.VideoFrame.from_ndarray(rgb, format="rgb24").reformat(format="yuv420p")
            f.pts = i
            for p in vs.encode(f):
                out.mux(p)
        for p in vs.encode(None):
            out.mux(p)
    """
)

MEASURE_VIDEO = textwrap.dedent(
    """
    import resource, sys, time
    from pathlib import Path
    import poisoner.video as v
    from poisoner.spec import PatchSpec
    if sys.argv[3] != "default":  # force a lookahead to compare with the default
        choose = v.choose_encoder
        def forced(info, options, crf_shift=0):
            c = choose(info, options, crf_shift)
            c.options["rc-lookahead"] = sys.argv[3]
            return c
        v.choose_encoder = forced
    t = time.perf_counter()
    r = v.poison_video(Path(sys.argv[1]), Path(sys.argv[2]), PatchSpec(), max_pixels=10**10)
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024, f"{time.perf_counter() - t:.1f}", r.crf)
    """
)


def measure_video(size: str, lookahead: str, work: Path) -> str:
    w, h = size.split("x")
    src = work / f"v{size}.mp4"
    subprocess.run([sys.executable, "-c", MAKE_VIDEO, w, h, str(src)], check=True)
    run = subprocess.run(
        [sys.executable, "-c", MEASURE_VIDEO, str(src), str(work / "vout.mp4"), lookahead],
        capture_output=True,
        text=True,
        check=False,
    )
    if run.returncode != 0:
        return f"| {size} | {lookahead} | failed: {run.stderr.strip().splitlines()[-1]} | | |"
    peak, secs, crf = run.stdout.split()
    return f"| {size} | {lookahead} | {peak} | {secs} | {crf} |"


SUFFIX = {"jpeg": ".jpg", "png": ".png", "webp": ".webp", "webpq": ".webp", "tiff": ".tif", "heif": ".heic"}


def measure(fmt: str, mp: float, work: Path) -> tuple[str, int, int, str, str, int]:
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
        return made.stdout.strip().replace(" ", "x"), -1, -1, run.stderr.strip().splitlines()[-1], "-", 0
    base, peak, secs, estimate = run.stdout.split()
    file_mb = src.stat().st_size // 2**20
    src.unlink()
    return made.stdout.strip().replace(" ", "x"), int(base), int(peak), secs, estimate, file_mb


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--mp", type=float, nargs="+", default=[50.0, 100.0])
    ap.add_argument(
        "--formats", nargs="+", default=["jpeg", "png-rgb", "png-rgba", "webp-rgba", "tiff-rgb", "heif-rgb"]
    )
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--video", nargs="*", default=[], help="frame sizes WxH: measure poison_video instead")
    ap.add_argument("--lookahead", default="default", help="force x264 rc-lookahead (video only)")
    args = ap.parse_args()
    if args.video:
        print("| frame size | rc-lookahead | peak RSS (MB) | seconds | CRF |\n|---|---|---|---|---|")
        with tempfile.TemporaryDirectory(prefix="ppd-limits-") as tmp:
            for size in args.video:
                print(measure_video(size, args.lookahead, Path(tmp)), flush=True)
        return
    lines = [
        "| format | MP | size | file (MB) | RSS after imports (MB) | peak RSS (MB) | ppd's estimate (MB) "
        "| seconds |",
        "|---|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="ppd-limits-") as tmp:
        for fmt in args.formats:
            for mp in args.mp:
                size, base, peak, secs, estimate, file_mb = measure(fmt, mp, Path(tmp))
                line = f"| {fmt} | {mp:g} | {size} | {file_mb} | {base} | {peak} | {estimate} | {secs} |"
                print(line, flush=True)
                lines.append(line)
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
