"""Issue 30: the block measured as COLMAP's SIFT sees the photo (PatchSpec.sift_edge), and the measured
mark that uses it (WATERMARK_LANES_3_SPEC, not the default, not offered by name): the same pixels as
watermark-lanes-2 up to 1600 px, 4 px blocks as SIFT sees larger photos, the lanes' rules kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.blend import apply_patch
from poisoner.formats import poison_file
from poisoner.ladder import WATERMARK_LANES_2_SPEC, WATERMARK_LANES_3_SPEC, named_spec, named_specs
from poisoner.spec import LANES_MAX_AREA, SIFT_MAX_EDGE, PatchSpec, SpecError

NEW, OLD = WATERMARK_LANES_3_SPEC, WATERMARK_LANES_2_SPEC
UP_TO_1600 = [(640, 480), (800, 600), (800, 800), (600, 800), (1024, 683), (1200, 1600), (1600, 1066),
              (1600, 1200), (1600, 900)]  # fmt: skip


def test_watermark_lanes_3_is_lanes_2_with_4_px_blocks_as_sift_sees_the_photo() -> None:
    assert OLD.replace(block_size=4, sift_edge=SIFT_MAX_EDGE) == NEW
    assert named_spec("watermark-lanes-2") == OLD
    assert NEW not in named_specs().values()  # measured, not offered
    assert OLD.spec_id == "db31915163f28c84"  # sift_edge at 0 stays out of the id: stored specs keep theirs
    assert "sift_edge" not in OLD.to_dict() and NEW.to_dict()["sift_edge"] == 3200
    assert PatchSpec.from_json(NEW.to_json()) == NEW


@pytest.mark.parametrize(("w", "h"), UP_TO_1600)
def test_up_to_1600_px_every_placement_is_the_old_one(w: int, h: int) -> None:
    for i in range(0, 40, 3):
        name = f"IMG_{i:04d}.jpg"
        assert NEW.resolve(w, h, name) == OLD.resolve(w, h, name), (w, h, name)
        anchor = (w // 7, h // 9)
        assert NEW.resolve(w, h, name, anchor=anchor) == OLD.resolve(w, h, name, anchor=anchor)


@pytest.mark.parametrize(("w", "h", "fmt"), [(1600, 1066, "JPEG"), (800, 800, "PNG"), (1200, 1600, "JPEG")])
def test_up_to_1600_px_the_written_file_is_byte_identical(tmp_path: Path, w: int, h: int, fmt: str) -> None:
    rng = np.random.default_rng(w + h)
    photo = np.full((h, w, 3), 200, np.uint8)
    photo[h // 3 :, w // 4 : 3 * w // 4] = rng.integers(0, 256, (h - h // 3, 3 * w // 4 - w // 4, 3))
    src = tmp_path / f"IMG_0007.{fmt.lower()[:3]}"
    Image.fromarray(photo).save(src, fmt)
    poison_file(src, tmp_path / "old", OLD)
    poison_file(src, tmp_path / "new", NEW)
    old, new = (tmp_path / "old").read_bytes(), (tmp_path / "new").read_bytes()
    assert old == new
    assert old != src.read_bytes()  # the mark was written


@pytest.mark.parametrize(
    ("w", "h", "block"),
    [(1920, 1080, 4), (2400, 1600, 4), (3200, 2133, 4), (3840, 2160, 5), (4500, 3000, 6), (6000, 4000, 8),
     (4000, 6000, 8), (8000, 5333, 10), (12000, 8000, 15)],
)  # fmt: skip
def test_above_the_sift_edge_the_block_is_4_px_as_sift_sees_it(w: int, h: int, block: int) -> None:
    placement = NEW.resolve(w, h, "IMG_0003.jpg")
    assert placement.block == block
    seen = placement.block * min(1.0, SIFT_MAX_EDGE / max(w, h))
    assert abs(seen - 4) <= 0.5  # whole stored pixels, the nearest to 4 seen
    assert placement.lane_size == OLD.resolve(w, h, "IMG_0003.jpg").lane_size  # only the blocks change


def test_lanes_at_6000_px_stay_pixel_identical_whole_pixel_and_within_the_area_budget() -> None:
    w, h = 6000, 4000
    photo = np.full((h, w, 3), 128, np.uint8)
    squares = []
    for name in ("IMG_0001.jpg", "IMG_0002.jpg", "IMG_0005.jpg"):
        p = NEW.resolve(w, h, name)
        out = apply_patch(photo, p)
        changed = np.any(out != photo, axis=2)
        assert changed.sum() <= LANES_MAX_AREA * w * h <= 0.01 * w * h
        lanes = []
        for dx, dy, _seed in p.parts:
            x, y, s = p.x + dx, p.y + dy, p.lane_size
            lanes.append(out[y : y + s, x : x + s])
        squares.append(lanes)
    for lanes in squares[1:]:  # every photo's lane k is the same square of pixels
        for k, lane in enumerate(lanes):
            assert np.array_equal(lane, squares[0][k])
    blocks = squares[0][0][..., 0] < 128  # dark blocks of 8 px
    grid = blocks[::8, ::8].repeat(8, 0).repeat(8, 1)
    assert np.array_equal(grid[: blocks.shape[0], : blocks.shape[1]], blocks)


@pytest.mark.parametrize("bad", [-1, True, 3200.0, "3200"])
def test_a_bad_sift_edge_is_refused(bad: object) -> None:
    with pytest.raises(SpecError, match="sift_edge"):
        PatchSpec(sift_edge=bad)  # type: ignore[arg-type]


def test_a_fraction_block_is_measured_on_the_picture_sift_sees() -> None:
    spec = PatchSpec(patch_size=0.06, block_size=0.001, sift_edge=3200)
    assert spec.resolve(6400, 4800).block == 8  # 0.1% of 3200 = 3 px seen, raised to 4 seen: 8 stored
    assert PatchSpec(patch_size=0.06, block_size=0.001).resolve(6400, 4800).block == 6  # 0.1% of 6400
    assert spec.resolve(1600, 1200).block == 4  # no downscale: as without sift_edge (the floor)
