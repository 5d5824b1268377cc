"""verifier.auto_visibility: what a viewer sees of a candidate (FLIP), the paper's SSIM/LPIPS
reported beside it, and the budget in FLIP terms (SSIM and LPIPS never gate)."""

from __future__ import annotations

import numpy as np
import pytest

from poisoner.blend import poison_array
from poisoner.spec import PatchSpec
from verifier.auto_options import PreflightInputError, PreflightOptions, VisibilityBudget
from verifier.auto_visibility import (
    SampleVisibility,
    budget_notes,
    budget_use,
    measure_image,
    whole_image_ssim,
    within_budget,
)
from verifier.metrics import ssim


def _textured(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = rng.random((h // 8 + 1, w // 8 + 1, 3))
    return np.kron(base, np.ones((8, 8, 1)))[:h, :w]


@pytest.mark.parametrize("position", ["top-left", "bottom-right", "center"])
def test_local_ssim_equals_the_full_computation(position: str) -> None:
    clean = (_textured(120, 160) * 255).astype(np.uint8)
    pois, _ = poison_array(clean, PatchSpec(patch_size=24, block_size=4, position=position))
    a, b = clean / 255.0, pois / 255.0
    assert whole_image_ssim(a, b) == pytest.approx(ssim(a, b), abs=1e-12)
    assert whole_image_ssim(a, b) < 0.999  # the patch is there and costs something
    assert whole_image_ssim(a, a) == 1.0


def test_visibility_is_what_a_viewer_sees_and_lpips_is_said_not_measured() -> None:
    a = (_textured(64, 64) * 255).astype(np.uint8)
    b = a.copy()
    b[2:10, 2:10] = 255  # an 8 x 8 white square in the top-left corner region
    budget = VisibilityBudget()  # 1920 px wide: a 64 px image is judged at its own size
    v = measure_image(a, b, budget, None)
    assert v.display_width == 64
    assert measure_image(a, b, VisibilityBudget(display_width=32), None).display_width == 32
    assert v.lpips is None  # not measured, never pretended
    assert v.ssim == pytest.approx(ssim(a / 255.0, b / 255.0), abs=1e-12)
    assert v.changed_area == pytest.approx(64 / 64**2, rel=0.2)  # pixels that happened to be white stay
    assert v.noticeable_area > 0.005 and v.flip_p999 > 0.5  # a viewer sees it
    assert v.in_one_corner is True and v.p999_vs_jpeg is None
    moved = a.copy()
    moved[28:36, 28:36] = 255  # the same square in the middle
    assert measure_image(a, moved, budget, None, jpeg_p999=0.1).in_one_corner is False
    assert measure_image(a, moved, budget, None, jpeg_p999=0.1).p999_vs_jpeg > 5
    same = measure_image(a, a, budget, None)
    assert (same.noticeable_area, same.flip_p999, same.ssim, same.in_one_corner) == (0.0, 0.0, 1.0, None)


def test_visibility_with_lpips_when_installed() -> None:
    lpips_mod = pytest.importorskip("verifier.lpips")
    ok, why = lpips_mod.lpips_available("vgg")
    if not ok:
        pytest.skip(why)
    a = (_textured(96, 96) * 255).astype(np.uint8)
    b = a.copy()
    b[0:16, 0:16] = 0
    model = lpips_mod.Lpips("vgg")
    budget = VisibilityBudget(display_width=96)
    assert measure_image(a, b, budget, model).lpips > 0.0
    assert measure_image(a, a, budget, model).lpips == 0.0


def _sample(area: float, ratio: float | None = None, corner: bool | None = True) -> SampleVisibility:
    return SampleVisibility(images=4, display_width=320, noticeable_area_max=area, flip_p999_max=0.9,
                            flip_mean_max=0.01, changed_area_max=area, in_one_corner=corner,
                            p999_vs_jpeg_max=ratio, ssim_min=0.98, ssim_mean=0.99, lpips_max=0.5,
                            lpips_mean=0.4)  # fmt: skip


def test_budget_is_flip_terms_and_ssim_lpips_do_not_gate() -> None:
    budget = VisibilityBudget(max_noticeable_area=0.01)
    fits = _sample(0.005)  # SSIM 0.98 and LPIPS 0.5 would have failed the old budget: reported only
    assert budget_use(fits, budget) == pytest.approx(0.5) and within_budget(fits, budget)
    assert budget_notes(fits, budget) == []
    over = _sample(0.03)
    assert budget_use(over, budget) == pytest.approx(3.0) and not within_budget(over, budget)
    assert budget_notes(over, budget) == [
        "3.00% of the picture noticeably changed (FLIP > 0.5) > 1.00% on the worst sample image"
    ]
    jpeg = VisibilityBudget(max_noticeable_area=0.01, max_p999_vs_jpeg=2.0)
    assert budget_use(_sample(0.005, ratio=3.0), jpeg) == pytest.approx(1.5)
    assert budget_use(_sample(0.005, ratio=3.0), budget) == pytest.approx(0.5)  # 0: the ratio not gated
    assert "JPEG q85" in budget_notes(_sample(0.005, ratio=3.0), jpeg)[0]
    corner = VisibilityBudget(corner_only=True)
    assert within_budget(_sample(0.005, corner=True), corner)
    assert within_budget(_sample(0.0, corner=None), corner)  # nothing changed: nothing to place
    assert not within_budget(_sample(0.005, corner=False), corner)
    assert within_budget(_sample(0.005, corner=False), budget)  # corner_only off: anywhere
    assert "corner region" in budget_notes(_sample(0.005, corner=False), corner)[0]
    for bad in ({"max_noticeable_area": 1.5}, {"max_p999_vs_jpeg": -1.0}, {"corner_region": 0.0},
                {"display_width": 4}):  # fmt: skip
        with pytest.raises(PreflightInputError, match=next(iter(bad))):
            VisibilityBudget(**bad)
    with pytest.raises(PreflightInputError, match="sample_size"):
        PreflightOptions(sample_size=2)
    assert PreflightOptions(camera_params="").camera_params is None  # "" in TOML: not given
