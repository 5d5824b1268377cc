"""Tilted lanes (spec `slide_run`, poisoner/motion.py `tilted_slide_offset`): the crash-free lanes design.

Two lanes sliding exactly along x make pycolmap 4.2.1 segfault in PoseLib's shared-focal solver
(every mark match has y' == y); the same lanes along the lattice direction (run, 1) do not
(bench/results/watermark.md). These tests pin the geometry that claim rests on: whole-pixel,
exactly parallel lane moves that are never purely horizontal, inside one corner, <= 0.96% of the image.
"""

from __future__ import annotations

import numpy as np
import pytest

from poisoner.blend import apply_patch, patch_coverage
from poisoner.corner import CORNERS, corner_box
from poisoner.ladder import WATERMARK_LANES_2_SPEC, WATERMARK_LANES_SPEC, named_spec
from poisoner.motion import tilted_slide_offset
from poisoner.spec import LANES_MAX_AREA, PatchSpec, SpecError

TILTED = WATERMARK_LANES_SPEC.replace(slide_run=8)


def test_the_named_spec_is_the_tilted_lanes() -> None:
    tilted = TILTED.replace(block_size=0.0025, position="auto")
    assert named_spec("watermark-lanes-2") == WATERMARK_LANES_2_SPEC == tilted
    assert TILTED.lanes == 2 and TILTED.motion == "slide"
FRAMES = [(800, 600), (1024, 683), (1920, 1080), (800, 800), (600, 800), (3072, 2048)]


def test_tilted_slide_stays_on_its_lattice_line_and_folds_back() -> None:
    offsets = [tilted_slide_offset(i, 6, 112, 8) for i in range(60)]
    assert all(dx == 8 * dy for dx, dy in offsets)  # on the line (8, 1), whole pixels
    assert min(dy for _, dy in offsets) == 0 and max(dy for _, dy in offsets) == 112 // 8
    ys = [dy for _, dy in offsets]
    assert ys[1] - ys[0] == 1 and ys[20] < ys[16]  # out one unit per image, then back
    with pytest.raises(ValueError, match="run"):
        tilted_slide_offset(1, 6, 112, 0)


def test_every_move_of_a_lane_changes_its_row() -> None:
    """The crash condition was y' == y for every mark match: a tilted lane never moves along x alone."""
    for a in range(40):
        for b in range(40):
            (xa, ya), (xb, yb) = tilted_slide_offset(a, 12, 112, 8), tilted_slide_offset(b, 12, 112, 8)
            assert (xa == xb) == (ya == yb)


def test_tilted_lanes_move_in_exact_parallel_with_pixel_identical_copies() -> None:
    rng = np.random.default_rng(5)
    photo = rng.integers(0, 256, (600, 800, 3), dtype=np.uint8)
    seen = {}
    for i in (0, 3, 11):
        p = TILTED.resolve(800, 600, image_key=f"{i:06d}.png")
        out = apply_patch(photo, p)
        side = p.lane_size
        seen[i] = []
        for dx, dy, _ in p.parts:
            x, y = p.x + dx, p.y + dy
            seen[i].append((x, y, out[y : y + side, x : x + side]))
    moves = []
    for k in (0, 1):
        (xa, ya, a), (xb, yb, b) = seen[0][k], seen[11][k]
        assert np.array_equal(a, b)  # the same pixels: no resampling
        moves.append((xb - xa, yb - ya))
    (ax, ay), (bx, by) = moves
    assert ay != 0 and by != 0  # not along x
    assert ax * by == ay * bx and moves[0] != moves[1]  # exactly parallel, different sizes


@pytest.mark.parametrize("named", [False, True])
@pytest.mark.parametrize(("width", "height"), FRAMES)
def test_tilted_lanes_stay_in_one_corner_within_the_area_budget(width: int, height: int, named: bool) -> None:
    for corner in CORNERS:
        spec = (WATERMARK_LANES_2_SPEC if named else TILTED).replace(position=corner)
        x0, y0, x1, y1 = corner_box(corner, width, height, 0.2)
        for i in range(0, 80, 3):
            p = spec.resolve(width, height, image_key=f"IMG_{i:04d}.JPG")
            cover = patch_coverage(p)
            assert cover.sum() == 2 * p.lane_size**2  # two lanes, never overlapping
            assert cover.sum() <= LANES_MAX_AREA * width * height
            ys, xs = np.nonzero(cover)
            assert p.x + xs.min() >= x0 and p.x + xs.max() < x1, (corner, width, height, i)
            assert p.y + ys.min() >= y0 and p.y + ys.max() < y1, (corner, width, height, i)
    again = TILTED.resolve(width, height, image_key="r_7.png")
    assert again == TILTED.resolve(width, height, image_key="r_7.png")  # deterministic


def test_the_bench_frames_keep_the_measured_lane_size() -> None:
    assert TILTED.resolve(800, 600).lane_size == 48  # dtu at 800x600: as the x-only lanes
    assert TILTED.resolve(800, 800).lane_size == 48  # lego at 800x800: as the x-only lanes
    # 16:9: the lanes give up a little size so their rise fits the corner
    assert TILTED.resolve(1920, 1080).lane_size < WATERMARK_LANES_SPEC.resolve(1920, 1080).lane_size


def test_slide_run_is_validated_and_stays_out_of_old_spec_ids() -> None:
    assert PatchSpec().spec_id == "63928d73de472b0a"
    assert "slide_run" not in WATERMARK_LANES_SPEC.to_dict()
    assert TILTED.to_dict()["slide_run"] == 8 and TILTED.spec_id != WATERMARK_LANES_SPEC.spec_id
    assert PatchSpec.from_json(TILTED.to_json()) == TILTED
    for bad in (3, -1, 2.5, True):
        with pytest.raises(SpecError, match="slide_run"):
            WATERMARK_LANES_SPEC.replace(slide_run=bad)
    with pytest.raises(SpecError, match="slide_run"):
        PatchSpec(slide_run=8)  # static: nothing slides
