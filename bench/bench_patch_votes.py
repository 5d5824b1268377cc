"""Issue #9: how many of COLMAP's votes a patch gets (`python -m bench.bench_patch_votes`).

Why a textured scene resists: every RANSAC and bundle adjustment is a vote, and the patch's
keypoints are few next to the scene's. This measures that share directly, per design and
dataset, with COLMAP's own SIFT (pycolmap 4.2.1, default extraction options: at most 8192
keypoint locations with up to 2 orientations each, so more than 8192 descriptors on large images;
images above 3200 px downscaled) on consecutive pairs of poisoned images:

- keypoints: the fraction of an image's kept keypoints inside its patch box, and the patch's share
  of the image area;
- tentative matches: mutual nearest neighbours passing Lowe's ratio test (0.8, COLMAP's default),
  and the fraction whose two ends both lie in the two patch boxes (the votes for the phantom
  geometry) against all of them (the scene's votes outnumber them by the ratio shown).

Geometric verification comes after this and only removes matches, so the tentative share is an
upper bound on the patch's share of the inliers. Writes bench/results/patch_votes.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image  # PIL before pycolmap (pillow 13 + pycolmap 4.2.1 PNG-write crash)

from bench.bench_designs import DESIGNS, setup_dataset
from poisoner.blend import apply_patch

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "patch_votes.md"
MAX_IMAGE_SIZE = 3200  # COLMAP's FeatureExtractionOptions.max_image_size default


def gray_for_colmap(rgb: np.ndarray) -> tuple[np.ndarray, float]:
    """Grey image as COLMAP's extractor sees it (downscaled to max_image_size) and the scale."""
    image = Image.fromarray(rgb).convert("L")
    scale = min(1.0, MAX_IMAGE_SIZE / max(image.size))
    if scale < 1.0:
        image = image.resize((round(image.width * scale), round(image.height * scale)), Image.BICUBIC)
    return np.ascontiguousarray(np.asarray(image, dtype=np.uint8)), scale


def inside(points: np.ndarray, box: tuple[int, int, int, int], scale: float) -> np.ndarray:
    x0, y0, x1, y1 = (v * scale for v in box)
    return (points[:, 0] >= x0) & (points[:, 0] < x1) & (points[:, 1] >= y0) & (points[:, 1] < y1)


def ratio_matches(d1: np.ndarray, d2: np.ndarray, ratio: float = 0.8) -> np.ndarray:
    """Mutual nearest neighbours that pass the ratio test: (k, 2) index pairs."""
    a = d1.astype(np.float32)
    b = d2.astype(np.float32)
    a /= np.linalg.norm(a, axis=1, keepdims=True) + 1e-12
    b /= np.linalg.norm(b, axis=1, keepdims=True) + 1e-12
    sim = a @ b.T
    order = np.argsort(-sim, axis=1)[:, :2]
    best, second = sim[np.arange(len(a)), order[:, 0]], sim[np.arange(len(a)), order[:, 1]]
    dist_best = np.sqrt(np.maximum(2 - 2 * best, 0))
    dist_second = np.sqrt(np.maximum(2 - 2 * second, 0))
    ok = dist_best < ratio * dist_second
    back = np.argmax(sim, axis=0)
    mutual = back[order[:, 0]] == np.arange(len(a))
    keep = np.nonzero(ok & mutual)[0]
    return np.stack([keep, order[keep, 0]], axis=1)


def measure(dataset: str, design: str, pairs: int) -> dict[str, float]:
    import pycolmap

    ds = setup_dataset(dataset)
    spec = DESIGNS[design].spec
    names = sorted(p.name for p in ds.clean.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    sift = pycolmap.Sift(pycolmap.FeatureExtractionOptions(), device=pycolmap.Device.cpu)
    feats = []
    for name in names[: pairs + 1]:
        rgb = np.asarray(Image.open(ds.clean / name).convert("RGB"))
        placement = spec.resolve(rgb.shape[1], rgb.shape[0], image_key=name)
        gray, scale = gray_for_colmap(apply_patch(rgb, placement))
        keypoints, descriptors = sift.extract(gray)
        area = placement.size**2 / (rgb.shape[0] * rgb.shape[1])
        feats.append((keypoints, descriptors, inside(keypoints, placement.box, scale), area))
    kp_share = [float(f[2].mean()) for f in feats]
    match_share, totals = [], []
    for (_, d1, in1, _), (_, d2, in2, _) in zip(feats, feats[1:], strict=False):
        m = ratio_matches(d1, d2)
        both = in1[m[:, 0]] & in2[m[:, 1]]
        match_share.append(float(both.mean()) if len(m) else 0.0)
        totals.append(len(m))
    return {
        "keypoints": float(np.mean([len(f[0]) for f in feats])),
        "kp_share": float(np.mean(kp_share)),
        "area_share": float(np.mean([f[3] for f in feats])),
        "matches": float(np.mean(totals)),
        "match_share": float(np.mean(match_share)),
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_patch_votes")
    ap.add_argument("--datasets", default="lego,fountain,synth")
    ap.add_argument(
        "--designs", default="paper-checkerboard-6pct,texture-6pct-drift,ms-8pct-b0.5pct-drift-1.3pct"
    )
    ap.add_argument("--pairs", type=int, default=3, help="consecutive image pairs per dataset")
    args = ap.parse_args(argv if argv is not None else sys.argv[1:])
    lines = [
        "# How many of COLMAP's votes the patch gets (issue 9)",
        "",
        f"`python -m bench.bench_patch_votes {' '.join(argv if argv is not None else sys.argv[1:])}`: "
        f"COLMAP's SIFT (pycolmap, default extraction: 8192 keypoint locations, up to 2 orientations "
        f"each, long edge <= 3200 px) on the first {args.pairs + 1} poisoned images; "
        "tentative matches = mutual nearest neighbours passing the 0.8 ratio test on consecutive pairs. "
        "scene : patch = how many scene matches stand against each patch match.",
        "",
        "| dataset | design | patch area | keypoints / image | in the patch | tentative matches / pair "
        "| patch-to-patch | scene : patch |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for dataset in args.datasets.split(","):
        for design in args.designs.split(","):
            r = measure(dataset, design, args.pairs)
            odds = (1 - r["match_share"]) / r["match_share"] if r["match_share"] > 0 else float("inf")
            line = (
                f"| {dataset} | {design} | {100 * r['area_share']:.2f}% | {r['keypoints']:.0f} | "
                f"{100 * r['kp_share']:.1f}% | {r['matches']:.0f} | {100 * r['match_share']:.1f}% | "
                f"{odds:.1f} : 1 |"
            )
            print(line, flush=True)
            lines.append(line)
    RESULTS.write_text("\n".join(lines) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
