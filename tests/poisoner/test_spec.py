"""PatchSpec: validation, sizes in pixels or fractions, placement, ratio, serialisation."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from poisoner.spec import MIN_BLOCK_PX, PATTERNS, POSITIONS, PatchSpec, SpecError


def test_default_spec_resolves_to_the_measured_lego_setting() -> None:
    # 6% of an 800 px frame is the P=48, b=4 setting we measured protecting lego.
    p = PatchSpec().resolve(800, 800)
    assert (p.x, p.y, p.size, p.block, p.alpha8, p.contrast) == (0, 0, 48, 4, 255, 255)


def test_fraction_sizes_scale_with_width_and_block_has_a_floor() -> None:
    spec = PatchSpec(patch_size=0.02, block_size=0.005)
    big = spec.resolve(3072, 2048)
    assert big.size == round(0.02 * 3072) and big.block == round(0.005 * 3072)
    small = spec.resolve(400, 300)
    assert small.block == MIN_BLOCK_PX  # 0.005 * 400 = 2 px would be harmless (paper b=1,2)


@pytest.mark.parametrize(
    ("position", "expected"),
    [("top-left", (10, 5)), ("top-right", (1000 - 48 - 10, 5)), ("bottom-left", (10, 600 - 48 - 5)),
     ("bottom-right", (1000 - 48 - 10, 600 - 48 - 5)),
     ("center", ((1000 - 48) // 2 + 10, (600 - 48) // 2 + 5))],
)
def test_positions_and_offsets(position: str, expected: tuple[int, int]) -> None:
    p = PatchSpec(patch_size=48, block_size=4, position=position, offset=(10, 5)).resolve(1000, 600)
    assert (p.x, p.y) == expected


def test_patch_that_does_not_fit_is_refused() -> None:
    with pytest.raises(SpecError, match="does not fit"):
        PatchSpec(patch_size=100, block_size=4).resolve(80, 80)
    with pytest.raises(SpecError, match="outside"):
        PatchSpec(patch_size=48, block_size=4, offset=(60, 0)).resolve(100, 100)


@pytest.mark.parametrize(
    "kwargs",
    [dict(pattern="stars"), dict(position="middle"), dict(alpha=1.5), dict(contrast=300), dict(ratio=-0.1),
     dict(patch_size=0), dict(block_size=-3), dict(version=99)],
)
def test_invalid_specs_are_refused_with_a_clear_error(kwargs: dict) -> None:
    with pytest.raises(SpecError):
        PatchSpec(**kwargs)


@given(
    pattern=st.sampled_from(PATTERNS),
    position=st.sampled_from(POSITIONS),
    size=st.integers(4, 200),
    block=st.integers(1, 16),
    alpha=st.floats(0, 1, exclude_min=True),  # 0 is refused (test_mark_faint.py)
    contrast=st.integers(1, 255),
    ratio=st.floats(0, 1),
    seed=st.integers(0, 2**31),
)
def test_json_and_toml_round_trip(pattern, position, size, block, alpha, contrast, ratio, seed) -> None:
    spec = PatchSpec(pattern=pattern, position=position, patch_size=size, block_size=block, alpha=alpha,
                     contrast=contrast, ratio=ratio, seed=seed)
    assert PatchSpec.from_json(spec.to_json()) == spec
    assert PatchSpec.from_toml(spec.to_toml()) == spec
    assert PatchSpec.from_json(spec.to_json()).spec_id == spec.spec_id


def test_unknown_fields_are_refused() -> None:
    with pytest.raises(SpecError, match="unknown spec field"):
        PatchSpec.from_dict({"pattern": "checkerboard", "colour": "red"})


def test_ratio_selection_is_deterministic_stable_and_close_to_the_ratio() -> None:
    spec = PatchSpec(ratio=0.5, seed=7)
    names = [f"img_{i:04d}.jpg" for i in range(2000)]
    chosen = [n for n in names if spec.selects(n)]
    assert 0.45 < len(chosen) / len(names) < 0.55
    # Adding images later does not change the choice for the earlier ones.
    more = names + [f"late_{i}.jpg" for i in range(500)]
    assert [n for n in more[:2000] if spec.selects(n)] == chosen
    assert chosen != [n for n in names if PatchSpec(ratio=0.5, seed=8).selects(n)]
    assert all(PatchSpec(ratio=1.0).selects(n) for n in names[:50])
    assert not any(PatchSpec(ratio=0.0).selects(n) for n in names[:50])


# ---- issue #9: moving patches, image keys, spec ids kept ----------------------------------------
def test_spec_ids_of_specs_without_the_new_fields_are_unchanged() -> None:
    # ids recorded before issue #9 (bench/results/verify.md folders, stores): they must not move
    assert PatchSpec().spec_id == "63928d73de472b0a"
    assert PatchSpec(patch_size=48, block_size=4, alpha=1.0).spec_id == "b018b4b4e024913d"
    assert "motion" not in PatchSpec().to_dict()
    moving = PatchSpec(motion="drift", motion_step=6)
    assert moving.to_dict()["motion"] == "drift" and moving.spec_id != PatchSpec().spec_id


def test_moving_spec_round_trips_through_json_and_toml() -> None:
    spec = PatchSpec(pattern="multiscale_blocks", motion="orbit", motion_step=0.01, motion_span=200)
    assert PatchSpec.from_json(spec.to_json()) == spec
    assert PatchSpec.from_toml(spec.to_toml()) == spec


def test_static_spec_ignores_the_image_key() -> None:
    spec = PatchSpec(patch_size=48, block_size=4, offset=(100, 100))
    assert spec.resolve(800, 800, image_key="r_3.png") == spec.resolve(800, 800) == spec.resolve(
        800, 800, image_key="r_77.png"
    )
    assert not spec.moves


def test_drift_moves_inward_by_step_per_image_index() -> None:
    spec = PatchSpec(
        patch_size=48, block_size=4, offset=(100, 100), motion="drift", motion_step=6, motion_span=200
    )
    assert spec.moves
    p0, p5 = spec.resolve(800, 800, "r_0.png"), spec.resolve(800, 800, "r_5.png")
    assert (p0.x, p0.y) == (100, 100) and (p5.x, p5.y) == (130, 130)
    assert spec.resolve(800, 800) == p0  # no key: index 0
    br = spec.replace(position="bottom-right")
    q5 = br.resolve(800, 800, "r_5.png")
    assert (q5.x, q5.y) == (800 - 48 - 130, 800 - 48 - 130)  # inward from the bottom-right corner


def test_moving_patch_keeps_every_image_inside_or_is_refused() -> None:
    spec = PatchSpec(
        patch_size=0.06, offset=(0.125, 0.125), motion="orbit", motion_step=0.02, motion_span=0.4
    )
    for i in range(200):
        x0, y0, x1, y1 = spec.resolve(3072, 2048, f"{i:04d}.jpg").box
        assert x0 >= 0 and y0 >= 0 and x1 <= 3072 and y1 <= 2048
    too_far = PatchSpec(patch_size=0.2, offset=(0.5, 0.5), motion="drift", motion_step=0.05, motion_span=0.5)
    with pytest.raises(SpecError, match="outside"):
        too_far.resolve(1000, 600, "r_4.png")


@pytest.mark.parametrize("kwargs", [dict(motion="zigzag"), dict(motion_step=-1), dict(motion_span=0)])
def test_invalid_motion_fields_are_refused(kwargs: dict) -> None:
    with pytest.raises(SpecError):
        PatchSpec(**kwargs)


# ---- issue 14: the tumbling corner mark ("watermark") ---------------------------------------------
TUMBLE = PatchSpec(pattern="random_blocks", patch_size=0.075, motion="tumble", corner_region=0.2)


def test_new_fields_keep_every_stored_spec_id() -> None:
    assert PatchSpec().spec_id == "63928d73de472b0a"
    assert "corner_region" not in PatchSpec().to_dict() and "tumble_scale" not in PatchSpec().to_dict()
    assert PatchSpec(corner_region=0.15).to_dict()["corner_region"] == 0.15
    assert PatchSpec.from_json(TUMBLE.to_json()) == TUMBLE


@pytest.mark.parametrize("position", ["top-left", "top-right", "bottom-left", "bottom-right"])
@pytest.mark.parametrize(("width", "height"), [(800, 600), (400, 400), (1920, 1080), (600, 800)])
def test_tumbling_mark_stays_inside_its_corner_region(position: str, width: int, height: int) -> None:
    spec = TUMBLE.replace(position=position)
    rw, rh = int(0.2 * width), int(0.2 * height)
    for i in range(60):
        p = spec.resolve(width, height, image_key=f"IMG_{i:04d}.JPG")
        x0, y0, x1, y1 = p.box
        assert (x1 <= rw) if position.endswith("left") else (x0 >= width - rw)
        assert (y1 <= rh) if position.startswith("top") else (y0 >= height - rh)


def test_tumbling_mark_turns_scales_and_moves_per_image_not_only_translates() -> None:
    ps = [TUMBLE.resolve(800, 600, image_key=f"r_{i}.png") for i in range(20)]
    angles = {round(p.angle) for p in ps}
    scales = {round(p.scale, 2) for p in ps}
    assert len(angles) >= 15 and len(scales) >= 10
    assert all(0.75 <= p.scale <= 1.0 and p.texture_size == 60 for p in ps)
    assert TUMBLE.moves
    assert TUMBLE.resolve(800, 600, image_key="r_3.png") == ps[3]  # deterministic
    assert TUMBLE.replace(seed=1).resolve(800, 600, image_key="r_3.png").angle != ps[3].angle


def test_tumbling_mark_that_cannot_fit_or_has_no_corner_is_refused() -> None:
    with pytest.raises(SpecError, match="corner region"):
        TUMBLE.replace(patch_size=0.15).resolve(800, 600)
    with pytest.raises(SpecError, match="corner"):
        TUMBLE.replace(position="center")
    with pytest.raises(SpecError, match="corner_region"):
        PatchSpec(corner_region=0.0)
    with pytest.raises(SpecError, match="tumble_scale"):
        PatchSpec(tumble_scale=1.5)


@pytest.mark.parametrize(("width", "height"), [(640, 480), (1920, 1080), (480, 640), (320, 240)])
def test_default_lanes_anchored_at_the_far_edge_fit_at_every_step(width: int, height: int) -> None:
    """A per-photo anchor may sit as far right and down as the mark's whole path allows (a video's
    keyframe clamps it there): at every point of the slide each lane is inside the frame, and so is
    the square box that holds them (it slid back where its side, the lanes' taller extent, would
    have passed the edge on the other axis: SpecError before, and the clip failed)."""
    from poisoner.ladder import default_spec

    spec = default_spec()
    reach = max(spec.path_extent(width, height))
    anchor = (width - reach, height - reach)
    for step in range(400):
        p = spec.resolve(width, height, index=step / 4, anchor=anchor)
        side = p.lane_size
        assert 0 <= p.x <= width - p.size and 0 <= p.y <= height - p.size
        for dx, dy, _ in p.parts:
            assert 0 <= dx <= p.size - side and 0 <= dy <= p.size - side
