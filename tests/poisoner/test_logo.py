"""A creator's text or logo as the mark's shape (poisoner/logo.py, PatchSpec.mark_text/mark_image)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageDraw

from poisoner.blend import apply_patch, patch_coverage
from poisoner.corner import corner_box
from poisoner.ladder import WATERMARK_SPEC
from poisoner.logo import LogoError, image_shape, text_shape
from poisoner.spec import PatchSpec, SpecError

SIGNATURE = "\u00a9 Ana 2026"


def _photo(shared_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    root = shared_dir / "datasets" / "dtu_scan37"
    if not root.is_dir():
        pytest.skip("dtu_scan37 not in the shared datasets")
    with Image.open(root / "images" / "000000.png") as im:
        photo = np.asarray(im.convert("RGB").resize((800, 600), Image.Resampling.LANCZOS))
    with Image.open(root / "mask" / "000.png") as m:
        mask = np.asarray(m.convert("L").resize((800, 600), Image.Resampling.NEAREST)) > 127
    return photo, mask


def test_text_shape_is_the_glyphs_not_the_square() -> None:
    shape = text_shape(SIGNATURE, 80)
    assert shape.shape == (80, 80) and shape.dtype == bool
    assert 0.15 < shape.mean() < 0.7  # ink, with background between the glyphs
    assert not np.array_equal(shape, text_shape("Ana", 80))
    assert np.array_equal(shape, text_shape(SIGNATURE, 80))  # deterministic
    with pytest.raises(LogoError, match="empty"):
        text_shape("   ", 80)


def test_strokes_hold_texture_blocks() -> None:
    """Every glyph stroke is at least a 4 px block thick somewhere: the texture's corners fit in it."""
    shape = text_shape(SIGNATURE, 80)
    core = shape[:-3, :-3] & shape[3:, :-3] & shape[:-3, 3:] & shape[3:, 3:]  # 4x4 squares of ink
    assert core.sum() > 0.2 * shape.sum()


def test_static_text_mark_changes_only_glyph_pixels(shared_dir: Path) -> None:
    photo, _ = _photo(shared_dir)
    spec = PatchSpec(pattern="random_blocks", patch_size=80, block_size=4, mark_text=SIGNATURE)
    placement = spec.resolve(800, 600)
    out = apply_patch(photo, placement)
    changed = np.any(out != photo, axis=2)
    x0, y0, x1, y1 = placement.box
    glyphs = np.zeros_like(changed)
    glyphs[y0:y1, x0:x1] = text_shape(SIGNATURE, 80)
    assert changed.any()
    assert not (changed & ~glyphs).any()  # nothing outside the glyphs, so nothing outside their box
    assert changed.sum() > 0.3 * glyphs.sum()  # the texture's dark and bright blocks both show
    assert np.array_equal(patch_coverage(placement), text_shape(SIGNATURE, 80))


def test_tumbling_text_mark_stays_in_the_corner_off_the_subject(shared_dir: Path) -> None:
    photo, mask = _photo(shared_dir)
    spec = WATERMARK_SPEC.replace(mark_text=SIGNATURE, patch_size=0.1)
    for i in range(0, 40, 4):
        name = f"{i:06d}.png"
        placement = spec.resolve(800, 600, image_key=name)
        out = apply_patch(photo, placement, keep_out=mask)
        changed = np.any(out != photo, axis=2)
        assert changed.any(), name
        x0, y0, x1, y1 = corner_box("top-left", 800, 600, 0.2)
        outside = changed.copy()
        outside[y0:y1, x0:x1] = False
        assert not outside.any(), name
        assert not (changed & mask).any(), name
        assert changed.mean() <= 0.01, name
        px0, py0, px1, py1 = placement.box
        assert not changed[:py0].any() and not changed[:, :px0].any()  # inside the turned mark's box
        assert not changed[py1:].any() and not changed[:, px1:].any()


def test_logo_png_alpha_is_the_shape(tmp_path: Path) -> None:
    logo = Image.new("RGBA", (200, 100), (0, 0, 0, 0))
    ImageDraw.Draw(logo).ellipse((10, 10, 190, 90), fill=(200, 30, 30, 255))
    path = tmp_path / "logo.png"
    logo.save(path)
    shape = image_shape(path, 60)
    assert shape.shape == (60, 60)
    rows = np.nonzero(shape.any(axis=1))[0]
    assert shape[30, 30] and not shape[0, 0]
    assert 25 <= len(rows) <= 35  # a 2:1 ellipse fitted to the square's width: half as tall
    spec = PatchSpec(pattern="random_blocks", patch_size=60, block_size=4, mark_image=str(path))
    assert np.array_equal(patch_coverage(spec.resolve(400, 300)), shape)


def test_bad_marks_are_spec_errors(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="not both"):
        PatchSpec(mark_text="A", mark_image="a.png")
    with pytest.raises(SpecError, match="blank"):
        PatchSpec(mark_text="  ")
    not_image = tmp_path / "logo.png"
    not_image.write_text("not a picture")
    with pytest.raises(SpecError, match="cannot read logo"):
        PatchSpec(patch_size=60, mark_image=str(not_image)).resolve(400, 300)
    with pytest.raises(SpecError, match="cannot read logo"):
        PatchSpec(patch_size=60, mark_image=str(tmp_path / "missing.png")).resolve(400, 300)


def test_mark_fields_keep_old_spec_ids_and_round_trip() -> None:
    assert PatchSpec().spec_id == "63928d73de472b0a"
    assert "mark_text" not in PatchSpec().to_dict()
    spec = WATERMARK_SPEC.replace(mark_text=SIGNATURE)
    assert spec.spec_id != WATERMARK_SPEC.spec_id
    assert PatchSpec.from_json(spec.to_json()) == spec
    assert PatchSpec.from_toml(spec.to_toml()) == spec
