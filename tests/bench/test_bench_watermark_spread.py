"""The pure parts of bench/bench_watermark_spread.py (testkit/spread_geometry.py): crops and resizes
move images and intrinsics together (a known 3D point lands on the same content after the transform);
the run summaries."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from testkit.spread_geometry import (
    Intrinsics,
    centre_crop_fractions,
    crop_box,
    crop_intrinsics,
    profile_cell,
    resize_intrinsics,
    summarise,
    transform_image,
    transform_intrinsics,
)


def project(k: Intrinsics, point: np.ndarray) -> tuple[float, float]:
    """Continuous image coordinates of a camera-frame point (pixel i covers [i, i+1))."""
    x, y, z = point
    return k.fx * x / z + k.cx, k.fy * y / z + k.cy


def marked_image(width: int, height: int, k: Intrinsics, point: np.ndarray, radius: int) -> Image.Image:
    """Black image with a white square of side 2 radius + 1 centred on the pixel the point projects into."""
    u, v = project(k, point)
    px, py = int(np.floor(u)), int(np.floor(v))
    pixels = np.zeros((height, width, 3), np.uint8)
    pixels[py - radius : py + radius + 1, px - radius : px + radius + 1] = 255
    return Image.fromarray(pixels)


def marker_centre(image: Image.Image) -> tuple[float, float]:
    """Centre of the bright pixels, in continuous coordinates (pixel centres at i + 0.5)."""
    grey = np.asarray(image.convert("L")).astype(float)
    ys, xs = np.nonzero(grey > 127)
    return float(xs.mean()) + 0.5, float(ys.mean()) + 0.5


POINT = np.array([0.31, -0.17, 2.0])  # camera frame, in front of the camera
K = Intrinsics(1000.0, 980.0, 410.0, 290.0)


@pytest.mark.parametrize(
    ("fractions", "new_width"),
    [
        (None, None),
        (centre_crop_fractions(0.85), None),  # centre crop
        ((0.1, 0.0, 1.0, 1.0), None),  # one side cut
        ((0.1, 0.0, 1.0, 1.0), 720),  # cut, then downscaled
        (None, 600),  # downscaled
        (None, 1200),  # upscaled
        ((0.05, 0.1, 0.9, 0.95), 500),  # uneven crop, then downscaled
    ],
)
def test_known_point_projects_onto_its_marker_after_crop_and_resize(fractions, new_width):
    size = (800, 600)
    image = marked_image(*size, K, POINT, radius=8)
    out = transform_image(image, fractions, new_width)
    k2, size2 = transform_intrinsics(K, size, fractions, new_width)
    assert out.size == size2
    u, v = project(k2, POINT)
    cu, cv = marker_centre(out)
    # the square's centre is within half a source pixel of the projection (scaled with the image),
    # plus up to half a pixel of resampling and thresholding
    tol = 0.5 * max(1.0, size2[0] / size[0]) + 0.5
    assert abs(cu - u) < tol and abs(cv - v) < tol, (cu, u, cv, v)


def test_wrong_intrinsics_miss_the_marker():
    """The check above can fail: the uncropped intrinsics on a cropped image miss by the crop offset."""
    fractions = (0.1, 0.0, 1.0, 1.0)
    out = transform_image(marked_image(800, 600, K, POINT, radius=8), fractions, None)
    u_wrong, _ = project(K, POINT)
    cu, _ = marker_centre(out)
    assert abs(cu - u_wrong) == pytest.approx(80, abs=0.75)


def test_crop_box_and_centre_crop():
    assert crop_box(800, 800, centre_crop_fractions(0.85)) == (60, 60, 740, 740)
    assert crop_box(1600, 1200, (0.1, 0.0, 1.0, 1.0)) == (160, 0, 1600, 1200)
    with pytest.raises(ValueError, match="crop fractions"):
        crop_box(800, 600, (0.5, 0.0, 0.4, 1.0))


def test_crop_and_resize_intrinsics_values():
    assert crop_intrinsics(K, (60, 30, 700, 500)) == Intrinsics(1000.0, 980.0, 350.0, 260.0)
    assert resize_intrinsics(K, (800, 600), (400, 300)) == Intrinsics(500.0, 490.0, 205.0, 145.0)
    k2, size = transform_intrinsics(K, (1600, 1200), (0.1, 0.0, 1.0, 1.0), 720)
    assert size == (720, 600)
    assert k2 == Intrinsics(500.0, 490.0, (410.0 - 160) / 2, 145.0)


def test_camera_params_round_trip():
    k = Intrinsics(1111.111, 1111.111, 340.0, 340.0)
    assert k.camera_params() == "1111.111,1111.111,340.000,340.000,0,0,0,0"
    assert Intrinsics.parse(k.camera_params()) == k


def test_mask_resize_keeps_binary_values():
    mask = Image.fromarray(
        ((np.arange(600)[:, None] + np.arange(800)[None, :]) % 7 == 0).astype(np.uint8) * 255
    )
    out = transform_image(mask, (0.1, 0.0, 1.0, 1.0), 720, Image.Resampling.NEAREST)
    assert set(np.unique(np.asarray(out)).tolist()) <= {0, 255}
    assert out.size == (720, 600)


def test_summarise_and_profile_cell():
    assert summarise([]) is None
    assert summarise([0.0, 0.5, 0.1]) == {"median": 0.1, "min": 0.0, "max": 0.5}
    runs = [
        {"within5": 0.0, "outcome": "ok"},
        {"within5": 0.8, "outcome": "ok"},
        {"within5": None, "outcome": "sfm_crashed"},
    ]
    assert profile_cell(runs) == "40% [0-80] (2 runs, 1 over 10%, 1 crashed)"
    assert profile_cell(runs[:1]) == "0% [0-0] (1 runs)"
    assert profile_cell([]) == "·"
    assert (
        profile_cell([{"within5": None, "outcome": "sfm_crashed"}]) == "no completed run (0 runs, 1 crashed)"
    )
