"""poisoner/motion.py: per-image index from a file name, deterministic bounded paths."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from poisoner.motion import FALLBACK_PERIOD, MOTIONS, image_index, path_offset


@pytest.mark.parametrize(
    ("key", "index"),
    [
        ("r_12.png", 12),
        ("IMG_0123.JPG", 123),
        ("0007.jpg", 7),
        ("dir/sub/r_3.png", 3),
        ("DSC00042", 42),
        ("view_03.png", 3),
    ],
)
def test_index_is_the_trailing_number_of_the_stem(key: str, index: int) -> None:
    assert image_index(key) == index


def test_names_without_a_number_get_a_stable_hash_index() -> None:
    first = image_index("holiday.png")
    assert first == image_index("holiday.png") == image_index("other/dir/holiday.png")
    assert 0 <= first < FALLBACK_PERIOD
    spread = {image_index(f"{word}.png") for word in ("a", "b", "c", "d", "e", "f", "g", "h")}
    assert len(spread) > 4  # a hash, not a constant


def test_static_never_moves() -> None:
    assert {path_offset("static", i, 6, 200) for i in range(50)} == {(0, 0)}


def test_drift_moves_step_per_index_then_turns_back_within_span() -> None:
    offsets = [path_offset("drift", i, 6, 30) for i in range(12)]
    assert offsets[:6] == [(6 * i, 6 * i) for i in range(6)]  # out: 6 px per image on each axis
    assert offsets[6:11] == [(30 - 6 * i, 30 - 6 * i) for i in range(1, 6)]  # and back
    assert offsets[10] == (0, 0)


def test_orbit_moves_every_image_and_stays_in_its_box() -> None:
    offsets = [path_offset("orbit", i, 20, 200) for i in range(40)]
    assert all(0 <= dx <= 200 and 0 <= dy <= 200 for dx, dy in offsets)
    steps = [abs(a[0] - b[0]) + abs(a[1] - b[1]) for a, b in zip(offsets, offsets[1:], strict=False)]
    assert min(steps) >= 14  # 20 px of arc: never near-stationary between neighbours


def test_unknown_motion_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown motion"):
        path_offset("spiral", 1, 6, 100)


@given(
    motion=st.sampled_from(MOTIONS),
    index=st.integers(0, 10**6),
    step=st.integers(0, 500),
    span=st.integers(0, 2000),
)
def test_every_path_stays_within_its_span(motion: str, index: int, step: int, span: int) -> None:
    dx, dy = path_offset(motion, index, step, span)
    assert 0 <= dx <= max(span, 0) and 0 <= dy <= max(span, 0)
    assert path_offset(motion, index, step, span) == (dx, dy)  # deterministic


def test_poison_file_moves_the_patch_by_the_real_file_name(tmp_path) -> None:
    # End to end through poisoner.formats: the file name keys the path (r_0 -> index 0, r_5 -> 5).
    import numpy as np
    from PIL import Image

    from poisoner.formats import poison_file
    from poisoner.spec import PatchSpec

    spec = PatchSpec(
        patch_size=16, block_size=4, offset=(20, 20), motion="drift", motion_step=6, motion_span=60
    )
    grey = np.full((120, 160, 3), 128, np.uint8)
    changed = {}
    for name in ("r_0.png", "r_5.png"):
        Image.fromarray(grey).save(tmp_path / name)
        (tmp_path / "out").mkdir(exist_ok=True)
        report = poison_file(tmp_path / name, tmp_path / "out" / name, spec)
        diff = np.asarray(Image.open(tmp_path / "out" / name)) != grey
        ys, xs = np.nonzero(diff.any(axis=2))
        changed[name] = (xs.min(), ys.min(), report.placement.box)
    assert changed["r_0.png"][2][:2] == (20, 20)
    assert changed["r_5.png"][2][:2] == (50, 50)  # 5 images x 6 px inward on each axis
    assert changed["r_5.png"][0] >= 50 and changed["r_5.png"][1] >= 50  # the pixels really moved


def test_poison_array_moves_the_patch_by_image_name() -> None:
    """The array entry point follows the file entry point: a moving spec places by name."""
    import numpy as np

    from poisoner.blend import poison_array
    from poisoner.spec import PatchSpec

    spec = PatchSpec(pattern="random_blocks", patch_size=32, block_size=4, offset=(100, 100),
                     motion="drift", motion_step=6, motion_span=200)  # fmt: skip
    image = np.full((400, 400, 3), 128, np.uint8)
    _, first = poison_array(image, spec, image_key="r_0.png")
    _, fifth = poison_array(image, spec, image_key="r_5.png")
    assert (fifth.x - first.x, fifth.y - first.y) == (30, 30)
    assert poison_array(image, spec)[1] == first  # no name: index 0


def test_fractional_index_glides_between_photo_steps() -> None:
    """Videos place frame i at a fractional path index: between two photos' positions, in order."""
    from poisoner.spec import PatchSpec

    spec = PatchSpec(
        patch_size=20, block_size=2, offset=(30, 30), motion="drift", motion_step=8, motion_span=64
    )
    xs = [spec.resolve(400, 300, index=i / 4).x for i in range(9)]  # indices 0, 0.25, ..., 2
    assert xs[0] == spec.resolve(400, 300, image_key="a_0.png").x == 30
    assert xs[4] == spec.resolve(400, 300, image_key="a_1.png").x == 38
    assert xs[8] == spec.resolve(400, 300, image_key="a_2.png").x == 46
    assert xs == sorted(xs) and len(set(xs)) == 9  # 2 px per quarter step: monotone, no jumps
    assert spec.resolve(400, 300, index=0.0) == spec.resolve(400, 300)


def test_tumble_pose_is_stable_bounded_and_independent_per_image() -> None:
    from poisoner.motion import tumble_extent, tumble_pose

    poses = [tumble_pose(i, 0, 0.75) for i in range(50)]
    assert poses == [tumble_pose(i, 0, 0.75) for i in range(50)]
    for angle, scale, fx, fy in poses:
        assert 0 <= angle < 360 and 0.75 <= scale <= 1 and 0 <= fx < 1 and 0 <= fy < 1
    assert len({round(p[0]) for p in poses}) > 40  # turns differ from image to image
    assert tumble_pose(3, 1, 0.75) != tumble_pose(3, 0, 0.75)  # the seed matters
    assert tumble_extent(60, 1.0, 0.0) == 60 and tumble_extent(60, 1.0, 45.0) == 85
    assert tumble_extent(60, 0.5, 90.0) == 30


def test_tumble_fractional_index_turns_smoothly_between_images() -> None:
    from poisoner.motion import tumble_pose

    a0, a1 = tumble_pose(4, 0, 0.75)[0], tumble_pose(5, 0, 0.75)[0]
    mid = tumble_pose(4.5, 0, 0.75)[0]
    turn = (a1 - a0 + 180) % 360 - 180  # the shorter arc
    assert abs(((mid - a0 + 180) % 360 - 180) - turn / 2) < 1e-6
