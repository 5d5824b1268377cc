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

MOTIONS = ("static", "drift", "orbit")
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
    """
    if motion == "static" or step == 0:
        return (0, 0)
    if motion == "drift":
        d = _fold(index * step, span)
        return (d, d)
    if motion == "orbit":
        radius = span / 2.0
        if radius <= 0:
            return (0, 0)
        angle = index * step / radius
        dx = int(round(radius + radius * math.cos(angle)))
        dy = int(round(radius + radius * math.sin(angle)))
        return (min(dx, span), min(dy, span))
    raise ValueError(f"unknown motion {motion!r}; choose one of {', '.join(MOTIONS)}")
