"""The paper's baselines: deterministic per image, and each does what it says."""

from __future__ import annotations

import numpy as np
import pytest

from poisoner.baselines import BaselineSpec, apply_baseline


@pytest.fixture
def textured() -> np.ndarray:
    rng = np.random.default_rng(1)
    return rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)


def test_blur_lowers_high_frequencies_more_with_bigger_kernels(textured) -> None:
    energy = [np.abs(np.diff(apply_baseline(textured, BaselineSpec("blur", k)).astype(float), axis=1)).mean()
              for k in (3, 7, 11, 21)]
    assert energy == sorted(energy, reverse=True)
    assert energy[0] < np.abs(np.diff(textured.astype(float), axis=1)).mean()


def test_noise_has_the_requested_sigma_and_is_seeded_per_image() -> None:
    grey = np.full((200, 200, 3), 128, np.uint8)
    a = apply_baseline(grey, BaselineSpec("noise", 10), "a.png")
    assert np.std(a.astype(float) - 128) == pytest.approx(10, rel=0.05)
    assert np.array_equal(a, apply_baseline(grey, BaselineSpec("noise", 10), "a.png"))
    assert not np.array_equal(a, apply_baseline(grey, BaselineSpec("noise", 10), "b.png"))


def test_jpeg_quality_orders_the_error(textured) -> None:
    err = [np.abs(apply_baseline(textured, BaselineSpec("jpeg", q)).astype(float) - textured).mean()
           for q in (10, 25, 50, 75)]
    assert err == sorted(err, reverse=True)


def test_rotation_moves_a_marker_about_the_centre() -> None:
    img = np.zeros((101, 101), np.uint8)
    img[50, 90] = 255  # 40 px right of the centre
    out = apply_baseline(img, BaselineSpec("rotation", 90))
    y, x = np.unravel_index(np.argmax(out), out.shape)
    # A positive angle turns +x towards +y in image coordinates (y down).
    assert (abs(int(x) - 50), abs(int(y) - 90)) <= (1, 1)


def test_shear_and_random_kinds_are_deterministic(textured) -> None:
    s = apply_baseline(textured, BaselineSpec("shear", 0.2, axis="x"))
    assert s.shape == textured.shape and not np.array_equal(s, textured)
    r1 = apply_baseline(textured, BaselineSpec("random_rotation", 45), "k")
    assert np.array_equal(r1, apply_baseline(textured, BaselineSpec("random_rotation", 45), "k"))
    assert not np.array_equal(r1, apply_baseline(textured, BaselineSpec("random_rotation", 45), "other"))


def test_bad_baselines_are_refused(textured) -> None:
    with pytest.raises(ValueError):
        BaselineSpec("blur", 4)
    with pytest.raises(ValueError):
        BaselineSpec("jpeg", 0)
    with pytest.raises(TypeError):
        apply_baseline(textured.astype(np.uint16), BaselineSpec("blur", 3))
