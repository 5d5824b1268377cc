"""Moving patches (issue #9): per-image index from a file name, and a deterministic path.

Pure functions, no I/O. COLMAP's `filter_stationary_matches` drops matches that sit at the same
pixel in two views, which is exactly the paper's fixed patch. A patch that moves from image to
image along a deterministic path keeps matches between its copies, but they now move, like a
(phantom) scene point would.

The per-image index is the trailing number of the file stem (camera and render names are
sequential: IMG_0123 -> 123, r_12 -> 12, 0007 -> 7), so neighbouring captures get neighbouring
positions and the displacement between them is `step` pixels along the path. Names without a
trailing number fall back to a stable hash of the name (FALLBACK_PERIOD positions): still
deterministic, order-independent and stable when images are added, just not sequential.
"""

from __future__ import annotations

import hashlib
import math
import re

MOTIONS = ("static", "drift", "orbit", "tumble", "spin", "slide")
CORNER_MOTIONS = ("tumble", "spin")  # marks that live inside one corner region (issue 14)

# spin: degrees turned and radians travelled around the region per image index. 13 deg is not a
# divisor of 360 (the turn repeats only after 360 indices) and large enough that the copies in two
# neighbouring views are no pure translation of each other (COLMAP's watermark test).
SPIN_DEG_PER_INDEX = 13.0
SPIN_PATH_PER_INDEX = 0.2
FALLBACK_PERIOD = 1000  # index range for names without a trailing number

_TRAILING_NUMBER = re.compile(r"(\d+)$")


def image_index(image_key: str) -> int:
    """The per-image index of a file name: its stem's trailing number, else a stable hash."""
    name = image_key.replace("\\", "/").rsplit("/", 1)[-1]
    stem = name.rsplit(".", 1)[0] if "." in name[1:] else name
    match = _TRAILING_NUMBER.search(stem)
    if match:
        return int(match.group(1))
    digest = hashlib.sha256(stem.encode()).digest()
    return int.from_bytes(digest[:8], "big") % FALLBACK_PERIOD


def _fold(t: float, span: int) -> int:
    """t folded into [0, span] as a triangle wave (out and back): bounded, continuous."""
    if span <= 0:
        return 0
    period = 2 * span
    r = t % period
    return int(round(r if r <= span else period - r))


def path_offset(motion: str, index: float, step: int, span: int) -> tuple[int, int]:
    """(dx, dy) >= 0 of image `index` along the path, each within [0, span] pixels.

    `index` may be fractional (a video frame between two photo-steps): the path is continuous.

    - static: (0, 0) for every image.
    - drift: along the diagonal, `step` px per index on each axis, out and back within span.
      Consecutive images are step*sqrt(2) px apart: a constant image translation, the signature
      of a camera turning steadily (the phantom motion).
    - orbit: around a circle of diameter span, `step` px of arc per index.
    - slide: along the image's x axis only, `step` px per index, out and back within span. Two
      slide marks with different steps in one corner move in parallel by different amounts: one
      epipolar geometry (a camera translating past two planes at different depths) that no single
      translation explains, so COLMAP's watermark test does not flag the pair (issue 14).
    """
    if motion in ("static", *CORNER_MOTIONS) or step == 0:
        return (0, 0)  # a corner mark is placed by tumble_pose / spin_pose, not along a path
    if motion == "drift":
        d = _fold(index * step, span)
        return (d, d)
    if motion == "slide":
        return (_fold(index * step, span), 0)
    if motion == "orbit":
        radius = span / 2.0
        if radius <= 0:
            return (0, 0)
        angle = index * step / radius
        dx = int(round(radius + radius * math.cos(angle)))
        dy = int(round(radius + radius * math.sin(angle)))
        return (min(dx, span), min(dy, span))
    raise ValueError(f"unknown motion {motion!r}; choose one of {', '.join(MOTIONS)}")


def tilted_slide_offset(index: float, step: int, span: int, run: int) -> tuple[int, int]:
    """(dx, dy) >= 0 of image `index` on a slide tilted to the lattice direction (run, 1).

    The position is u * (run, 1) for a whole number u that goes out and back over span // run
    units, `step` px of x per index (at least one unit). Why a lattice direction: every copy sits
    at whole pixels (no resampling, identical descriptors), the copies of two lanes move exactly
    in parallel, and any move of a lane changes its y by >= 1 px. Two lanes moving exactly along
    the image's x axis make pycolmap 4.2.1 segfault in PoseLib's shared-focal 6-point solver
    (every mark match has y' == y exactly); the same lanes tilted by one pixel in `run` do not
    (bench/results/watermark.md, "Round 3").
    """
    if run < 1:
        raise ValueError(f"run must be >= 1, got {run}")
    units = max(1, round(step / run)) if step else 0
    u = _fold(index * units, span // run)
    return (u * run, u)


# ---- tumble (issue 14): a corner mark that turns, scales and shifts per image ----------------------
def _unit(seed: int, index: int, what: str) -> float:
    """A stable pseudo-random number in [0, 1) for (seed, image index, quantity)."""
    digest = hashlib.sha256(f"tumble:{seed}:{index}:{what}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2**64


def _pose_at(index: int, seed: int, min_scale: float) -> tuple[float, float, float, float]:
    angle = 360.0 * _unit(seed, index, "angle")
    scale = min_scale + (1.0 - min_scale) * _unit(seed, index, "scale")
    return angle, scale, _unit(seed, index, "x"), _unit(seed, index, "y")


def tumble_pose(index: float, seed: int, min_scale: float) -> tuple[float, float, float, float]:
    """(angle in degrees, scale, fx, fy) of image `index`: fx, fy in [0, 1] place the mark in its region.

    Why random per image, not a path: COLMAP's watermark test fits a pure translation to border
    matches and its stationary filter drops matches that stay put; a mark turned and scaled
    differently in every image matches between images by a similarity that is neither. Integer
    indices are independent draws (keyed by seed); a fractional index (a video frame between two
    steps) interpolates between its neighbours, the angle along the shorter arc, so a video's
    mark turns smoothly instead of jumping every frame.
    """
    lo = math.floor(index)
    t = index - lo
    a0 = _pose_at(lo, seed, min_scale)
    if t == 0:
        return a0
    a1 = _pose_at(lo + 1, seed, min_scale)
    turn = (a1[0] - a0[0] + 180.0) % 360.0 - 180.0
    angle = (a0[0] + t * turn) % 360.0
    scale, x, y = (a0[i] + t * (a1[i] - a0[i]) for i in (1, 2, 3))
    return angle, scale, x, y


def spin_pose(index: float, seed: int, min_scale: float) -> tuple[float, float, float, float]:
    """(angle, scale, fx, fy) of image `index` for a mark that turns and circles SMOOTHLY.

    Why smooth (a hypothesis measured in bench/results/watermark.md): neighbouring views, the pairs
    COLMAP leans on, then carry nearly the same copy of the mark, so its descriptors match as well
    as a real object's, and the mark's phantom camera path is as smooth as a real one. Every
    quantity is continuous in `index`, so a video's fractional index needs no interpolation.
    """
    phase = 2 * math.pi * _unit(seed, 0, "spin")
    angle = (360.0 * _unit(seed, 0, "angle") + SPIN_DEG_PER_INDEX * index) % 360.0
    t = SPIN_PATH_PER_INDEX * index + phase
    scale = min_scale + (1.0 - min_scale) * (0.5 + 0.5 * math.sin(0.61 * t))
    return angle, scale, 0.5 + 0.5 * math.cos(t), 0.5 + 0.5 * math.sin(t)


def tumble_extent(texture: int, scale: float, angle: float) -> int:
    """Side (px) of the bounding box of a texture-px square scaled by `scale` and turned by `angle`."""
    rad = math.radians(angle)
    side = texture * scale * (abs(math.cos(rad)) + abs(math.sin(rad)))
    return max(1, int(math.ceil(side - 1e-9)))
