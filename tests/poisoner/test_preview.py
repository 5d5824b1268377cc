"""poisoner.preview.render_preview: side by side + nearest-neighbour zoom, pure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from poisoner.blend import apply_patch
from poisoner.preview import GAP, render_preview, to_rgb8, zoom_box
from poisoner.spec import PatchSpec


def scene(h: int = 200, w: int = 300, channels: int = 3) -> np.ndarray:
    rng = np.random.default_rng(5)
    return rng.integers(0, 256, size=(h, w, channels)).astype(np.uint8)


def test_layout_panels_and_zoom() -> None:
    original = scene()
    placement = PatchSpec(patch_size=40, block_size=4, position="center").resolve(300, 200)
    poisoned = apply_patch(original, placement)
    before = (original.copy(), poisoned.copy())
    out = render_preview(original, poisoned, placement)
    assert out.dtype == np.uint8 and out.ndim == 3 and out.shape[2] == 3
    np.testing.assert_array_equal(original, before[0])  # pure: inputs untouched
    np.testing.assert_array_equal(poisoned, before[1])
    # Top row: the full pictures (max_width not exceeded: no subsampling), outline aside.
    left, right = out[:200, :300], out[:200, 300 + GAP : 600 + GAP]
    np.testing.assert_array_equal(left[:50, :50], original[:50, :50])
    np.testing.assert_array_equal(right[:50, :50], poisoned[:50, :50])
    assert (left[placement.y, placement.x + 5] == [255, 0, 0]).all()  # red outline on the box
    # Bottom row: nearest-neighbour zoom of the patch region of the poisoned picture.
    zx0, zy0, zx1, zy1 = zoom_box(placement, 300, 200)
    scale = 300 // (zx1 - zx0)
    assert scale >= 2
    bottom = out[200 + GAP :]
    zoom_right = bottom[:, 300 + GAP :]
    for dy, dx in [(0, 0), (17, 23), (40, 41)]:
        expected = poisoned[zy0 + dy, zx0 + dx]
        block = zoom_right[dy * scale : (dy + 1) * scale, dx * scale : (dx + 1) * scale]
        assert (block == expected).all()
    np.testing.assert_array_equal(bottom[:scale, :scale].reshape(-1, 3)[0], original[zy0, zx0])


def test_zooms_fill_the_bottom_row() -> None:
    """A zoom box that does not divide the panel width still fills its panel: no empty canvas."""
    original = scene()
    placement = PatchSpec(patch_size=36, block_size=4, position="center").resolve(300, 200)
    zx0, _, zx1, _ = zoom_box(placement, 300, 200)
    assert 300 % (zx1 - zx0) != 0  # the case an integer zoom factor leaves a strip empty
    out = render_preview(original, apply_patch(original, placement), placement)
    bottom = out[200 + GAP :]
    background = (bottom == bottom[0, 300]).all(axis=2).all(axis=0)  # columns of pure gap colour
    assert background.sum() == GAP and background[300 : 300 + GAP].all()
    assert bottom.shape[1] == 600 + GAP


def test_large_pictures_are_subsampled_under_max_width() -> None:
    original = scene(h=1000, w=2000)
    placement = PatchSpec().resolve(2000, 1000)
    out = render_preview(original, apply_patch(original, placement), placement, max_width=800)
    assert out.shape[1] <= 800 + GAP


@pytest.mark.parametrize(
    "pixels",
    [
        np.full((60, 80), 7, dtype=np.uint8),
        np.full((60, 80, 4), 0, dtype=np.uint8),  # fully transparent: shows white
        np.full((60, 80, 3), 65535, dtype=np.uint16),
    ],
)
def test_to_rgb8_handles_grey_alpha_and_16bit(pixels: np.ndarray) -> None:
    rgb = to_rgb8(pixels)
    assert rgb.shape == (60, 80, 3) and rgb.dtype == np.uint8
    expected = 7 if pixels.ndim == 2 else 255
    assert (rgb == expected).all()


def test_mismatched_sizes_are_rejected() -> None:
    placement = PatchSpec(patch_size=10).resolve(50, 50)
    with pytest.raises(ValueError):
        render_preview(scene(50, 50), scene(40, 50), placement)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_oriented_placement_is_where_a_viewer_sees_the_patch(tmp_path, orientation: int) -> None:
    from PIL import Image, ImageOps

    from poisoner.preview import orient, oriented_placement

    w, h = 120, 80
    placement = PatchSpec(patch_size=20, offset=(10, 5)).resolve(w, h)
    stored = np.zeros((h, w, 3), np.uint8)
    stored[placement.y : placement.y + 20, placement.x : placement.x + 20] = 255
    im = Image.fromarray(stored)
    exif = im.getexif()
    exif[0x0112] = orientation
    im.save(tmp_path / "o.png", exif=exif)
    with Image.open(tmp_path / "o.png") as saved:
        shown = np.asarray(ImageOps.exif_transpose(saved).convert("RGB"))
    np.testing.assert_array_equal(orient(stored, orientation), shown)
    moved = oriented_placement(placement, orientation, w, h)
    assert (shown[moved.y : moved.y + 20, moved.x : moved.x + 20] == 255).all()
    assert shown.sum() == stored.sum()  # the whole patch, nothing else


def test_labels_add_a_caption_strip() -> None:
    from poisoner.preview import LABEL_HEIGHT

    original = scene()
    placement = PatchSpec(patch_size=40, block_size=4, position="center").resolve(300, 200)
    poisoned = apply_patch(original, placement)
    plain = render_preview(original, poisoned, placement)
    labelled = render_preview(original, poisoned, placement, labels=("original", "patched"))
    assert labelled.shape[0] == plain.shape[0] + LABEL_HEIGHT
    assert (labelled[:LABEL_HEIGHT] > 200).any()  # white text in the strip
    np.testing.assert_array_equal(labelled[LABEL_HEIGHT : LABEL_HEIGHT + 200], plain[:200])  # panels intact


def test_subject_edge_is_drawn_on_the_zooms() -> None:
    """With the subject mask the picture was poisoned around, its edge shows in cyan on both zooms,
    and the zoomed subject pixels of the poisoned picture are the original's."""
    from poisoner.preview import SUBJECT_EDGE

    original = scene()
    placement = PatchSpec(patch_size=40, block_size=4, position="center").resolve(300, 200)
    subject = np.zeros((200, 300), dtype=bool)
    subject[:, :150] = True  # the subject covers the mark's left half
    poisoned = apply_patch(original, placement, subject)
    out = render_preview(original, poisoned, placement, subject=subject)
    zx0, zy0, zx1, zy1 = zoom_box(placement, 300, 200)
    scale = 300 // (zx1 - zx0)
    bottom = out[200 + GAP :]
    for panel in (bottom[:, :300], bottom[:, 300 + GAP :]):
        edge_col = (149 - zx0) * scale  # the subject's last column, x = 149
        assert (panel[5 * scale, edge_col] == SUBJECT_EDGE).all()
    zoom_right = bottom[:, 300 + GAP :]
    dx = 140 - zx0  # inside the subject, inside the mark: untouched
    assert (zoom_right[20 * scale, dx * scale] == original[zy0 + 20, 140]).all()
    with pytest.raises(ValueError, match="subject mask"):
        render_preview(original, poisoned, placement, subject=subject[:10])


def test_split_squares_are_outlined_and_zoomed_each() -> None:
    """Squares that went to places of their own: their common box was outlined and 'zoomed' (most of
    the picture: no zoom at all; a black-box review). Each square now gets its outline and its row."""
    original = scene()
    placement = PatchSpec(patch_size=40, block_size=4, position="center").resolve(300, 200)
    squares = [(10, 10, 30, 30), (250, 160, 270, 180)]
    out = render_preview(original, original, placement, squares=squares)
    left = out[:200, :300]
    for x0, y0, _, _ in squares:
        assert (left[y0, x0 + 5] == [255, 0, 0]).all()  # outlined
    assert not (left[placement.y, placement.x + 5] == [255, 0, 0]).all()  # not the common box
    rows = 1 + len(squares)
    first = zoom_box(dataclasses.replace(placement, x=10, y=10, size=20), 300, 200)
    zoom_height = round(300 * (first[3] - first[1]) / (first[2] - first[0]))
    assert out.shape[0] >= 200 + (rows - 1) * (zoom_height + GAP) - GAP
    # the first zoom row shows the first square's region, enlarged
    np.testing.assert_array_equal(out[200 + GAP, 0], original[first[1], first[0]])
