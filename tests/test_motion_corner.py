"""Corner marks that move (poisoner/motion.py: "spin", "slide") and where they land."""

from __future__ import annotations

import numpy as np

from poisoner.blend import apply_patch
from poisoner.ladder import WATERMARK_SPEC
from poisoner.motion import SPIN_DEG_PER_INDEX, spin_pose, tumble_pose
from poisoner.placement import corner_box


def _turn(a: float, b: float) -> float:
    return abs((b - a + 180.0) % 360.0 - 180.0)


def test_spin_turns_a_fixed_step_per_image_and_is_continuous() -> None:
    for i in range(20):
        a0, s0, x0, y0 = spin_pose(i, 0, 0.75)
        a1, s1, x1, y1 = spin_pose(i + 1, 0, 0.75)
        assert abs(_turn(a0, a1) - SPIN_DEG_PER_INDEX) < 1e-6
        assert 0.75 <= s0 <= 1.0 and 0.0 <= x0 <= 1.0 and 0.0 <= y0 <= 1.0
        # a tenth of an index (a video frame) moves a tenth as far: no jumps
        a2, s2, x2, y2 = spin_pose(i + 0.1, 0, 0.75)
        assert _turn(a0, a2) < 0.11 * SPIN_DEG_PER_INDEX + 1e-6
        assert abs(x2 - x0) < 0.05 and abs(y2 - y0) < 0.05 and abs(s2 - s0) < 0.05


def test_spin_differs_from_tumble_and_by_seed() -> None:
    assert spin_pose(3, 0, 0.75) != tumble_pose(3, 0, 0.75)
    assert spin_pose(3, 0, 0.75) != spin_pose(3, 1, 0.75)


def test_spinning_mark_changes_only_its_corner_on_a_real_size_image() -> None:
    rng = np.random.default_rng(0)
    photo = rng.integers(0, 256, (600, 800, 3), dtype=np.uint8)  # textured: every block shows
    spec = WATERMARK_SPEC.replace(motion="spin", position="bottom-right")
    x0, y0, x1, y1 = corner_box("bottom-right", 800, 600, 0.2)
    boxes = set()
    for i in range(0, 50, 2):
        placement = spec.resolve(800, 600, image_key=f"{i:06d}.png")
        boxes.add(placement.box)
        changed = np.any(apply_patch(photo, placement) != photo, axis=2)
        assert changed.any()
        outside = changed.copy()
        outside[y0:y1, x0:x1] = False
        assert not outside.any(), i
        assert changed.mean() <= 0.01
    assert len(boxes) > 20  # it moves: the stationary filter has nothing to remove


def test_slide_moves_along_x_only_and_folds_back_within_its_span() -> None:
    from poisoner.motion import path_offset

    xs = [path_offset("slide", i, 6, 112)[0] for i in range(60)]
    assert all(path_offset("slide", i, 6, 112)[1] == 0 for i in range(60))
    assert min(xs) == 0 and max(xs) == 112
    assert xs[1] - xs[0] == 6 and xs[20] < xs[18]  # out, then back


def test_two_lanes_stay_apart_inside_the_corner_region() -> None:
    """The bench's two-lane design: both marks inside the 20% x 20% corner, never overlapping."""
    from poisoner.spec import PatchSpec

    lane = PatchSpec(
        pattern="random_blocks", patch_size=0.06, motion="slide", motion_step=0.0075, motion_span=0.14
    )
    other = lane.replace(motion_step=0.015, offset=(0, 0.07), seed=101)
    for w, h in ((800, 600), (800, 800), (1024, 683)):
        for i in range(0, 80, 3):
            a = lane.resolve(w, h, image_key=f"{i:04d}.png").box
            b = other.resolve(w, h, image_key=f"{i:04d}.png").box
            for box in (a, b):
                assert box[2] <= int(0.2 * w) and box[3] <= int(0.2 * h), (w, h, i, box)
            assert a[3] <= b[1]  # lane a above lane b
