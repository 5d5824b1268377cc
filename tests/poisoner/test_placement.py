"""Subject-aware placement of a corner mark (poisoner/placement.py) on dtu_scan37's real masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.blend import apply_patch
from poisoner.corner import CORNERS, choose_corner, corner_box, corner_cover, keep_out_mask
from poisoner.ladder import WATERMARK_SPEC


def _dtu(shared_dir: Path, width: int = 800) -> tuple[list[str], list[np.ndarray], list[np.ndarray]]:
    root = shared_dir / "datasets" / "dtu_scan37"
    if not root.is_dir():
        pytest.skip("dtu_scan37 not in the shared datasets")
    names, photos, masks = [], [], []
    for p in sorted((root / "images").glob("*.png"))[::4]:  # 7 of the 25 views: the test stays quick
        with Image.open(p) as im:
            h = round(im.height * width / im.width)
            photos.append(np.asarray(im.convert("RGB").resize((width, h), Image.Resampling.LANCZOS)))
        with Image.open(root / "mask" / f"{int(p.stem):03d}.png") as m:
            masks.append(np.asarray(m.convert("L").resize((width, h), Image.Resampling.NEAREST)) > 127)
        names.append(p.name)
    return names, photos, masks


def test_corner_box_of_each_corner() -> None:
    assert corner_box("top-left", 800, 600, 0.2) == (0, 0, 160, 120)
    assert corner_box("bottom-right", 800, 600, 0.2) == (640, 480, 800, 600)
    with pytest.raises(ValueError, match="unknown corner"):
        corner_box("center", 800, 600, 0.2)


def test_subject_in_one_corner_sends_the_mark_to_the_opposite_one() -> None:
    mask = np.zeros((300, 400), dtype=bool)
    mask[:100, :150] = True  # subject fills the top-left
    assert choose_corner([mask]) == "bottom-right"
    mask2 = np.zeros((300, 400), dtype=bool)
    mask2[200:, 300:] = True  # subject at the bottom-right
    assert choose_corner([mask2]) == "top-left"
    # keep_out counts like the subject: the creator's own logo area at the top-left
    assert choose_corner([mask2], keep_out=mask) in ("top-right", "bottom-left")


def test_no_mask_gives_the_default_corner() -> None:
    assert choose_corner([None, None]) == "top-left"
    assert choose_corner([], default="bottom-left") == "bottom-left"


def test_dtu_corner_is_the_least_covered_one(shared_dir: Path) -> None:
    _, _, masks = _dtu(shared_dir)
    corner = choose_corner(masks)
    union = np.any(np.stack(masks), axis=0)
    cover = corner_cover(union, 0.2)
    assert set(cover) == set(CORNERS)
    assert cover[corner] == min(cover.values())
    assert cover[corner] < max(cover.values())  # the masks do discriminate between corners


def test_dtu_mark_stays_in_its_corner_and_off_the_subject(shared_dir: Path) -> None:
    names, photos, masks = _dtu(shared_dir)
    corner = choose_corner(masks)
    spec = WATERMARK_SPEC.replace(position=corner)
    for name, photo, mask in zip(names, photos, masks, strict=True):
        h, w = mask.shape
        keep = keep_out_mask(mask, margin=2)
        out = apply_patch(photo, spec.resolve(w, h, image_key=name), keep)
        changed = np.any(out != photo, axis=2)
        assert changed.sum() > 0.001 * changed.size, name  # the mark is there
        assert changed.mean() <= 0.01, name
        x0, y0, x1, y1 = corner_box(corner, w, h, 0.2)
        outside = changed.copy()
        outside[y0:y1, x0:x1] = False
        assert not outside.any(), name
        assert not (changed & keep).any(), name


def test_subject_reaching_into_the_corner_is_never_written(shared_dir: Path) -> None:
    """A subject mask that covers part of the chosen corner: those pixels stay as they were."""
    names, photos, masks = _dtu(shared_dir)
    photo, mask = photos[0], masks[0].copy()
    h, w = mask.shape
    spec = WATERMARK_SPEC.replace(position="top-left")
    placement = spec.resolve(w, h, image_key=names[0])
    x0, y0, x1, y1 = placement.box
    mask[y0 : (y0 + y1) // 2, x0:x1] = True  # the subject covers the mark's upper half
    out = apply_patch(photo, placement, keep_out_mask(mask))
    changed = np.any(out != photo, axis=2)
    assert changed.any()
    assert not (changed & mask).any()


def test_keep_out_margin_grows_the_mask() -> None:
    mask = np.zeros((20, 20), dtype=bool)
    mask[10, 10] = True
    grown = keep_out_mask(mask, margin=2)
    assert grown is not None
    assert grown.sum() == 25 and grown[8:13, 8:13].all()
    assert keep_out_mask(None) is None


def test_corner_bound_says_which_specs_live_in_one_corner() -> None:
    """A dataset's corner may be chosen off its subject only for marks confined to one corner region."""
    from poisoner.ladder import named_specs
    from poisoner.spec import PatchSpec

    specs = named_specs()
    assert specs["watermark"].corner_bound and specs["watermark-lanes"].corner_bound
    assert specs["watermark"].replace(motion="spin").corner_bound
    assert not specs["roaming"].corner_bound  # roams over the frame
    assert not specs["paper"].corner_bound  # the static reference keeps its corner
    assert not PatchSpec(motion="drift", motion_step=0.01).corner_bound
    assert not PatchSpec(motion="slide", motion_step=0.01, position="center").corner_bound
