"""Videos and frame sets (issue 25): per-photo placement (poisoner.placement.place_on_photo) per
keyframe, the mark moving smoothly between them. Moved out of poisoner/placement.py (round 7) to
keep that module under 600 lines.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

MAX_ANCHOR_SPEED = 0.25  # of the frame's shorter side per second: how fast a video's mark may move


def smooth_anchors(
    keys: Sequence[tuple[float, tuple[int, int]]], max_step: float
) -> list[tuple[float, tuple[float, float]]]:
    """Keyframe anchors (time, (x, y)) limited to move at most max_step px per unit of time from
    one keyframe to the next (a jump is spread out: the video's mark glides, never teleports)."""
    out: list[tuple[float, tuple[float, float]]] = []
    for t, (x, y) in sorted(keys):
        if not out:
            out.append((t, (float(x), float(y))))
            continue
        pt, (px, py) = out[-1]
        reach = max_step * max(t - pt, 0.0)
        dx, dy = x - px, y - py
        dist = float(np.hypot(dx, dy))
        scale = 1.0 if dist <= reach or dist == 0 else reach / dist
        out.append((t, (px + dx * scale, py + dy * scale)))
    return out


def anchor_at(anchors: Sequence[tuple[float, tuple[float, float]]], t: float) -> tuple[int, int]:
    """The whole-pixel anchor at time t, linear between the (smoothed) keyframe anchors."""
    if not anchors:
        raise ValueError("no keyframe anchors")
    if t <= anchors[0][0]:
        x, y = anchors[0][1]
        return (round(x), round(y))
    for (t0, (x0, y0)), (t1, (x1, y1)) in zip(anchors, anchors[1:], strict=False):
        if t <= t1:
            f = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
            return (round(x0 + f * (x1 - x0)), round(y0 + f * (y1 - y0)))
    x, y = anchors[-1][1]
    return (round(x), round(y))
