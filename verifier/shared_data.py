"""The project's shared real datasets (../shared/datasets next to the checkout), prepared the
one way the benchmarks, `ppd experiment lego` and the tests read them.

lego: NeRF-Synthetic's first n training views composited on white (as 3DGS does), RGB PNG, with
its transforms_train.json as ground truth. fountain-P11: the images and gt_dense_cameras as they are.
"""

from __future__ import annotations

from pathlib import Path

SHARED = Path(__file__).resolve().parents[2] / "shared" / "datasets"
WORK = Path("/tmp/ppd-bench-verify")  # composited views, reused between runs
LEGO_SIZE = 800  # px, each side


def prepare_lego(n_views: int, work: Path = WORK) -> tuple[Path, Path, int]:
    """(folder of the first n views on white, ground truth file, image size)."""
    import numpy as np
    from PIL import Image

    from poisoner.atomic import atomic_output

    src = SHARED / "nerf_synthetic_lego"
    dst = work / "lego" / "clean"
    dst.mkdir(parents=True, exist_ok=True)
    for i in range(n_views):
        out = dst / f"r_{i}.png"
        if out.exists():
            continue
        with Image.open(src / "train" / f"r_{i}.png") as im:
            rgba = np.asarray(im.convert("RGBA")).astype(np.float64)
        rgb = rgba[..., :3] * rgba[..., 3:] / 255 + 255 * (1 - rgba[..., 3:] / 255)
        with atomic_output(out) as tmp:  # an interrupted run leaves no half-written view behind
            Image.fromarray(np.floor(rgb + 0.5).astype(np.uint8)).save(tmp, format="PNG")
    return dst, src / "transforms_train.json", LEGO_SIZE


def prepare_fountain() -> tuple[Path, Path]:
    """(fountain-P11's images, its gt_dense_cameras folder)."""
    return SHARED / "fountain_P11" / "images", SHARED / "fountain_P11" / "gt_dense_cameras"
