"""Loading training scenes: images at the working resolution plus cameras and initial points.

`load_colmap_scene` reads a COLMAP sparse model written by pycolmap (imported here only, i.e.
only in the verification child / tests / bench). `load_blender_scene` reads NeRF-Synthetic's
transforms_train.json (ground-truth poses) for the benchmark.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import PIL.Image  # before pycolmap (pillow 13 + pycolmap 4.2.1 crash otherwise)
import torch

from verifier.splat.camera import Camera, camera_from_blender


@dataclass
class Scene:
    cameras: list[Camera]  # at the working resolution
    images: list[torch.Tensor]  # 3 x H x W float32 in [0, 1], matching cameras
    names: list[str]
    points: np.ndarray  # M x 3 initial points
    colours: np.ndarray  # M x 3 in [0, 1]


def load_rgb(path: Path, size: tuple[int, int] | None, background: tuple[float, float, float]) -> np.ndarray:
    """H x W x 3 float32 in [0, 1]; alpha composited over background; resized (bicubic, as 3DGS)."""
    with PIL.Image.open(path) as im:
        im.load()
        rgba = im.convert("RGBA")
    if size is not None and rgba.size != size:
        rgba = rgba.resize(size, PIL.Image.Resampling.BICUBIC)
    arr = np.asarray(rgba, dtype=np.float32) / 255.0
    alpha = arr[..., 3:4]
    return arr[..., :3] * alpha + np.asarray(background, dtype=np.float32) * (1.0 - alpha)


def to_chw(arr: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(arr)).permute(2, 0, 1).contiguous()


def _rigid(image: Any) -> tuple[np.ndarray, np.ndarray]:  # a pycolmap.Image (pycolmap ships no types)
    pose = image.cam_from_world
    pose = pose() if callable(pose) else pose  # a method in pycolmap 4.x, a property before
    rot = np.asarray(pose.rotation.matrix(), dtype=np.float64)
    return rot, np.asarray(pose.translation, dtype=np.float64)


def load_colmap_scene(model_dir: Path, images_dir: Path, long_edge: int,
                      background: tuple[float, float, float], max_points: int, seed: int = 0) -> Scene:
    """Registered images of a COLMAP model with their SfM poses, and its 3D points.

    Intrinsics come from the calibration matrix (fx, fy, cx, cy); lens distortion terms of
    SIMPLE_RADIAL/RADIAL models are ignored (3DGS expects undistorted images; ours are small).
    """
    import pycolmap

    rec = pycolmap.Reconstruction(str(model_dir))
    cameras: list[Camera] = []
    images: list[torch.Tensor] = []
    names: list[str] = []
    for image_id in sorted(rec.images):
        img = rec.images[image_id]
        has_pose = img.has_pose if isinstance(img.has_pose, bool) else img.has_pose()
        if not has_pose:
            continue
        path = images_dir / img.name
        if not path.is_file():
            continue
        cam = rec.cameras[img.camera_id]
        k = np.asarray(cam.calibration_matrix())
        rot, trans = _rigid(img)
        full = Camera(rot, trans, float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                      int(cam.width), int(cam.height), img.name)
        small = full.scaled(long_edge)
        cameras.append(small)
        images.append(to_chw(load_rgb(path, (small.width, small.height), background)))
        names.append(img.name)
    if not cameras:
        raise ValueError(f"{model_dir}: no registered image found in {images_dir}")
    pts = [(p.xyz, p.color) for p in rec.points3D.values()]
    if len(pts) < 2:
        raise ValueError(f"{model_dir}: the model has {len(pts)} 3D points; cannot initialise a splat")
    xyz = np.array([p[0] for p in pts], dtype=np.float64)
    rgb = np.array([p[1] for p in pts], dtype=np.float64) / 255.0
    if len(xyz) > max_points:
        keep = np.random.default_rng(seed).choice(len(xyz), max_points, replace=False)
        xyz, rgb = xyz[keep], rgb[keep]
    return Scene(cameras, images, names, xyz, rgb)


def load_blender_scene(root: Path, long_edge: int, num_views: int, num_points: int,
                       background: tuple[float, float, float] = (1.0, 1.0, 1.0), seed: int = 0) -> Scene:
    """NeRF-Synthetic train split with ground-truth poses; random initial points in [-1.5, 1.5]^3
    (the 3DGS paper's synthetic-scene initialisation uses a box of this size around the object)."""
    meta = json.loads((root / "transforms_train.json").read_text())
    frames = meta["frames"]
    step = max(1, len(frames) // num_views)
    cameras: list[Camera] = []
    images: list[torch.Tensor] = []
    names: list[str] = []
    for frame in frames[::step][:num_views]:
        path = root / (frame["file_path"].removeprefix("./") + ".png")
        with PIL.Image.open(path) as im:
            width, height = im.size
        full = camera_from_blender(np.array(frame["transform_matrix"]), meta["camera_angle_x"], width, height,
                                   path.name)
        small = full.scaled(long_edge)
        cameras.append(small)
        images.append(to_chw(load_rgb(path, (small.width, small.height), background)))
        names.append(path.name)
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-1.5, 1.5, (num_points, 3))
    rgb = rng.random((num_points, 3))
    return Scene(cameras, images, names, xyz, rgb)
