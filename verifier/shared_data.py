"""The project's shared real datasets, prepared the one way the benchmarks, `ppd experiment lego`
and the tests read them.

Where they are is the user's to say (`--shared-data DIR`, or $PPD_SHARED_DATA): an installed ppd
has no checkout beside it to look in. The tests (tests/conftest.py) and the benchmarks
(bench/__init__.py) point the variable at the datasets beside the checkout.

lego: NeRF-Synthetic's first n training views composited on white (as 3DGS does), RGB PNG, with
its transforms_train.json as ground truth. fountain-P11: the images and gt_dense_cameras as they are.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "PPD_SHARED_DATA"
WORK = Path("/tmp/ppd-bench-verify")  # composited views, reused between runs
LEGO_SIZE = 800  # px, each side


class SharedDataMissing(RuntimeError):
    """The shared datasets' folder was not given, or is not there; the message is one line."""


def shared_root(given: Path | None = None) -> Path:
    """The folder holding nerf_synthetic_lego/, fountain_P11/, ...: `given`, else $PPD_SHARED_DATA."""
    raw = given if given is not None else os.environ.get(ENV_VAR)
    if not raw:
        raise SharedDataMissing(f"shared datasets: not told where; give --shared-data DIR or set {ENV_VAR}")
    root = Path(raw).expanduser()
    if not root.is_dir():
        raise SharedDataMissing(f"shared datasets not found at {root} (--shared-data / {ENV_VAR})")
    return root


def prepare_lego(n_views: int, work: Path = WORK, root: Path | None = None) -> tuple[Path, Path, int]:
    """(folder of the first n views on white, ground truth file, image size)."""
    import numpy as np
    from PIL import Image

    from poisoner.atomic import atomic_output

    src = shared_root(root) / "nerf_synthetic_lego"
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


def prepare_fountain(root: Path | None = None) -> tuple[Path, Path]:
    """(fountain-P11's images, its gt_dense_cameras folder)."""
    fountain = shared_root(root) / "fountain_P11"
    return fountain / "images", fountain / "gt_dense_cameras"
