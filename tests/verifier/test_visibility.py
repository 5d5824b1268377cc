"""verifier.visibility: FLIP figures at a display size, changed area, subject contact, JPEG budget."""

from __future__ import annotations

import json
from pathlib import Path

import msgspec
import numpy as np
import pytest

from verifier.visibility import (
    VisibilityError,
    box_in_one_corner,
    dataset_visibility_from_json,
    jpeg_reencode,
    measure_pairs,
    sample_evenly,
    visibility_report,
)

W, H, DISPLAY = 240, 180, 480  # small, so FLIP runs in well under a second


def photo_like(seed: int = 0) -> np.ndarray:
    """A smooth image with some mid-frequency detail (JPEG q85 handles it well, as on photos)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W]
    base = 120 + 60 * np.sin(xx / 23.0) * np.cos(yy / 31.0)
    detail = np.kron(rng.normal(0, 12, (H // 6, W // 6)), np.ones((6, 6)))
    rgb = np.stack([base + detail, base * 0.9 + detail, base * 0.8 + 20], axis=2)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def with_square(img: np.ndarray, x: int, y: int, size: int) -> np.ndarray:
    out = img.copy()
    checker = (np.indices((size, size)).sum(axis=0) // 4) % 2 == 0
    out[y : y + size, x : x + size] = np.where(checker, 0, 255)[..., None]
    return out


def test_identical_images_score_zero_everywhere() -> None:
    img = photo_like()
    v = visibility_report(img, img, display_width=DISPLAY, jpeg_reference=False)
    assert (v.flip_mean, v.flip_p999, v.flip_max, v.area_above_half, v.changed_area) == (0, 0, 0, 0, 0)
    assert v.changed_box is None and v.in_one_corner is None


def test_a_glaring_square_is_seen_and_a_jpeg_q85_is_not() -> None:
    img = photo_like()
    square = visibility_report(img, with_square(img, 10, 10, 24), display_width=DISPLAY)
    jpeg = visibility_report(img, jpeg_reencode(img), display_width=DISPLAY, jpeg_reference=False)
    assert square.flip_p999 > 0.7 and square.area_above_half > 0.001
    assert jpeg.flip_p999 < 0.4 and jpeg.area_above_half < 0.001
    # the budget: the square is far above the JPEG's p99.9, and the report says so
    assert square.jpeg_p999 == pytest.approx(jpeg.flip_p999)
    assert square.p999_vs_jpeg is not None and square.p999_vs_jpeg > 2
    # the whole-image mean hides the square (the reason for local figures)
    assert square.flip_mean < jpeg.flip_mean


def test_changed_area_box_corner_and_subject_contact() -> None:
    img = photo_like()
    marked = with_square(img, 5, 6, 20)
    subject = np.zeros((H, W), dtype=np.uint8)
    subject[60:150, 80:200] = 255
    v = visibility_report(img, marked, display_width=DISPLAY, subject_mask=subject, jpeg_reference=False)
    assert v.changed_box == (5, 6, 25, 26)
    assert v.changed_area == pytest.approx(np.any(marked != img, axis=2).mean())
    assert v.in_one_corner is True and v.touches_subject is False
    middle = with_square(img, 100, 80, 20)
    w = visibility_report(img, middle, display_width=DISPLAY, subject_mask=subject, jpeg_reference=False)
    assert w.in_one_corner is False and w.touches_subject is True


def test_display_width_and_ppd_are_reported_and_change_the_figures() -> None:
    img = photo_like()
    marked = with_square(img, 10, 10, 8)
    small = visibility_report(img, marked, display_width=W, ppd=67.0, jpeg_reference=False)
    big = visibility_report(img, marked, display_width=2 * W, ppd=67.0, jpeg_reference=False)
    assert (small.display_width, big.display_width, small.ppd) == (W, 2 * W, 67.0)
    assert small.area_above_half != big.area_above_half


def test_result_is_json_able() -> None:
    img = photo_like()
    d = visibility_report(img, with_square(img, 0, 0, 10), display_width=DISPLAY).to_dict()
    assert json.loads(json.dumps(d))["changed_box"] == [0, 0, 10, 10]


def test_rgba_and_grey_inputs_are_accepted() -> None:
    img = photo_like()
    rgba = np.concatenate([img, np.full((H, W, 1), 255, np.uint8)], axis=2)
    v = visibility_report(rgba, rgba, display_width=DISPLAY, jpeg_reference=False)
    assert v.flip_max == 0
    grey = img[..., 0]
    assert visibility_report(grey, grey.copy(), display_width=DISPLAY, jpeg_reference=False).changed_area == 0


@pytest.mark.parametrize(
    ("a", "b", "kwargs", "match"),
    [
        ((10, 10, 3), (10, 12, 3), {}, "differ in size"),
        ((10, 10, 3), (10, 10, 3), {"display_width": 2}, "display width"),
        ((10, 10, 3), (10, 10, 3), {"subject_mask": np.zeros((5, 5))}, "subject mask"),
    ],
)
def test_bad_input_is_one_clear_error(a: tuple, b: tuple, kwargs: dict, match: str) -> None:
    with pytest.raises(VisibilityError, match=match):
        visibility_report(np.zeros(a, np.uint8), np.zeros(b, np.uint8), jpeg_reference=False, **kwargs)
    with pytest.raises(VisibilityError, match="uint8"):
        visibility_report(np.zeros((4, 4, 3)), np.zeros((4, 4, 3)))


def test_box_in_one_corner() -> None:
    assert box_in_one_corner((0, 0, 20, 20), 100, 100, 0.2)
    assert box_in_one_corner((85, 81, 100, 100), 100, 100, 0.2)  # bottom-right
    assert not box_in_one_corner((0, 0, 21, 20), 100, 100, 0.2)
    assert not box_in_one_corner((0, 0, 100, 10), 100, 100, 0.2)  # a band along the top is not one corner


# ---- the verification's stage: a few files of a dataset ----------------------------------------
def _pair_folders(
    root: Path, n: int = 5, marked: bool = True, x: int = 5, y: int = 6
) -> list[tuple[Path, Path]]:
    """n photo-like originals and their copies, the copies marked with a square (or untouched)."""
    from PIL import Image

    clean, pois = root / "clean", root / "poisoned"
    clean.mkdir()
    pois.mkdir()
    pairs = []
    for i in range(n):
        img = photo_like(i)
        Image.fromarray(img).save(clean / f"{i:06d}.png")
        Image.fromarray(with_square(img, x, y, 20) if marked else img).save(pois / f"{i:06d}.png")
        pairs.append((clean / f"{i:06d}.png", pois / f"{i:06d}.png"))
    return pairs


def test_measure_pairs_sees_a_mark_and_nothing_on_an_untouched_copy(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    marked = measure_pairs(_pair_folders(tmp_path / "a"), sample=2)
    untouched = measure_pairs(_pair_folders(tmp_path / "b", marked=False), sample=2)
    assert marked is not None and untouched is not None
    assert (marked.measured, marked.total) == (2, 5)
    assert [m.name for m in marked.images] == ["000000.png", "000004.png"]  # spread: first and last
    assert marked.worst.area_above_half > 0 and marked.worst.changed_area > 0
    assert marked.worst.in_one_corner is True and marked.worst.p999_vs_jpeg > 1
    assert untouched.worst.area_above_half == 0 and untouched.worst.changed_area == 0
    assert untouched.worst.flip_max == 0 and untouched.worst.in_one_corner is None
    # judged at min(1920, width): these files are W px wide, so at W
    assert marked.worst.display_width == W and all(m.figures.display_width == W for m in marked.images)


def test_dataset_visibility_lines_and_json_round_trip(tmp_path: Path) -> None:
    vis = measure_pairs(_pair_folders(tmp_path), sample=1)
    assert vis is not None
    text = "\n".join(vis.lines())
    assert f"{vis.worst.area_above_half:.2%} of the picture clearly visible (FLIP > 0.5)" in text
    assert f"p99.9 {vis.worst.flip_p999:.2f}" in text and "worst of 1 of 5 images" in text
    assert "inside one corner region" in text
    again = dataset_visibility_from_json(json.loads(json.dumps(msgspec.to_builtins(vis))))
    assert again == vis
    assert dataset_visibility_from_json(None) is None


def test_subject_masks_are_found_by_name_or_frame_number(tmp_path: Path) -> None:
    from PIL import Image

    from poisoner.subject import mask_path

    pairs = _pair_folders(tmp_path, n=3, x=100, y=80)  # a square in the middle
    masks = tmp_path / "mask"
    masks.mkdir()
    for i in range(3):  # DTU names 000002.png's mask 002.png
        m = np.zeros((H, W), np.uint8)
        m[60:150, 80:200] = 255
        Image.fromarray(m).save(masks / f"{i:03d}.png")
    assert mask_path(masks, "000002.png") == masks / "002.png"
    assert mask_path(masks, "other.png") is None
    vis = measure_pairs(pairs, sample=3, subject_mask_dir=masks)
    assert vis is not None and vis.subject_masks
    assert vis.worst.touches_subject is True and vis.worst.in_one_corner is False
    assert "changed pixels touch the subject mask" in "\n".join(vis.lines())
    (tmp_path / "c").mkdir()
    corner = measure_pairs(_pair_folders(tmp_path / "c", n=3), sample=3, subject_mask_dir=masks)
    assert corner is not None and corner.worst.touches_subject is False


def test_unreadable_files_are_listed_not_fatal(tmp_path: Path) -> None:
    pairs = _pair_folders(tmp_path, n=2)
    pairs[0][1].write_bytes(b"not an image")
    vis = measure_pairs(pairs, sample=2)
    assert vis is not None and vis.measured == 1 and vis.skipped[0].startswith("000000.png")
    assert measure_pairs([pairs[0]], sample=1) is None


def test_sample_evenly() -> None:
    assert sample_evenly(10, 3) == [0, 4, 9]  # round(4.5) is 4 (banker's rounding)
    assert sample_evenly(2, 3) == [0, 1] and sample_evenly(5, 1) == [0] and sample_evenly(0, 3) == []


def test_a_smaller_subject_mask_is_read_at_the_image_size(tmp_path: Path) -> None:
    """Masks are often kept smaller: they are resized (nearest) instead of skipping the image."""
    from PIL import Image

    pairs = _pair_folders(tmp_path, n=2, x=100, y=80)  # a square in the middle
    masks = tmp_path / "mask"
    masks.mkdir()
    for original, _ in pairs:
        m = np.zeros((H // 2, W // 2), np.uint8)
        m[30:75, 40:100] = 255  # the middle, at half the size
        Image.fromarray(m).save(masks / original.name)
    vis = measure_pairs(pairs, sample=2, subject_mask_dir=masks)
    assert vis is not None and vis.measured == 2 and not vis.skipped
    assert vis.worst.touches_subject is True


# ---- the local evaluation and the quick answer (issue 28: `ppd preview` in seconds) ------------
def big_photo(seed: int = 3) -> np.ndarray:
    """A 960 x 720 photo-like picture: large enough that the mark is a small part of it."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:720, 0:960]
    base = 120 + 60 * np.sin(xx / 37.0) * np.cos(yy / 23.0)
    detail = np.kron(rng.normal(0, 14, (120, 160)), np.ones((6, 6)))
    rgb = np.stack([base + detail, base * 0.9 + detail, base * 0.7 + 30 - detail], axis=2)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def test_flip_around_a_local_mark_is_the_whole_pictures_flip() -> None:
    from verifier.visibility import FLIP_DEFAULT_PPD, flip_map, local_flip_map, to_display

    a = big_photo()
    b = with_square(a, 30, 600, 64)  # a mark in one corner
    ref, test = to_display(a, 640), to_display(b, 640)
    whole = flip_map(ref, test)
    local = local_flip_map(ref, test, (30, 600, 94, 664), 960, FLIP_DEFAULT_PPD)
    assert whole.max() > 0.5 and np.array_equal(whole, local)  # the same map, bit for bit


def test_the_quick_answer_gives_the_marks_figures_and_estimates_the_budget() -> None:
    a = big_photo()
    b = with_square(a, 860, 20, 64)
    exact = visibility_report(a, b, display_width=640)
    quick = visibility_report(a, b, display_width=640, jpeg_sample=0.1)
    # the mark's own figures: the same up to the region resize's rounding
    for field in ("flip_mean", "flip_p99", "flip_p999", "flip_max", "area_above_half"):
        assert getattr(quick, field) == pytest.approx(getattr(exact, field), rel=0.02, abs=1e-4), field
    assert quick.changed_area == exact.changed_area and quick.changed_box == exact.changed_box
    assert exact.jpeg_p999 is not None and quick.jpeg_p999 is not None
    assert quick.jpeg_p999 == pytest.approx(exact.jpeg_p999, rel=0.15)  # an estimate from a tenth
    assert quick.p999_vs_jpeg > 1 and exact.p999_vs_jpeg > 1  # the square is far above the budget
    untouched = visibility_report(a, a.copy(), display_width=640, jpeg_sample=0.1)
    assert untouched.flip_max == 0.0 and untouched.changed_box is None
