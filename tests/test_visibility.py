"""verifier.visibility: FLIP figures at a display size, changed area, subject contact, JPEG budget."""

from __future__ import annotations

import json

import numpy as np
import pytest

from verifier.visibility import (
    VisibilityError,
    box_in_one_corner,
    jpeg_reencode,
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
    checker = ((np.indices((size, size)).sum(axis=0) // 4) % 2 == 0)
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
