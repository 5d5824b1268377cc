"""The pure parts of bench/bench_watermark_spread.py (tests/bench/test_bench_watermark_spread.py checks
them): crops and resizes that move images and pinhole intrinsics together, and the run summaries
of its results page."""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from typing import Any

from PIL import Image

GOAL_WITHIN5 = 0.10  # issue 14's goal: at most 10% of the cameras within 5 deg


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in COLMAP's convention: pixel (i, j) covers [i, i+1) x [j, j+1), so a
    point at u = fx X/Z + cx lands in pixel floor(u)."""

    fx: float
    fy: float
    cx: float
    cy: float

    def camera_params(self) -> str:
        """As Verifier I takes them ("fx,fy,cx,cy,k1,k2,p1,p2"), no distortion."""
        return f"{self.fx:.3f},{self.fy:.3f},{self.cx:.3f},{self.cy:.3f},0,0,0,0"

    @classmethod
    def parse(cls, params: str) -> Intrinsics:
        fx, fy, cx, cy = (float(x) for x in params.split(",")[:4])
        return cls(fx, fy, cx, cy)


def crop_box(
    width: int, height: int, fractions: tuple[float, float, float, float]
) -> tuple[int, int, int, int]:
    """Pixel box (x0, y0, x1, y1) of a crop given as fractions of the frame (left, top, right, bottom)."""
    left, top, right, bottom = fractions
    if not (0 <= left < right <= 1 and 0 <= top < bottom <= 1):
        raise ValueError(f"crop fractions must satisfy 0 <= left < right <= 1 (same for y): {fractions}")
    return round(left * width), round(top * height), round(right * width), round(bottom * height)


def centre_crop_fractions(keep: float) -> tuple[float, float, float, float]:
    """The centre crop that keeps `keep` of the width and of the height."""
    margin = (1 - keep) / 2
    return margin, margin, 1 - margin, 1 - margin


def crop_intrinsics(k: Intrinsics, box: tuple[int, int, int, int]) -> Intrinsics:
    """Cropping moves the principal point by the box's origin; the focal length is unchanged."""
    return Intrinsics(k.fx, k.fy, k.cx - box[0], k.cy - box[1])


def resize_intrinsics(k: Intrinsics, old_size: tuple[int, int], new_size: tuple[int, int]) -> Intrinsics:
    """Resizing scales x and y by new/old (pixel corners map to pixel corners)."""
    sx, sy = new_size[0] / old_size[0], new_size[1] / old_size[1]
    return Intrinsics(k.fx * sx, k.fy * sy, k.cx * sx, k.cy * sy)


def scaled_size(width: int, height: int, new_width: int | None) -> tuple[int, int]:
    if new_width is None:
        return width, height
    return new_width, round(height * new_width / width)


def transform_image(
    image: Image.Image,
    fractions: tuple[float, float, float, float] | None,
    new_width: int | None,
    resample: int = Image.Resampling.LANCZOS,
) -> Image.Image:
    """Crop (fractions of the frame, or None) then resize to new_width (None: keep), aspect kept."""
    if fractions is not None:
        image = image.crop(crop_box(image.width, image.height, fractions))
    size = scaled_size(image.width, image.height, new_width)
    return image if size == image.size else image.resize(size, resample)


def transform_intrinsics(
    k: Intrinsics,
    size: tuple[int, int],
    fractions: tuple[float, float, float, float] | None,
    new_width: int | None,
) -> tuple[Intrinsics, tuple[int, int]]:
    """The intrinsics and size after transform_image's crop and resize."""
    if fractions is not None:
        box = crop_box(size[0], size[1], fractions)
        k, size = crop_intrinsics(k, box), (box[2] - box[0], box[3] - box[1])
    new_size = scaled_size(size[0], size[1], new_width)
    return resize_intrinsics(k, size, new_size), new_size


def summarise(values: list[float]) -> dict[str, float] | None:
    """Median and range of the completed runs' fractions within 5 deg (None when none completed)."""
    if not values:
        return None
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


# ---- the results page ----------------------------------------------------------------------------
def profile_cell(runs: list[dict[str, Any]]) -> str:
    """`median [min-max] (k runs, o over 10%, c crashed)` of the fraction within 5 deg, `·` without runs."""
    if not runs:
        return "·"
    done = [r["within5"] for r in runs if r["within5"] is not None]
    crashed = sum(r["outcome"] == "sfm_crashed" for r in runs)
    other = len(runs) - len(done) - crashed
    s = summarise(done)
    text = (
        "no completed run"
        if s is None
        else (f"{100 * s['median']:.0f}% [{100 * s['min']:.0f}-{100 * s['max']:.0f}]")
    )
    over = sum(x > GOAL_WITHIN5 for x in done)
    extra = f", {over} over {100 * GOAL_WITHIN5:.0f}%" if over else ""
    extra += f", {crashed} crashed" if crashed else ""
    extra += f", {other} failed" if other else ""
    return f"{text} ({len(done)} runs{extra})"
