"""Corner marks that move (poisoner/motion.py: "spin", "slide") and where they land."""

from __future__ import annotations

import numpy as np
import pytest

from poisoner.blend import apply_patch
from poisoner.corner import CORNERS, corner_box
from poisoner.ladder import WATERMARK_SPEC
from poisoner.motion import SPIN_DEG_PER_INDEX, spin_pose, tumble_pose
from poisoner.spec import SpecError


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


def test_lanes_spec_is_the_two_mark_design_and_copies_are_pixel_identical() -> None:
    """One spec with lanes=2 writes the same pixels as two slide specs (the bench's form), and each
    lane's copy in one image is the same pixels as in another image, shifted along x only."""
    from poisoner.ladder import WATERMARK_LANES_SPEC
    from poisoner.spec import PatchSpec

    first = WATERMARK_LANES_SPEC.replace(lanes=1)
    second = first.replace(motion_step=0.015, offset=(0, 0.07), seed=101)
    rng = np.random.default_rng(3)
    photo = rng.integers(0, 256, (600, 800, 3), dtype=np.uint8)
    lanes = []
    for i in (0, 2, 10):
        name = f"{i:06d}.png"
        two = apply_patch(apply_patch(photo, first.resolve(800, 600, name)), second.resolve(800, 600, name))
        one = apply_patch(photo, WATERMARK_LANES_SPEC.resolve(800, 600, name))
        assert np.array_equal(one, two), i
        placement = WATERMARK_LANES_SPEC.resolve(800, 600, name)
        assert len(placement.parts) == 2 and placement.lane_size == 48
        crops = []
        for dx, dy, _ in placement.parts:
            x, y = placement.x + dx, placement.y + dy
            crops.append((x, y, one[y : y + 48, x : x + 48]))
        lanes.append(crops)
    for k in (0, 1):
        (xa, ya, a), (xb, yb, b) = lanes[0][k], lanes[2][k]
        assert np.array_equal(a, b) and ya == yb and xa != xb  # same copy, moved along x
    shift0 = lanes[2][0][0] - lanes[0][0][0]
    shift1 = lanes[2][1][0] - lanes[0][1][0]
    assert shift0 != shift1  # two different translations: no single one explains the mark
    with pytest.raises(SpecError, match="lanes"):
        PatchSpec(lanes=2)  # static: lanes need motion 'slide'
    with pytest.raises(SpecError, match="lanes"):
        WATERMARK_LANES_SPEC.replace(lanes=4)


def test_lanes_fit_every_corner_and_change_only_their_squares() -> None:
    from poisoner.blend import patch_coverage
    from poisoner.ladder import WATERMARK_LANES_SPEC

    for corner in CORNERS:
        spec = WATERMARK_LANES_SPEC.replace(position=corner)
        x0, y0, x1, y1 = corner_box(corner, 800, 600, 0.2)
        for i in range(0, 60, 5):
            placement = spec.resolve(800, 600, image_key=f"{i:04d}.png")
            cover = patch_coverage(placement)
            assert cover.sum() == 2 * 48 * 48
            ys, xs = np.nonzero(cover)
            assert placement.x + xs.min() >= x0 and placement.x + xs.max() < x1, (corner, i)
            assert placement.y + ys.min() >= y0 and placement.y + ys.max() < y1, (corner, i)


def test_lanes_stay_within_one_percent_and_the_corner_on_every_aspect_ratio() -> None:
    from poisoner.blend import patch_coverage
    from poisoner.ladder import WATERMARK_LANES_SPEC

    for w, h in ((800, 600), (1024, 683), (1920, 1080), (3072, 2048), (600, 800)):
        for i in range(0, 80, 7):
            placement = WATERMARK_LANES_SPEC.resolve(w, h, image_key=f"{i:04d}.png")
            cover = patch_coverage(placement)
            assert cover.sum() <= 0.01 * w * h, (w, h)
            ys, xs = np.nonzero(cover)
            assert placement.x + xs.max() < int(0.2 * w) and placement.y + ys.max() < int(0.2 * h), (w, h, i)
    # the 4:3 bench frames keep the full 6% lanes (the measured design)
    assert WATERMARK_LANES_SPEC.resolve(800, 600).lane_size == 48
