"""Pinhole cameras in the OpenCV/COLMAP convention (x right, y down, z forward; world -> camera).

Pixel (i, j) covers [i, i+1) x [j, j+1); its centre is (i + 0.5, j + 0.5), COLMAP's convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Camera:
    rotation: np.ndarray  # 3 x 3, world -> camera
    translation: np.ndarray  # 3, world -> camera: x_cam = R x_world + t
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    name: str = ""

    @property
    def centre(self) -> np.ndarray:
        """Camera centre in world coordinates: -R^T t."""
        return -self.rotation.T @ self.translation

    def scaled(self, long_edge: int) -> Camera:
        """The same camera at an image size whose longer edge is long_edge pixels."""
        s = long_edge / max(self.width, self.height)
        width, height = max(1, round(self.width * s)), max(1, round(self.height * s))
        sx, sy = width / self.width, height / self.height
        return Camera(
            self.rotation, self.translation, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy,
            width, height, self.name,
        )


def camera_from_blender(c2w_opengl: np.ndarray, camera_angle_x: float, width: int, height: int,
                        name: str = "") -> Camera:
    """NeRF-Synthetic transform_matrix (camera-to-world, OpenGL axes) -> Camera."""
    c2w = np.asarray(c2w_opengl, dtype=np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])  # to OpenCV axes
    rot_c2w, centre = c2w[:3, :3], c2w[:3, 3]
    rotation = rot_c2w.T
    focal = 0.5 * width / math.tan(0.5 * camera_angle_x)
    return Camera(rotation, -rotation @ centre, focal, focal, width / 2, height / 2, width, height, name)


def scene_extent(cameras: list[Camera]) -> float:
    """3DGS's getNerfppNorm radius: 1.1 x the largest camera-centre distance from their mean."""
    centres = np.stack([c.centre for c in cameras])
    return float(1.1 * np.linalg.norm(centres - centres.mean(0), axis=1).max()) or 1.0
