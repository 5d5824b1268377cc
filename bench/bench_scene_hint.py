"""The scene hint (poisoner/scene.py) on the shared sets and on variants of them: is it stable, and
does it rest on the mechanism rather than on three sets?

`python -m bench.bench_scene_hint` (or `python -m bench scene_hint`; ~1 min on a shared 2-core CPU)
writes bench/results/scene_hint.md. Variants: resizes (COLMAP's size and smaller), crops (the
subject filling more of the frame, off-centre, the support alone), sensor noise and a JPEG q85
re-encode on a plain background, and our own renders (verifier/synthetic.py) with a plain and a
textured backdrop over several seeds. Each variant writes the sample's images to a temporary folder
and calls `scene_hint` as `ppd auto` / `ppd poison` do.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from bench.results_page import rewrite_keeping_analysis
from poisoner.scene import SAMPLE, SceneHint, evenly_spaced, scene_hint
from verifier.synthetic import SyntheticOptions, render_scene

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "datasets"
RESULTS = ROOT / "bench" / "results" / "scene_hint.md"
SETS = {
    "lego": ("nerf_synthetic_lego/train", "*.png", 40),  # the first 40 views, as the benches use
    "dtu_scan37": ("dtu_scan37/images", "*.png", None),
    "fountain-P11": ("fountain_P11/images", "*.jpg", None),
}

Transform = Callable[[Image.Image], Image.Image]


def _on_white(im: Image.Image) -> Image.Image:
    if im.mode != "RGBA":
        return im.convert("RGB")
    out = Image.new("RGBA", im.size, (255, 255, 255, 255))
    out.alpha_composite(im)
    return out.convert("RGB")


def _width(w: int) -> Transform:
    return lambda im: im.resize((w, round(im.height * w / im.width)), Image.Resampling.LANCZOS)


def _crop(x0: float, y0: float, x1: float, y1: float) -> Transform:
    return lambda im: im.crop((round(x0 * im.width), round(y0 * im.height), round(x1 * im.width),
                               round(y1 * im.height)))  # fmt: skip


def _noise(sigma: float) -> Transform:
    def add(im: Image.Image) -> Image.Image:
        rng = np.random.default_rng(0)
        arr = np.asarray(im, dtype=np.float32) + rng.normal(0, sigma, (im.height, im.width, 3))
        return Image.fromarray(np.clip(arr, 0, 255).round().astype(np.uint8))

    return add


def _subject_fill(keep: float) -> Transform:
    """Issue 25: the subject filling the frame: `keep` of the frame around the bounding box of the
    pixels that are not the white backdrop (an object shot close up)."""

    def crop(im: Image.Image) -> Image.Image:
        fg = np.asarray(im.convert("L")) < 250
        ys, xs = np.nonzero(fg)
        cx, cy = (xs.min() + xs.max()) / 2, (ys.min() + ys.max()) / 2
        cw, ch = round(keep * im.width), round(keep * im.height)
        x0 = int(min(max(round(cx - cw / 2), 0), im.width - cw))
        y0 = int(min(max(round(cy - ch / 2), 0), im.height - ch))
        return im.crop((x0, y0, x0 + cw, y0 + ch))

    return crop


def _open_sky(share: float) -> Transform:
    """Issue 25: a façade under open sky: the top `share` of the frame replaced by a smooth sky
    (a vertical blue gradient, no texture), the façade below as photographed."""

    def sky(im: Image.Image) -> Image.Image:
        arr = np.array(im.convert("RGB"))
        rows = round(share * arr.shape[0])
        t = np.linspace(0, 1, rows)[:, None]
        top, horizon = np.array([70, 120, 200]), np.array([170, 200, 235])
        arr[:rows] = (top * (1 - t) + horizon * t)[:, None, :].round().astype(np.uint8)
        return Image.fromarray(arr)

    return sky


def _marked(name: str) -> Transform:
    """The picture as `ppd poison` leaves it: what the hint reads when it runs after poisoning."""
    from poisoner.blend import poison_array
    from poisoner.ladder import default_spec, named_spec

    spec = default_spec() if name == "default" else named_spec(name)
    return lambda im: Image.fromarray(poison_array(np.asarray(im), spec, image_key="view.png")[0])


VARIANTS: dict[str, list[tuple[str, Transform | None, str]]] = {
    "lego": [
        ("as published (800 px)", None, "png"), ("reduced to 400 px", _width(400), "png"),
        ("enlarged to 1600 px", _width(1600), "png"),
        ("centre crop 70%", _crop(0.15, 0.15, 0.85, 0.85), "png"),
        ("off-centre crop 60%", _crop(0.0, 0.0, 0.6, 0.6), "png"),
        ("sensor noise sigma 3 levels", _noise(3.0), "png"),
        ("sensor noise sigma 8 levels", _noise(8.0), "png"),
        ("JPEG q85", None, "jpg"), ("after ppd's default mark", _marked("default"), "png"),
        ("after the watermark mark", _marked("watermark"), "png"),
        ("subject filling the frame (55% around it)", _subject_fill(0.55), "png"),
    ],
    "dtu_scan37": [
        ("reduced to 800 px", _width(800), "png"), ("as published (1600 px)", None, "png"),
        ("centre crop 70%", _crop(0.15, 0.15, 0.85, 0.85), "png"),
        ("lower half (the support)", _crop(0.0, 0.5, 1.0, 1.0), "png"),
        ("upper half", _crop(0.0, 0.0, 1.0, 0.5), "png"), ("JPEG q85", None, "jpg"),
        ("after the watermark mark", _marked("watermark"), "png"),
        ("subject filling the frame (55% around it)", _subject_fill(0.55), "png"),
    ],
    "fountain-P11": [
        ("as published (3072 px)", None, "jpg"), ("reduced to 1600 px", _width(1600), "jpg"),
        ("reduced to 800 px", _width(800), "jpg"), ("centre crop 50%", _crop(0.25, 0.25, 0.75, 0.75), "jpg"),
        ("corner crop 40%", _crop(0.0, 0.0, 0.4, 0.4), "jpg"),
        ("façade under open sky (top 35% sky)", _open_sky(0.35), "jpg"),
        ("façade under open sky (top 50% sky)", _open_sky(0.5), "jpg"),
    ],
}  # fmt: skip


def _write_variant(
    sources: Sequence[Path], transform: Transform | None, suffix: str, out: Path
) -> list[Path]:
    out.mkdir(parents=True)
    written = []
    for src in sources:
        dst = out / f"{src.stem}.{suffix}"
        with Image.open(src) as im:
            if transform is None and suffix == src.suffix.lstrip("."):
                dst.write_bytes(src.read_bytes())  # the published file itself, alpha and all
            else:
                picture = _on_white(im)
                picture = transform(picture) if transform else picture
                picture.save(dst, quality=85) if suffix == "jpg" else picture.save(dst)
        written.append(dst)
    return written


def _measure(name: str, files: Sequence[Path]) -> tuple[SceneHint, float]:
    started = time.process_time()
    hint = scene_hint(name, files)
    assert hint is not None, name
    return hint, (time.process_time() - started) / hint.images


def _row(set_name: str, variant: str, size: str, hint: SceneHint, cpu: float) -> str:
    spread = f"{hint.textured_fraction_min:.0%}-{hint.textured_fraction_max:.0%}"
    frame = f"{hint.textured_fraction:.0%} ({spread})"
    fits = hint.mark_area_fraction > 0  # the default spec does not fit every crop's shape
    mark = f"{hint.mark_responses}" if fits else "n/a (does not fit)"
    area = f"{hint.mark_area_fraction:.2%}" if fits else "n/a"
    return (
        f"| {set_name} | {variant} | {size} | {hint.images} | {frame} | {hint.edge_textured_fraction:.0%} "
        f"| {hint.scene_responses} / {mark} | {area} | **{hint.kind}** | {cpu:.2f} |"
    )


def shared_rows(tmp: Path) -> list[str]:
    rows = []
    for set_name, (folder, pattern, first) in SETS.items():
        files = sorted((SHARED / folder).glob(pattern))[:first]
        if not files:
            continue
        sample = evenly_spaced(files, SAMPLE)
        for i, (variant, transform, suffix) in enumerate(VARIANTS[set_name]):
            written = _write_variant(sample, transform, suffix, tmp / f"{set_name}-{i}")
            with Image.open(written[0]) as im:
                size = f"{im.width}x{im.height}"
            hint, cpu = _measure(set_name, written)
            rows.append(_row(set_name, variant, size, hint, cpu))
            print(rows[-1], flush=True)
    return rows


RENDERS = [  # (seed, width, camera distance, elevation): the subject smaller or larger in the frame
    (0, 320, 7.0, 25.0),
    (0, 640, 7.0, 25.0),
    (1, 640, 7.0, 25.0),
    (2, 640, 5.0, 15.0),
    (3, 640, 10.0, 40.0),
]


def render_rows(tmp: Path) -> list[str]:
    rows = []
    for backdrop in ("plain", "textured"):
        for seed, width, radius, elevation in RENDERS:
            opts = SyntheticOptions(num_views=SAMPLE, width=width, height=width * 3 // 4, seed=seed,
                                    focal=1.2 * width, radius=radius, elevation_deg=elevation,
                                    backdrop=backdrop)  # fmt: skip
            out = tmp / f"render-{backdrop}-{seed}-{width}-{radius}"
            render_scene(out, opts)
            hint, cpu = _measure("render", sorted(out.glob("*.png")))
            variant = f"seed {seed}, distance {radius:g}, elevation {elevation:g}°"
            rows.append(_row(f"render, {backdrop} backdrop", variant, f"{width}x{opts.height}", hint, cpu))
            print(rows[-1], flush=True)
    return rows


HEADER = [
    "# Scene hint: how much of the frame carries texture, against what ppd's mark adds (issue 14)",
    "",
    "`python -m bench.bench_scene_hint` ({when}). poisoner/scene.py's `scene_hint` on {sample} evenly",
    "spaced images per set (what `ppd auto` and `ppd poison` print). Frame textured: share of cells (2% of",
    "the width, at most 800 px wide) whose DoG (sigma 1 vs 2 px) reaches COLMAP's SIFT peak threshold",
    "0.02/3; median over the sample (min-max). Edge band: the same share in the outer 10% of each side.",
    "Kind: richly-textured when the frame is >= 80% textured; else plain when the edge band is < 20%",
    "textured; else textured-support. DoG responses: local maxima at or above the threshold per frame,",
    "the scene's (median) / the default mark's alone on the same frame. CPU: process time per image,",
    "decoding included.",
    "",
    "| set | variant | size | images | frame textured | edge band | DoG responses scene / mark | mark area "
    "| kind | CPU s / image |",
    "|---|---|---|---|---|---|---|---|---|---|",
]


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="ppd-scene-hint-") as tmp:
        rows = shared_rows(Path(tmp)) + render_rows(Path(tmp))
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    lines = [line.format(when=when, sample=SAMPLE) for line in HEADER] + rows
    rewrite_keeping_analysis(RESULTS, lines)
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
