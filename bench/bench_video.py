"""Video benchmark: poison_video throughput on 1080p H.264 (2 encoder threads) against the floor
(decode + encode with the same encoder settings, no patch), and the patch's survival through
each encoder as a function of CRF. Writes bench/results/video.md.

    python -m bench.bench_video [--seconds 5] [--skip-sweep]
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import av
import numpy as np

from poisoner.spec import PatchSpec
from poisoner.video import VideoOptions, choose_encoder, poison_video, probe
from testkit.video import mux_rgb_frames, mux_sine

RESULTS = Path(__file__).resolve().parent / "results" / "video.md"
THREADS = 2


def textured_frame(width: int, height: int, index: int, tex: np.ndarray) -> np.ndarray:
    """A textured scene panning under the camera (blocks of several sizes, like real detail)."""
    dy, dx = (index * 2) % 64, index * 6
    return np.ascontiguousarray(tex[dy : dy + height, dx : dx + width])



def make_source(path: Path, width: int, height: int, fps: int, seconds: float, crf: int = 20) -> Path:
    rng = np.random.default_rng(11)
    coarse = rng.random((height // 16 + 8, (width + 6 * int(fps * seconds)) // 16 + 8, 3))
    fine = rng.random((coarse.shape[0] * 16, coarse.shape[1] * 16, 3))
    tex = (coarse.repeat(16, 0).repeat(16, 1) * 170 + fine * 60 + 10).astype(np.uint8)
    with av.open(str(path), "w") as out:
        vs = out.add_stream("libx264", rate=fps, options={"crf": str(crf), "preset": "veryfast"})
        vs.width, vs.height, vs.pix_fmt = width, height, "yuv420p"
        aud = out.add_stream("aac", rate=48000)
        aud.layout = "stereo"
        n = int(round(fps * seconds))
        mux_rgb_frames(out, vs, (textured_frame(width, height, i, tex) for i in range(n)))
        mux_sine(out, aud, int(seconds * 48000), hz=330, amplitude=0.2, fmt="fltp", layout="stereo")
    return path


def floor_transcode(src: Path, dst: Path, options: VideoOptions) -> int:
    """Decode + encode with poison_video's encoder choice, no patch, no verification pass."""
    info = probe(src)
    choice = choose_encoder(info, options)
    n = 0
    with av.open(str(src)) as inp, av.open(str(dst), "w", format=info.muxer) as out:
        vin = inp.streams.video[0]
        vin.thread_type = "AUTO"
        vs = out.add_stream(choice.encoder, rate=info.average_rate, options=dict(choice.options))
        vs.width, vs.height, vs.pix_fmt = info.width, info.height, info.pix_fmt
        vs.time_base = vs.codec_context.time_base = info.time_base
        vs.codec_context.thread_count = options.threads
        for frame in inp.decode(vin):
            frame.pict_type = av.video.frame.PictureType.NONE
            for pkt in vs.encode(frame):
                out.mux(pkt)
            n += 1
        for pkt in vs.encode(None):
            out.mux(pkt)
    return n


@dataclass
class Timing:
    label: str
    frames: int
    seconds: float

    @property
    def fps(self) -> float:
        return self.frames / self.seconds


def throughput(work: Path, seconds: float) -> tuple[list[Timing], dict[str, object]]:
    src = make_source(work / "src1080.mp4", 1920, 1080, 30, seconds)
    options = VideoOptions(threads=THREADS)
    timings: list[Timing] = []
    t0 = time.perf_counter()
    n = floor_transcode(src, work / "floor.mp4", options)
    timings.append(Timing("floor: decode + encode, same settings, no patch", n, time.perf_counter() - t0))
    t0 = time.perf_counter()
    rep = poison_video(
        src, work / "nover.mp4", PatchSpec(), options=VideoOptions(threads=THREADS, verify_patch=False)
    )
    timings.append(Timing("poison_video, no patch check", rep.frames, time.perf_counter() - t0))
    t0 = time.perf_counter()
    rep = poison_video(src, work / "poisoned.mp4", PatchSpec(), options=options)
    timings.append(
        Timing("poison_video (default: patch check on output)", rep.frames, time.perf_counter() - t0)
    )
    facts: dict[str, object] = {
        "source": f"{rep.width}x{rep.height} {rep.codec} {rep.pix_fmt}, {rep.frames} frames, "
        f"{(rep.source_bit_rate or 0) / 1e6:.2f} Mbit/s",
        "encoder": f"{rep.encoder} crf={rep.crf} preset={options.preset} threads={THREADS}",
        "output bitrate": f"{(rep.output_bit_rate or 0) / 1e6:.2f} Mbit/s "
        f"({(rep.output_bit_rate or 0) / max(1, rep.source_bit_rate or 1):.2f} x source)",
        "patch contrast after encoding (min / mean over frames)": (
            f"{rep.patch_contrast_min:.3f} / {rep.patch_contrast_mean:.3f}"
        ),
        "placement": str(rep.placement),
    }
    return timings, facts


SWEEP = {
    "libx264": [18, 23, 28, 33, 38, 43],
    "libx265": [18, 24, 30, 36, 42],
    "libvpx-vp9": [20, 30, 40, 50, 60],
    "libsvtav1": [20, 30, 42, 50, 60],
}
SWEEP_CODEC_SOURCE = {
    "libx264": "libx264",
    "libx265": "libx265",
    "libvpx-vp9": "libvpx-vp9",
    "libsvtav1": "libsvtav1",
}
SWEEP_SUFFIX = {"libx264": ".mp4", "libx265": ".mp4", "libvpx-vp9": ".webm", "libsvtav1": ".mkv"}


def sweep_source(work: Path, encoder: str) -> Path:
    """A 640x360 textured clip (2 s at 24 fps) in the encoder's own codec, near-lossless."""
    path = work / f"sweep_{encoder}{SWEEP_SUFFIX[encoder]}"
    rng = np.random.default_rng(5)
    coarse = rng.random((360 // 16 + 8, (640 + 6 * 48) // 16 + 8, 3))
    tex = (coarse.repeat(16, 0).repeat(16, 1) * 200 + 20).astype(np.uint8)
    quality = {
        "libx264": {"crf": "12", "preset": "veryfast"},
        "libx265": {"crf": "12", "preset": "ultrafast", "x265-params": "log-level=error"},
        "libvpx-vp9": {"crf": "15", "b": "0", "cpu-used": "8"},
        "libsvtav1": {"crf": "15", "preset": "10", "svtav1-params": "log-level=1"},
    }[encoder]
    with av.open(str(path), "w") as out:
        vs = out.add_stream(encoder, rate=24, options=quality)
        vs.width, vs.height, vs.pix_fmt = 640, 360, "yuv420p"
        for i in range(48):
            f = av.VideoFrame.from_ndarray(textured_frame(640, 360, i, tex), format="rgb24").reformat(
                format="yuv420p"
            )
            f.pts = i
            for pkt in vs.encode(f):
                out.mux(pkt)
        for pkt in vs.encode(None):
            out.mux(pkt)
    return path


def survival_sweep(work: Path) -> list[tuple[str, int, int, float, float, float]]:
    """(encoder, block, crf, min contrast ratio, mean contrast ratio, Mbit/s) per setting."""
    rows = []
    for encoder, crfs in SWEEP.items():
        src = sweep_source(work, encoder)
        for block in (2, 4):
            spec = PatchSpec(patch_size=40, block_size=block)
            for crf in crfs:
                opts = VideoOptions(
                    crf_override=crf, min_patch_contrast=0.0, max_retries=0, preset="veryfast"
                )
                rep = poison_video(src, work / f"s{SWEEP_SUFFIX[encoder]}", spec, options=opts)
                rows.append(
                    (
                        encoder,
                        block,
                        crf,
                        rep.patch_contrast_min or 0.0,
                        rep.patch_contrast_mean or 0.0,
                        (rep.output_bit_rate or 0) / 1e6,
                    )
                )
                print(rows[-1], flush=True)
    return rows


def render_scene_video(path: Path, opts: Any, fps: int, crf: int) -> list[Any]:
    """verifier.synthetic's scene from opts' cameras, one frame per camera, as H.264; the poses."""
    from verifier.synthetic import camera_poses, render_view, scene_rects

    rects = scene_rects(opts.seed, opts.backdrop)
    poses = camera_poses(opts)
    with av.open(str(path), "w") as out:
        vs = out.add_stream("libx264", rate=fps, options={"crf": str(crf), "preset": "veryfast"})
        vs.width, vs.height, vs.pix_fmt = opts.width, opts.height, "yuv420p"
        mux_rgb_frames(out, vs, (render_view(rot, trans, opts, rects) for rot, trans in poses))
    return poses


def pose_check(work: Path, views: int = 48, every_k: int = 2) -> list[str]:
    """verifier.verify_folders on frames sampled from a clean and a poisoned video of
    verifier.synthetic's textured scene seen from a camera moving along an arc."""
    import PIL.Image  # noqa: F401  (PIL before pycolmap, which the verifier's children import)

    from poisoner.video import sample_frames
    from verifier.synthetic import SyntheticOptions, write_ground_truth
    from verifier.verification import VerifyOptions, verify_folders

    opts = SyntheticOptions(
        num_views=views, width=480, height=320, focal=576.0, arc_deg=90.0, elevation_jitter_deg=0.0
    )
    clean_video = work / "scene.mp4"
    poses = render_scene_video(clean_video, opts, fps=24, crf=18)
    poisoned_video = work / "scene_poisoned.mp4"
    rep = poison_video(clean_video, poisoned_video, PatchSpec())
    clean_frames = sample_frames(clean_video, work / "pose_clean", every_k=every_k)
    sample_frames(poisoned_video, work / "pose_poisoned", every_k=every_k)
    gt = work / "gt.json"
    write_ground_truth(gt, {p.name: poses[int(p.stem.split("_")[1])] for p in clean_frames}, opts)
    t0 = time.perf_counter()
    report = verify_folders(
        work / "pose_clean",
        work / "pose_poisoned",
        work / "pose_out",
        profiles=("default", "hardened"),
        options=VerifyOptions(ground_truth=gt),
    )
    elapsed = time.perf_counter() - t0
    lines = [
        f"- video: {views} frames {opts.width}x{opts.height} H.264 crf 18, "
        f"camera on a {opts.arc_deg:.0f} deg arc; "
        f"poisoned with the default spec ({rep.placement}), {rep.encoder} crf={rep.crf}, "
        f"patch contrast min {rep.patch_contrast_min:.3f}",
        f"- frames sampled every {every_k}: {len(clean_frames)} per side; "
        f"verify_folders took {elapsed:.0f} s; "
        f"overall verdict: {report.verdict}",
        "",
    ]
    lines += [
        "| profile | verdict | clean | poisoned | clean vs GT | poisoned vs GT | poisoned vs clean |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, pr in report.profiles.items():
        lines.append(
            f"| {name} | {pr.verdict} | {_short(pr.clean)} | {_short(pr.poisoned)} | "
            f"{_short(pr.clean_vs_gt)} | {_short(pr.poisoned_vs_gt)} | {_short(pr.vs_clean)} |"
        )
    lines += ["", "Reasons: " + "; ".join(f"{n}: {', '.join(p.reasons)}" for n, p in report.profiles.items())]
    return lines


def _short(d: dict | None) -> str:
    if not d:
        return "-"
    keep = {k: v for k, v in d.items() if not isinstance(v, dict | list)}
    return ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in keep.items())


def write_results(
    timings: list[Timing], facts: dict[str, object], sweep: list | None, pose: list[str] | None = None
) -> None:
    lines = [
        "# Video benchmark (bench/bench_video.py)",
        "",
        f"Machine: {platform.machine()}, {platform.python_version()}, PyAV {av.__version__}; "
        f"encoder threads = {THREADS}.",
        "",
        "## Throughput, 1080p H.264",
        "",
    ]
    lines += [f"- {k}: {v}" for k, v in facts.items()]
    lines += ["", "| run | frames | seconds | frames/s | vs floor |", "|---|---|---|---|---|"]
    floor = timings[0].fps
    for t in timings:
        lines.append(f"| {t.label} | {t.frames} | {t.seconds:.1f} | {t.fps:.1f} | {t.fps / floor:.2f} |")
    if sweep:
        lines += [
            "",
            "## Patch survival vs CRF (640x360 textured clip, patch 40 px, contrast 255, alpha 1)",
            "",
            "Contrast ratio = mean(bright blocks) - mean(dark blocks) on decoded output / intended "
            "(255); min over 48 frames.",
            "",
            "| encoder | block px | CRF | min ratio | mean ratio | Mbit/s |",
            "|---|---|---|---|---|---|",
        ]
        for enc, block, crf, mn, mean, mbps in sweep:
            lines.append(f"| {enc} | {block} | {crf} | {mn:.3f} | {mean:.3f} | {mbps:.2f} |")
    if pose:
        lines += ["", "## Pose verification on sampled frames (verifier.verify_folders)", "", *pose]
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    # bench_video_size's round stays above these sections
    old = RESULTS.read_text() if RESULTS.exists() else ""
    above = old[: old.index(lines[0])] if lines[0] in old else ""
    RESULTS.write_text(above + "\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--skip-sweep", action="store_true")
    parser.add_argument("--skip-throughput", action="store_true")
    parser.add_argument("--skip-pose", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="ppd-bench-video-") as tmp:
        work = Path(tmp)
        sweep = None if args.skip_sweep else survival_sweep(work)
        timings, facts = ([], {}) if args.skip_throughput else throughput(work, args.seconds)
        pose = None if args.skip_pose else pose_check(work)
        for line in pose or []:
            print(line)
        for t in timings:
            print(f"{t.label}: {t.frames} frames in {t.seconds:.1f} s = {t.fps:.1f} frames/s")
        for k, v in facts.items():
            print(f"{k}: {v}")
        if timings:
            write_results(timings, facts, sweep, pose)
            print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
