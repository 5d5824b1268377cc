"""Why a patched video grows, and what keeps it small at the same quality outside the mark (a black-box
review: a 720p x264 CRF 23 clip grew 1.85x at the same CRF). Clips are panned crops of the shared
datasets' photos (camera texture, not synthetic noise), coded as ffmpeg codes by default; each is
written by ppd several ways and measured against the decoded source outside the mark (box + 16 px).

    python -m bench.bench_video_size [--seconds 10] [--only NAME ...]

Writes its round at the top of bench/results/video.md (bench_video's own sections stay below).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import av
import numpy as np
from PIL import Image
from skimage.metrics import structural_similarity

from poisoner.ladder import default_spec
from poisoner.video import driver, encoder, poison_video
from poisoner.video.driver import frame_placements
from poisoner.video.encoder import choose_encoder, configure_video_stream
from poisoner.video.model import EncoderChoice, SourceInfo, VideoOptions, VideoReport
from poisoner.video.source import probe
from testkit.video import mux_rgb_frames

RESULTS = Path(__file__).resolve().parent / "results" / "video.md"
DATASETS = Path(os.environ["PPD_SHARED_DATA"])  # bench/__init__.py: the checkout's ../shared/datasets
ROUND_TITLE = "## Size of a patched video (bench/bench_video_size.py)"
MARGIN = 16  # px around the mark's box left out of "outside the mark", as tests/poisoner/test_video.py
SSIM_EVERY = 3  # SSIM on every 3rd frame (PSNR on all): 720p SSIM costs ~60 ms a frame


@dataclass(frozen=True)
class ClipSpec:
    name: str
    photo: str  # relative to the shared datasets
    width: int
    height: int
    encoder: str = "libx264"
    options: tuple[tuple[str, str], ...] = (("crf", "23"), ("preset", "medium"))


CLIPS = (
    ClipSpec("fountain-720p", "fountain_P11/images/0000.jpg", 1280, 720),
    ClipSpec("dtu-720p", "dtu_scan37/images/000000.png", 1280, 720),
    ClipSpec("fountain-360p", "fountain_P11/images/0005.jpg", 640, 360),
    ClipSpec("lego-360p", "nerf_synthetic_lego/train/r_0.png", 640, 360),
    ClipSpec("dtu-720p-x265", "dtu_scan37/images/000010.png", 1280, 720, "libx265",
             (("crf", "28"), ("preset", "medium"), ("x265-params", "log-level=error"))),  # fmt: skip
    # a phone's hardware encoder codes no B-frames: ppd leaves x264 its own choice there
    ClipSpec("fountain-720p-noB", "fountain_P11/images/0003.jpg", 1280, 720,
             options=(("crf", "23"), ("preset", "medium"), ("bf", "0"), ("g", "30"))),  # fmt: skip
)


def _photo(path: Path) -> np.ndarray:
    im = Image.open(path)
    if im.mode == "RGBA":  # lego: composited on white, as 3DGS does for this dataset
        white = Image.new("RGBA", im.size, (255, 255, 255, 255))
        im = Image.alpha_composite(white, im)
    return np.asarray(im.convert("RGB"))


def _pan(photo: np.ndarray, width: int, height: int, n: int) -> Iterator[np.ndarray]:
    """n crops of width x height panning across the photo (scaled to leave room), bobbing up and down."""
    h, w = photo.shape[:2]
    scale = max(width * 1.6 / w, height * 1.3 / h)
    size = (int(w * scale), int(h * scale))
    big = np.asarray(Image.fromarray(photo).resize(size, Image.Resampling.LANCZOS))
    bh, bw = big.shape[:2]
    for i in range(n):
        t = i / max(1, n - 1)
        x = int(round(t * (bw - width)))
        y = int(round((0.5 + 0.5 * np.sin(2 * np.pi * t)) * (bh - height)))
        yield np.ascontiguousarray(big[y : y + height, x : x + width])


def make_clip(spec: ClipSpec, path: Path, seconds: float, fps: int = 30) -> Path:
    photo = _photo(DATASETS / spec.photo)
    with av.open(str(path), "w") as out:
        vs = out.add_stream(spec.encoder, rate=fps, options=dict(spec.options))
        vs.width, vs.height, vs.pix_fmt = spec.width, spec.height, "yuv420p"
        mux_rgb_frames(out, vs, _pan(photo, spec.width, spec.height, int(seconds * fps)))
    return path


def floor_transcode(src: Path, dst: Path) -> None:
    """Decode + encode with ppd's encoder choice and no mark (the encoder picks every frame type)."""
    info = probe(src)
    options = VideoOptions()
    choice = choose_encoder(info, options)
    with av.open(str(src)) as inp, av.open(str(dst), "w", format=info.muxer) as out:
        vs = configure_video_stream(out, info, choice, options)
        for frame in inp.decode(video=0):
            frame.pict_type = av.video.frame.PictureType.NONE
            for pkt in vs.encode(frame):
                out.mux(pkt)
        for pkt in vs.encode(None):
            out.mux(pkt)


def vbv_capped(choose: Callable[..., EncoderChoice]) -> Callable[..., EncoderChoice]:
    """choose_encoder with the source's bit rate as a VBV cap (the review's suggestion), for this bench
    only: maxrate = the source's rate, a 2 s buffer."""

    def capped(info: SourceInfo, options: VideoOptions, crf_shift: int = 0) -> EncoderChoice:
        choice = choose(info, options, crf_shift)
        rate = info.bit_rate or 0
        extra = {"maxrate": str(rate), "bufsize": str(2 * rate)} if rate else {}
        return dataclasses.replace(choice, options={**choice.options, **extra})

    return capped


def _luma(frame: av.VideoFrame) -> np.ndarray:
    return frame.to_ndarray(format="gray").astype(np.float64)


def quality_outside(src: Path, out: Path) -> tuple[float, float]:
    """(luma PSNR over all frames, mean luma SSIM over every SSIM_EVERY-th frame) of out against the
    decoded src, outside each frame's mark box grown by MARGIN."""
    placement_at = frame_placements(default_spec(), probe(src), VideoOptions(), src)
    se, count, ssims = 0.0, 0, []
    with av.open(str(src)) as a, av.open(str(out)) as b:
        for i, (fa, fb) in enumerate(zip(a.decode(video=0), b.decode(video=0), strict=True)):
            ya, yb = _luma(fa), _luma(fb)
            keep = np.ones(ya.shape, bool)
            x0, y0, x1, y1 = placement_at(i).box
            keep[max(0, y0 - MARGIN) : y1 + MARGIN, max(0, x0 - MARGIN) : x1 + MARGIN] = False
            diff = (ya - yb)[keep]
            se += float(np.sum(diff * diff))
            count += diff.size
            if i % SSIM_EVERY == 0:
                _, smap = structural_similarity(ya, yb, data_range=255, full=True)
                ssims.append(float(smap[keep].mean()))
    mse = se / max(1, count)
    return (10 * np.log10(255**2 / mse) if mse else float("inf")), float(np.mean(ssims))


def frame_types(path: Path) -> str:
    with av.open(str(path)) as c:
        kinds = [av.video.frame.PictureType(int(f.pict_type)).name for f in c.decode(video=0)]
    return "/".join(f"{kinds.count(k)}" for k in ("I", "P", "B"))


@dataclass
class Row:
    clip: str
    way: str
    kb: float
    ratio: float
    psnr: float
    ssim: float
    types: str
    contrast: float | None
    seconds: float


def _poison(src: Path, dst: Path, *, source_types: bool, capped: bool = False) -> VideoReport:
    """poison_video with the encoder picking every frame type (ppd before) or given the source's, whatever
    the encoder (ppd gives x264 alone the source's: encoder.KEEP_FRAME_TYPES); capped: vbv_capped."""
    choose, kept = driver.choose_encoder, encoder.KEEP_FRAME_TYPES
    if capped:
        driver.choose_encoder = vbv_capped(choose)  # type: ignore[assignment]  # the bench's variant only
    encoder.KEEP_FRAME_TYPES = frozenset({"libx264", "libx265"})  # type: ignore[misc]  # measured on both
    try:
        return poison_video(src, dst, default_spec(), options=VideoOptions(keep_frame_types=source_types))
    finally:
        driver.choose_encoder, encoder.KEEP_FRAME_TYPES = choose, kept  # type: ignore[assignment, misc]


def measure(spec: ClipSpec, work: Path, seconds: float) -> tuple[list[Row], dict[str, Any]]:
    src = make_clip(spec, work / f"{spec.name}.mp4", seconds)
    base = src.stat().st_size
    info = probe(src)
    crf, rate = dict(spec.options).get("crf"), (info.bit_rate or 0) / 1e6
    facts = {"clip": spec.name, "source": f"{spec.width}x{spec.height} {info.codec} CRF {crf}, "
             f"{base / 1024:.0f} KB, {rate:.2f} Mbit/s, frames I/P/B {frame_types(src)}"}  # fmt: skip
    ways: list[tuple[str, Callable[[Path], VideoReport | None]]] = [
        ("no mark (floor)", lambda d: floor_transcode(src, d)),
        ("encoder picks the frame types (ppd before)", lambda d: _poison(src, d, source_types=False)),
        ("the source's frame types", lambda d: _poison(src, d, source_types=True)),
        ("the source's frame types + VBV cap at its rate",
         lambda d: _poison(src, d, source_types=True, capped=True)),
    ]
    rows = []
    for k, (way, write) in enumerate(ways):
        dst = work / f"{spec.name}.{k}.mp4"
        t0 = time.perf_counter()
        report = write(dst)
        took = time.perf_counter() - t0
        psnr, ssim = quality_outside(src, dst)
        size = dst.stat().st_size
        contrast = report.patch_contrast_min if report is not None else None
        row = Row(spec.name, way, size / 1024, size / base, psnr, ssim, frame_types(dst), contrast, took)
        rows.append(row)
        print(f"{spec.name}: {way}: {row.kb:.0f} KB ({row.ratio:.2f}x), {psnr:.2f} dB, SSIM {ssim:.4f}, "
              f"I/P/B {row.types}, contrast {contrast}, {took:.1f} s", flush=True)  # fmt: skip
    return rows, facts


def _round(rows: list[Row], facts: list[dict[str, Any]], seconds: float) -> list[str]:
    lines = [
        ROUND_TITLE,
        "",
        f"Machine: {platform.machine()}, Python {platform.python_version()}, PyAV {av.__version__}; "
        f"`python -m bench.bench_video_size --seconds {seconds:g}`. Each clip: {seconds:g} s at 30 fps, a "
        "crop panning across one photo of the shared datasets, coded as ffmpeg does by default (x264 CRF 23 "
        "preset medium; x265 CRF 28); ppd's default spec. Quality: luma PSNR (all frames) and SSIM (every "
        "3rd) against the decoded source outside the mark's box + 16 px. Frames: I/P/B counts of the "
        "output. Contrast: the mark's minimum over frames (ppd re-encodes below 0.8). KB: 1024 bytes. "
        "ppd now gives x264 the source's frame types where the source has B-frames "
        "(`poisoner.video.encoder.KEEP_FRAME_TYPES`); x265 and a source without B-frames keep the "
        "encoder's choice.",
        "",
    ]
    lines += [f"- {f['clip']}: {f['source']}" for f in facts]
    lines += ["", "| clip | written | KB | x source | PSNR out dB | SSIM out | I/P/B | mark contrast | s |",
              "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        contrast = f"{r.contrast:.3f}" if r.contrast is not None else "-"
        lines.append(f"| {r.clip} | {r.way} | {r.kb:.0f} | {r.ratio:.2f} | {r.psnr:.2f} | {r.ssim:.4f} | "
                     f"{r.types} | {contrast} | {r.seconds:.1f} |")  # fmt: skip
    return lines


BENCH_VIDEO_TITLE = "# Video benchmark (bench/bench_video.py)"  # where bench_video's own sections start


def write_round(lines: list[str]) -> None:
    """The round at the top of video.md, in place of an earlier one; bench_video's sections below."""
    old = RESULTS.read_text() if RESULTS.exists() else ""
    rest = old[old.index(BENCH_VIDEO_TITLE) :] if BENCH_VIDEO_TITLE in old else ""
    RESULTS.write_text("# Video benchmarks\n\n" + "\n".join(lines) + "\n\n" + rest)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--only", nargs="*", default=None)
    args = parser.parse_args()
    rows: list[Row] = []
    facts = []
    with tempfile.TemporaryDirectory(prefix="ppd-bench-video-size-") as tmp:
        for spec in CLIPS:
            if args.only and spec.name not in args.only:
                continue
            got, fact = measure(spec, Path(tmp), args.seconds)
            rows += got
            facts.append(fact)
    write_round(_round(rows, facts, args.seconds))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
