"""COLMAP's own view of a few images, for bench_textured: features kept and verified pairs.

`pair_stats(image_dir, ...)` runs `python -m bench.textured_colmap` in a child process (pycolmap can
segfault, and is never imported by the parent): COLMAP SIFT extraction into a fresh database, exact
matching of consecutive images (sequential pairing, overlap 1), then COLMAP's geometric verification
with its default two-view options. It returns, per image, the keypoints kept and the smallest kept
scale, and per consecutive pair the tentative matches, the verified inliers and the model type.
`keypoints(image_path)` returns COLMAP's kept keypoints (x, y, scale, orientation) of one image.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image  # PIL before pycolmap (pillow + pycolmap 4.2.1 crash otherwise)

ROOT = Path(__file__).resolve().parents[1]


def _run_child(job: dict[str, Any], timeout_s: float = 1800) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="ppd-tex-") as tmp:
        out = Path(tmp) / "out.json"
        job = {**job, "out": str(out), "tmp": tmp}
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        proc = subprocess.run(
            ["nice", "-n", "10", sys.executable, "-m", "bench.textured_colmap"],
            input=json.dumps(job).encode(),
            capture_output=True,
            env=env,
            timeout=timeout_s,
        )
        if proc.returncode != 0 or not out.exists():
            tail = proc.stderr.decode(errors="replace")[-500:]
            raise RuntimeError(f"COLMAP child exited {proc.returncode}: {tail}")
        return json.loads(out.read_text())


def pair_stats(
    image_dir: Path,
    names: list[str],
    max_num_features: int = 8192,
    boxes: dict[str, tuple[int, int, int, int]] | None = None,
) -> dict[str, Any]:
    """Features kept per image and verified inliers per consecutive pair (COLMAP defaults).

    boxes: per image name, a window (x0, y0, x1, y1); each pair then also reports `inliers_in_box`,
    its verified inliers with an end inside the window of either image."""
    return _run_child(
        {
            "kind": "pairs",
            "image_dir": str(image_dir),
            "names": names,
            "max_num_features": max_num_features,
            "boxes": boxes or {},
        }
    )


def _in_box(xy: np.ndarray, box: list[int] | None) -> np.ndarray:
    if box is None:
        return np.zeros(len(xy), bool)
    x0, y0, x1, y1 = box
    return (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)


def keypoints(image_path: Path, max_num_features: int = 8192) -> np.ndarray:
    """COLMAP's kept SIFT keypoints of one image, (N, 4): x, y, scale, orientation (full-size pixels)."""
    res = _run_child({"kind": "keypoints", "image": str(image_path), "max_num_features": max_num_features})
    return np.asarray(res["keypoints"], np.float32).reshape(-1, 4)


def descriptors(image_path: Path, box: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's keypoints (window coordinates) and unit-norm descriptors of a window of one image."""
    res = _run_child(
        {"kind": "descriptors", "image": str(image_path), "box": list(box), "max_num_features": 8192}
    )
    return np.asarray(res["keypoints"], np.float32).reshape(-1, 4), np.asarray(res["descriptors"], np.float32)


# ---- child side ---------------------------------------------------------------------------------
def _extraction(max_num_features: int) -> Any:
    import pycolmap

    opts = pycolmap.FeatureExtractionOptions()
    opts.sift.max_num_features = max_num_features
    return opts


def _child_pairs(job: dict[str, Any]) -> dict[str, Any]:
    import pycolmap

    pycolmap.set_random_seed(0)
    db_path = Path(job["tmp"]) / "db.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "OPENCV"
    pycolmap.extract_features(
        db_path,
        job["image_dir"],
        image_names=job["names"],
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=_extraction(job["max_num_features"]),
        device=pycolmap.Device.cpu,
    )
    matching = pycolmap.FeatureMatchingOptions()
    matching.skip_geometric_verification = True
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = 1
    pairing.quadratic_overlap = False
    pycolmap.match_sequential(
        db_path, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu
    )
    two_view = pycolmap.TwoViewGeometryOptions()
    two_view.ransac.random_seed = 0
    pycolmap.geometric_verification(db_path, two_view_geometry_options=two_view)
    images: dict[str, Any] = {}
    pairs: list[dict[str, Any]] = []
    with pycolmap.Database.open(db_path) as db:
        by_name = {im.name: im for im in db.read_all_images()}
        for name in job["names"]:
            kp = db.read_keypoints(by_name[name].image_id)
            scales = (
                np.sqrt(np.abs(kp[:, 2] * kp[:, 5] - kp[:, 3] * kp[:, 4])) if kp.shape[1] >= 6 else kp[:, 2]
            )
            images[name] = {"keypoints": int(len(kp)), "min_scale": float(scales.min()) if len(kp) else None}
        for a, b in zip(job["names"], job["names"][1:], strict=False):
            ia, ib = by_name[a].image_id, by_name[b].image_id
            tentative = len(db.read_matches(ia, ib)) if db.exists_matches(ia, ib) else 0
            inliers, config, in_box = 0, "none", 0
            if db.exists_two_view_geometry(ia, ib):
                tvg = db.read_two_view_geometry(ia, ib)
                inliers = len(tvg.inlier_matches)
                config = str(tvg.config).split(".")[-1]
                if job.get("boxes") and inliers:
                    m = np.asarray(tvg.inlier_matches)
                    xa = db.read_keypoints(ia)[m[:, 0], :2]
                    xb = db.read_keypoints(ib)[m[:, 1], :2]
                    hit = _in_box(xa, job["boxes"].get(a)) | _in_box(xb, job["boxes"].get(b))
                    in_box = int(hit.sum())
            row = {"pair": f"{a}-{b}", "tentative": tentative, "inliers": inliers, "config": config}
            if job.get("boxes"):
                row["inliers_in_box"] = in_box
            pairs.append(row)
    return {"images": images, "pairs": pairs}


def _child_keypoints(job: dict[str, Any]) -> dict[str, Any]:
    import pycolmap

    opts = _extraction(job["max_num_features"])
    image = Image.open(job["image"]).convert("L")
    scale = 1.0
    if max(image.size) > 3200:  # COLMAP's max_image_size default
        scale = 3200 / max(image.size)
        image = image.resize((round(image.width * scale), round(image.height * scale)), Image.BICUBIC)
    sift = pycolmap.Sift(opts, device=pycolmap.Device.cpu)
    kp, _ = sift.extract(np.ascontiguousarray(np.asarray(image, np.uint8)))
    kp = np.asarray(kp, np.float64)
    kp[:, :3] /= scale
    return {"keypoints": kp.tolist()}


def _child_descriptors(job: dict[str, Any]) -> dict[str, Any]:
    import pycolmap

    x0, y0, x1, y1 = job["box"]
    gray = np.asarray(Image.open(job["image"]).convert("L"), np.uint8)[y0:y1, x0:x1]
    sift = pycolmap.Sift(_extraction(job["max_num_features"]), device=pycolmap.Device.cpu)
    kp, desc = sift.extract(np.ascontiguousarray(gray))
    desc = np.asarray(desc, np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True) + 1e-12
    return {"keypoints": np.asarray(kp).tolist(), "descriptors": desc.tolist()}


def _child_main() -> None:
    job = json.loads(sys.stdin.read())
    kinds = {"pairs": _child_pairs, "keypoints": _child_keypoints, "descriptors": _child_descriptors}
    result = kinds[job["kind"]](job)
    Path(job["out"]).write_text(json.dumps(result))


if __name__ == "__main__":
    _child_main()
