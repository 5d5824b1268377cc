"""Benchmark: poison_in_place latency and JPEG fidelity (python -m bench.bench_poison).

Latency (median of REPEATS runs, each on a fresh copy of the file) of
- poison_in_place (what the daemon does per file),
- the floor: decode + encode of the same file with the same settings, no patch, written through the
  same atomic_output (so both include the fsync and rename),
- an ImageMagick `composite` one-liner laying the same patch over the file,
for a generated 12 MP camera-like JPEG (4:2:0) and an 800x800 PNG.

Fidelity, for the DCT splice and for the same-tables full re-encode: max / mean absolute pixel
difference outside the patch's MCU-aligned box (and outside that box grown by one MCU) and the
whole-image PSNR against the original, on the 12 MP JPEG and a fountain_P11 photo.

Writes bench/results/poison.md.
"""

from __future__ import annotations

import os
import platform
import shutil
import statistics
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image

from poisoner import jpeg as jpeg_codec
from poisoner.atomic import atomic_output
from poisoner.blend import apply_patch
from poisoner.formats import poison_file, poison_in_place
from poisoner.spec import PatchSpec

REPEATS = 7
RESULTS = Path(__file__).resolve().parent / "results" / "poison.md"
FOUNTAIN = Path(__file__).resolve().parents[2] / "shared/datasets/fountain_P11/images/0005.jpg"
SPEC = PatchSpec()  # the daemon's default patch


def camera_like(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Smooth shading, edges, texture and sensor noise: compresses like a photo."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.stack(
        [
            120 + 80 * np.sin(xx / 310.0) * np.cos(yy / 170.0),
            110 + 70 * np.cos(xx / 230.0 + yy / 410.0),
            90 + 0.02 * xx + 0.015 * yy,
        ],
        axis=-1,
    )
    img += 25.0 * ((xx // 97 + yy // 83) % 2)[..., None]  # edges
    img += 12.0 * np.sin(xx / 3.1 + yy / 4.7)[..., None]  # fine texture
    img += rng.normal(0, 3.0, img.shape).astype(np.float32)  # sensor noise
    return np.clip(img, 0, 255).astype(np.uint8)


def make_inputs(folder: Path) -> dict[str, Path]:
    jpg = folder / "camera12mp.jpg"
    exif = Image.Exif()
    exif[0x010F] = "BenchCam"
    Image.fromarray(camera_like(3000, 4000)).save(jpg, quality=92, subsampling=2, exif=exif)
    png = folder / "frame800.png"
    Image.fromarray(camera_like(800, 800, seed=1)).save(png)
    return {"JPEG 4000x3000 4:2:0 q92": jpg, "PNG 800x800 RGB": png}


def median_time(fn: Callable[[Path], None], src: Path, work: Path) -> float:
    times = []
    for i in range(REPEATS):
        target = work / f"run{i}{src.suffix}"
        shutil.copyfile(src, target)
        t0 = time.perf_counter()
        fn(target)
        times.append(time.perf_counter() - t0)
        target.unlink()
    return statistics.median(times)


def floor_reencode(path: Path) -> None:
    """Decode + encode with the same settings, no patch, through atomic_output."""
    data = path.read_bytes()
    im = Image.open(path)
    im.load()
    with atomic_output(path) as tmp:
        if im.format == "JPEG":
            layout = jpeg_codec.read_layout(data)
            tmp.write_bytes(jpeg_codec.encode_like(np.asarray(im), im, layout))
        else:
            im.save(tmp, "PNG")


def patch_png(folder: Path, width: int, height: int) -> tuple[Path, int, int]:
    placement = SPEC.resolve(width, height)
    white = np.full((placement.size, placement.size, 3), 255, dtype=np.uint8)
    from poisoner.spec import PatchPlacement

    local = PatchPlacement(**{**placement.__dict__, "x": 0, "y": 0})
    path = folder / "patch.png"
    Image.fromarray(apply_patch(white, local)).save(path)
    return path, placement.x, placement.y


def imagemagick_binary() -> list[str] | None:
    for cand in ("/usr/bin/magick", "/usr/bin/composite"):
        if Path(cand).exists():
            return [cand, "composite"] if cand.endswith("magick") else [cand]
    return None


def imagemagick_fn(patch: Path, x: int, y: int) -> Callable[[Path], None] | None:
    binary = imagemagick_binary()
    if binary is None:
        return None

    def run(path: Path) -> None:
        # In place the way ppd writes (poisoner.atomic: temporary, fsync, rename), so both pay the same.
        with atomic_output(path) as out:
            subprocess.run([*binary, "-geometry", f"+{x}+{y}", str(patch), str(path), str(out)], check=True)

    return run


def outside(arr: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    mask = np.ones(arr.shape[:2], dtype=bool)
    x0, y0, x1, y1 = box
    mask[y0:y1, x0:x1] = False
    return arr[mask]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def jpeg_fidelity(src: Path, work: Path) -> list[dict[str, object]]:
    rows = []
    original = np.asarray(Image.open(src)).astype(np.int16)
    h, w = original.shape[:2]
    layout = jpeg_codec.read_layout(src.read_bytes())
    box = jpeg_codec.mcu_box(SPEC.resolve(w, h).box, layout)
    mw, mh = layout.mcu_size
    ring = (max(0, box[0] - mw), max(0, box[1] - mh), min(w, box[2] + mw), min(h, box[3] + mh))
    for label, env in (("DCT splice (jpegtran -drop)", None), ("full re-encode, same tables", "")):
        if env is not None:
            os.environ[jpeg_codec.JPEGTRAN_ENV] = env
        try:
            out = work / f"fid-{label[:4]}.jpg"
            report = poison_file(src, out, SPEC)
        finally:
            os.environ.pop(jpeg_codec.JPEGTRAN_ENV, None)
        poisoned = np.asarray(Image.open(out)).astype(np.int16)
        diff = np.abs(original - poisoned)
        rows.append(
            {
                "image": f"{src.name} {w}x{h}",
                "method": f"{label} [{report.method}]",
                "max_out": int(outside(diff, box).max()),
                "mean_out": float(outside(diff, box).mean()),
                "max_out_ring": int(outside(diff, ring).max()),
                "psnr": psnr(original, poisoned),
                "psnr_out": psnr(outside(original, box), outside(poisoned, box)),
                "box": box,
                "size": f"{src.stat().st_size} -> {out.stat().st_size}",
            }
        )
    return rows


def main() -> None:
    rows_latency = []
    rows_fidelity: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory(prefix="ppd-bench-") as tmp:
        folder = Path(tmp)
        inputs = make_inputs(folder)
        for label, src in inputs.items():
            w, h = Image.open(src).size
            patch, x, y = patch_png(folder, w, h)
            t_poison = median_time(lambda p: poison_in_place(p, SPEC), src, folder)
            t_floor = median_time(floor_reencode, src, folder)
            im_fn = imagemagick_fn(patch, x, y)
            t_im = median_time(im_fn, src, folder) if im_fn else float("nan")
            method = poison_file(src, folder / f"m{src.suffix}", SPEC).method
            rows_latency.append((label, method, t_poison, t_floor, t_im))
            ms = [f"{t * 1000:.0f} ms" for t in (t_poison, t_floor, t_im)]
            print(f"{label}: poison {ms[0]}, floor {ms[1]}, ImageMagick {ms[2]}")
        rows_fidelity += jpeg_fidelity(inputs["JPEG 4000x3000 4:2:0 q92"], folder)
        if FOUNTAIN.exists():
            rows_fidelity += jpeg_fidelity(FOUNTAIN, folder)
    write_results(rows_latency, rows_fidelity)


def write_results(
    latency: list[tuple[str, str, float, float, float]], fidelity: list[dict[str, object]]
) -> None:
    im = imagemagick_binary()
    im_version = (
        subprocess.run([*im, "-version"], capture_output=True, text=True).stdout.splitlines()[0]
        if im
        else "absent"
    )
    lines = [
        "# poison_in_place benchmark",
        "",
        f"`python -m bench.bench_poison` on {platform.machine()} ({os.cpu_count()} cores, shared), "
        f"Python {platform.python_version()}, Pillow {Image.__version__}; ImageMagick: {im_version}.",
        f"Median of {REPEATS} runs, each on a fresh copy; default PatchSpec "
        "(checkerboard, 6% of width, top-left).",
        "",
        "## Latency",
        "",
        "Per file and in process (wall): the floor here is `encode_like`, which re-optimises the Huffman "
        "tables (`optimize=True`, ~4x the CPU of a plain same-tables save), so this ratio flatters ppd. The "
        "whole-process comparison with a plain same-tables re-save, over 24-file folders, CPU and wall, "
        "is bench/results/batch.md (`python -m bench.bench_batch`).",
        "",
        "| file | method | poison_in_place | floor (decode+encode, same settings) | ratio to floor "
        "| ImageMagick composite | ratio to ImageMagick |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, method, t_p, t_f, t_im in latency:
        im_cells = "absent | -" if t_im != t_im else f"{t_im * 1000:.0f} ms | {t_p / t_im:.2f}x"  # NaN: none
        ratio = f"{t_p / t_f:.2f}x"
        lines.append(
            f"| {label} | {method} | {t_p * 1000:.0f} ms | {t_f * 1000:.0f} ms | {ratio} | {im_cells} |"
        )
    lines += [
        "",
        "## JPEG fidelity: splice vs full re-encode",
        "",
        "Pixel differences against the decoded original, outside the patch's MCU-aligned box, outside",
        "that box grown by one MCU; PSNR outside the box and of the whole picture (patch included).",
        "",
        "| image | method | MCU box | max abs outside box | mean abs outside box "
        "| max abs outside box + 1 MCU | PSNR outside box | PSNR whole image | bytes |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in fidelity:
        lines.append(
            f"| {r['image']} | {r['method']} | {r['box']} | {r['max_out']} | {r['mean_out']:.4f} "
            f"| {r['max_out_ring']} | {r['psnr_out']:.2f} dB | {r['psnr']:.2f} dB | {r['size']} |"
        )
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text("\n".join(lines) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
