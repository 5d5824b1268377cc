"""A small textured scene rendered from known cameras, for CI tests and the demo.

Pure numpy ray casting against a handful of textured rectangles (a box on a ground plane in
front of a back wall). Textures are multi-scale random noise, so SIFT finds plenty of
distinctive features at every octave and clean SfM registers every camera accurately in a
few seconds. Poses follow the OpenCV/COLMAP convention: x_cam = R @ x_world + t.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poisoner.atomic import atomic_write_bytes


@dataclass(frozen=True)
class SyntheticOptions:
    num_views: int = 12
    width: int = 320
    height: int = 320
    focal: float = 384.0  # 1.2 x width: COLMAP's prior for images without EXIF focal length
    radius: float = 7.0
    elevation_deg: float = 25.0  # views alternate +-elevation_jitter_deg around this
    elevation_jitter_deg: float = 10.0
    arc_deg: float = 120.0  # cameras spread over this arc of azimuth, looking at the origin
    seed: int = 0
    # "textured": floor and wall carry texture (a real room: the scene outvotes a small patch);
    # "plain": uniform floor and wall, only the box is textured (an object on a plain backdrop,
    # the case where the paper's patch works, like NeRF-Synthetic lego)
    backdrop: str = "textured"

    def camera_params(self) -> str:
        """The renders' true intrinsics as Verifier I takes them ("fx,fy,cx,cy,k1,k2,p1,p2").

        Tests that assert a verdict pass them: with the focal length left to COLMAP, the outcome
        on a small render varies from run to run (and pycolmap 4.2.1 can segfault estimating it)."""
        w, h, f = self.width, self.height, self.focal
        return f"{f:g},{f:g},{w / 2:g},{h / 2:g},0,0,0,0"


@dataclass(frozen=True)
class Rect:
    """A textured rectangle: origin + u*[0,1]*edge_u + v*[0,1]*edge_v."""

    origin: np.ndarray
    edge_u: np.ndarray
    edge_v: np.ndarray
    texture: np.ndarray  # T x T x 3 float in [0, 1]
    shade: float


def _noise_texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Sum of upsampled random grids at several scales: texture at every SIFT octave."""
    tex = np.zeros((size, size, 3))
    for cells, weight in ((4, 0.35), (16, 0.3), (64, 0.25), (256, 0.1)):
        grid = rng.random((cells, cells, 3))
        rep = size // cells
        tex += weight * np.kron(grid, np.ones((rep, rep, 1)))
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return tex


def scene_rects(seed: int = 0, backdrop: str = "textured") -> list[Rect]:
    if backdrop not in ("textured", "plain"):
        raise ValueError(f"backdrop must be 'textured' or 'plain', got {backdrop!r}")
    rng = np.random.default_rng(seed)
    a = np.array
    floor, wall = _noise_texture(rng), _noise_texture(rng)  # drawn either way: same box textures
    if backdrop == "plain":
        floor, wall = np.full((2, 2, 3), 0.9), np.full((2, 2, 3), 0.95)
    rects = [
        # ground plane z = 0
        Rect(a([-6.0, -6.0, 0.0]), a([12.0, 0, 0]), a([0, 12.0, 0]), floor, 0.8),
        # back wall y = 5 (behind the box as seen from the cameras at negative y)
        Rect(a([-6.0, 5.0, 0.0]), a([12.0, 0, 0]), a([0, 0, 6.0]), wall, 0.7),
    ]
    # a 2 x 2 x 2 box on the ground, centred on the origin: faces visible from -y, +-x, top
    lo, hi = -1.0, 1.0
    rects += [
        Rect(a([lo, lo, 0.0]), a([2.0, 0, 0]), a([0, 0, 2.0]), _noise_texture(rng), 1.0),  # y = -1
        Rect(a([lo, lo, 0.0]), a([0, 2.0, 0]), a([0, 0, 2.0]), _noise_texture(rng), 0.85),  # x = -1
        Rect(a([hi, lo, 0.0]), a([0, 2.0, 0]), a([0, 0, 2.0]), _noise_texture(rng), 0.75),  # x = +1
        Rect(a([lo, lo, 2.0]), a([2.0, 0, 0]), a([0, 2.0, 0]), _noise_texture(rng), 0.95),  # top
    ]
    return rects


def look_at(centre: np.ndarray, target: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) for an OpenCV camera at centre looking at target (y down)."""
    z = target - centre
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z])
    return rot, -rot @ centre


def camera_poses(options: SyntheticOptions) -> list[tuple[np.ndarray, np.ndarray]]:
    start = -90.0 - options.arc_deg / 2  # centred on the -y axis, facing the box's front
    azimuths = np.deg2rad(
        start + options.arc_deg * np.arange(options.num_views) / max(1, options.num_views - 1)
    )
    target = np.array([0.0, 0.0, 0.8])
    poses = []
    for i, az in enumerate(azimuths):
        # alternating heights: views on one circle leave the vertical focal length unconstrained
        elev = np.deg2rad(options.elevation_deg + options.elevation_jitter_deg * (1 if i % 2 else -1))
        centre = options.radius * np.array(
            [np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), np.sin(elev)]
        )
        centre = centre + np.array([0, 0, 0.8])
        poses.append(look_at(centre, target, np.array([0.0, 0.0, 1.0])))
    return poses


def render_view(
    rot: np.ndarray, trans: np.ndarray, options: SyntheticOptions, rects: list[Rect]
) -> np.ndarray:
    """RGB uint8 render of the scene from one camera (nearest hit, bilinear-free texture lookup)."""
    w, h, f = options.width, options.height, options.focal
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    dirs_cam = np.stack([(u - w / 2) / f, (v - h / 2) / f, np.ones_like(u)], axis=-1).reshape(-1, 3)
    dirs = dirs_cam @ rot  # rot.T @ d for each row: camera to world
    centre = -rot.T @ trans
    depth = np.full(dirs.shape[0], np.inf)
    colour = np.full((dirs.shape[0], 3), 0.5)
    for rect in rects:
        normal = np.cross(rect.edge_u, rect.edge_v)
        denom = dirs @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = ((rect.origin - centre) @ normal) / denom
        hit = centre + dist[:, None] * dirs
        rel = hit - rect.origin
        su = rel @ rect.edge_u / (rect.edge_u @ rect.edge_u)
        sv = rel @ rect.edge_v / (rect.edge_v @ rect.edge_v)
        ok = (dist > 1e-6) & (dist < depth) & (su >= 0) & (su < 1) & (sv >= 0) & (sv < 1)
        if not ok.any():
            continue
        size = rect.texture.shape[0]
        ti = np.clip((sv[ok] * size).astype(int), 0, size - 1)
        tj = np.clip((su[ok] * size).astype(int), 0, size - 1)
        colour[ok] = rect.texture[ti, tj] * rect.shade
        depth[ok] = dist[ok]
    return np.clip(colour.reshape(h, w, 3) * 255 + 0.5, 0, 255).astype(np.uint8)


def render_scene(
    out_dir: Path, options: SyntheticOptions | None = None, gt_path: Path | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Write view_NN.png files to out_dir (and the ground truth to gt_path); return name -> (R, t).

    Keep gt_path outside out_dir: COLMAP reads every file of an image folder."""
    from PIL import Image  # PIL before any pycolmap import in this process

    options = options or SyntheticOptions()
    out_dir.mkdir(parents=True, exist_ok=True)
    rects = scene_rects(options.seed, options.backdrop)
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for i, (rot, trans) in enumerate(camera_poses(options)):
        name = f"view_{i:02d}.png"
        Image.fromarray(render_view(rot, trans, options, rects)).save(out_dir / name)
        poses[name] = (rot, trans)
    if gt_path is not None:
        write_ground_truth(gt_path, poses, options)
    return poses


def write_ground_truth(
    path: Path, poses: dict[str, tuple[np.ndarray, np.ndarray]], options: SyntheticOptions
) -> None:
    data = {
        "format": "ppd-synthetic-v1",
        "width": options.width,
        "height": options.height,
        "focal": options.focal,
        "cameras": {n: {"R": r.tolist(), "t": t.tolist()} for n, (r, t) in poses.items()},
    }
    atomic_write_bytes(path, json.dumps(data, indent=1).encode())
