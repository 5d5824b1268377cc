"""verifier.auto: visibility measured as a viewer sees it (FLIP) with the paper's SSIM/LPIPS reported,
the budget, the sample, and the preflight's ladder walk (over-budget candidates never reach SfM; one
end-to-end preflight with real COLMAP)."""

from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np
import pytest
from PIL import Image

from poisoner.blend import poison_array
from poisoner.ladder import default_spec
from poisoner.spec import PatchSpec
from verifier import auto
from verifier.auto import (
    NO_CANDIDATE,
    AutoDecision,
    LadderEntry,
    PreflightInputError,
    PreflightOptions,
    SampleVisibility,
    VisibilityBudget,
    budget_notes,
    budget_use,
    choose_sample,
    measure_image,
    preflight,
    whole_image_ssim,
    within_budget,
)
from verifier.metrics import ssim
from verifier.synthetic import SyntheticOptions, render_scene

BIG = LadderEntry("big-static", PatchSpec(patch_size=0.4), "a large patch: far over any sensible budget")
# enough images to measure; SfM never runs with these; LPIPS (reported only) is tested on its own
SMALL = PreflightOptions(sample_size=4, lpips_net="none")
PAPER = LadderEntry("paper-static", PatchSpec(), "the paper's checkerboard, 6% of the width, top-left")
MOVING = LadderEntry("texture-drift", default_spec(), "ppd's default: random texture, moving")
# An object on a plain backdrop (the lego case) with its true intrinsics: the verdicts below are
# then the same on every run. With a textured backdrop the scene outvotes the patch, and with the
# focal length left to COLMAP the paper's patch "protected" this render on some runs and not on
# others (CI saw both).
OBJECT = SyntheticOptions(num_views=12, backdrop="plain", arc_deg=90.0)
# The renders shown at their own size: FLIP at 1920 px would cost seconds per image here.
BUDGET = VisibilityBudget(display_width=OBJECT.width)


def _textured(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = rng.random((h // 8 + 1, w // 8 + 1, 3))
    return np.kron(base, np.ones((8, 8, 1)))[:h, :w]


# ---- visibility -----------------------------------------------------------------------------------
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
    budget = VisibilityBudget(display_width=64)
    v = measure_image(a, b, budget, None)
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


def test_sample_is_evenly_spaced_and_sfm_readable(tmp_path: Path) -> None:
    items = [(tmp_path / f"r_{i:02d}.png", f"r_{i:02d}.png") for i in range(40)]
    items.append((tmp_path / "x.heic", "x.heic"))  # COLMAP cannot read it: left out
    sample = choose_sample(items, 12)
    names = [n for _, n in sample]
    assert len(names) == 12 and names[0] == "r_00.png" and names[-1] == "r_39.png"
    assert "x.heic" not in names
    assert choose_sample(items[:5], 12) == sorted(items[:5], key=lambda t: t[1])
    with pytest.raises(PreflightInputError, match="at least 3 images"):
        choose_sample(items[:2], 12)


# ---- the ladder walk --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("scene") / "views"
    render_scene(out, OBJECT)
    return out


def test_over_budget_candidates_never_reach_sfm_and_it_is_said_plainly(scene: Path, tmp_path: Path) -> None:
    decision = preflight(sorted(scene.glob("*.png")), [BIG], BUDGET, SMALL, tmp_path)
    assert decision.chosen is None and decision.spec is None
    assert decision.outcome == "none_within_budget"
    assert NO_CANDIDATE in decision.reason and "big-static" in decision.reason
    assert not decision.lpips_checked and "LPIPS not measured" in decision.reason  # said, not pretended
    (e,) = decision.evidence
    assert e.status == auto.OVER_BUDGET and e.profiles == {}  # no SfM ran
    assert e.visibility.noticeable_area_max > 0.05 and e.budget_use > 5 and not e.within_budget
    assert e.visibility.p999_vs_jpeg_max > 1.0  # calibrated on this dataset against JPEG q85
    assert e.visibility.ssim_min < 0.99  # the paper's figure, still reported
    assert any("noticeably changed" in n for n in e.budget_notes)
    assert not (tmp_path / "clean-cache").exists()
    assert (tmp_path / "decision.json").is_file()


def test_time_budget_stops_the_walk_and_says_so(scene: Path, tmp_path: Path) -> None:
    decision = preflight(
        sorted(scene.glob("*.png")), [PAPER], BUDGET,
        PreflightOptions(sample_size=4, time_budget_s=0.001, lpips_net="none"), tmp_path,
    )  # fmt: skip
    assert decision.chosen is None and decision.outcome == "time_budget"
    assert "stopped at the time budget" in decision.reason and "paper-static" in decision.reason
    assert decision.evidence[0].status == auto.NOT_REACHED


def test_decision_round_trips_through_json(scene: Path, tmp_path: Path) -> None:
    measure_only = PreflightOptions(sample_size=4, time_budget_s=0.001, lpips_net="none")
    decision = preflight(sorted(scene.glob("*.png")), [BIG, PAPER], BUDGET, measure_only, tmp_path)
    assert msgspec.json.decode(msgspec.json.encode(decision), type=AutoDecision) == decision
    on_disk = msgspec.json.decode((tmp_path / "decision.json").read_bytes(), type=AutoDecision)
    assert on_disk == decision and on_disk.evidence[1].visibility.in_one_corner is True


def test_corner_only_budget_keeps_only_marks_in_one_corner(scene: Path, tmp_path: Path) -> None:
    """The paper's patch sits in the top-left corner; the moving texture drifts inward from 15%."""
    corner = VisibilityBudget(display_width=OBJECT.width, corner_only=True)
    options = PreflightOptions(sample_size=4, time_budget_s=0.001, lpips_net="none")  # measure only
    decision = preflight(sorted(scene.glob("*.png")), [PAPER, MOVING], corner, options, tmp_path)
    paper, moving = decision.evidence
    assert paper.within_budget and paper.visibility.in_one_corner is True
    assert moving.status == auto.OVER_BUDGET and moving.visibility.in_one_corner is False
    assert moving.budget_use <= 1.0  # small enough: only the corner rule excludes it
    assert any("corner region" in n for n in moving.budget_notes)


@pytest.mark.integration
def test_preflight_end_to_end_with_real_colmap(scene: Path, tmp_path: Path) -> None:
    """Budget skip + real verification: the big patch is skipped without SfM, the paper's patch is
    measured, verified with real COLMAP and confirmed under the default profile."""
    images = sorted(scene.glob("*.png"))
    options = PreflightOptions(profiles=("default",), camera_params=OBJECT.camera_params())
    decision = preflight(images, [BIG, PAPER], BUDGET, options, tmp_path)
    assert decision.chosen == "paper-static", decision.reason
    assert decision.spec == PAPER.spec
    big, paper = decision.evidence
    assert big.status == auto.OVER_BUDGET and big.profiles == {}
    assert paper.status == auto.PROTECTED
    assert paper.profiles["default"].verdict == "protected"
    assert paper.profiles["default"].frac_within_5deg <= 0.25
    assert paper.profiles["default"].clean_registered == 12
    assert "paper-static" in decision.reason and "within 5 deg" in decision.reason


@pytest.mark.integration
def test_two_profile_walk_passes_the_static_patch_and_chooses_the_moving_one(
    scene: Path, tmp_path: Path
) -> None:
    """The paper's static patch: protected under default, not under hardened COLMAP (the stationary
    filter removes it), so the walk goes on to the moving texture, which holds under both."""
    budget = BUDGET
    options = PreflightOptions(camera_params=OBJECT.camera_params())
    decision = preflight(sorted(scene.glob("*.png")), [PAPER, MOVING], budget, options, tmp_path)
    paper, moving = decision.evidence
    assert paper.status == auto.NOT_PROTECTED
    assert paper.profiles["default"].verdict == "protected"
    assert paper.profiles["hardened"].verdict == "not_protected"
    assert moving.status == auto.PROTECTED, moving.profiles
    assert {p: v.verdict for p, v in moving.profiles.items()} == {
        "default": "protected", "hardened": "protected"
    }  # fmt: skip
    assert decision.chosen == "texture-drift" and decision.spec == default_spec()
    # the same ladder without the moving rung: nothing qualifies, and the decision says so
    # (same work folder: the clean reconstructions are reused from its cache)
    without = preflight(sorted(scene.glob("*.png")), [PAPER], budget, options, tmp_path)
    assert without.chosen is None and NO_CANDIDATE in without.reason and "paper-static" in without.reason


def test_candidate_that_does_not_fit_is_recorded_not_fatal(tmp_path: Path) -> None:
    for i in range(3):
        Image.fromarray((_textured(40, 40, i) * 255).astype(np.uint8)).save(tmp_path / f"v{i}.png")
    too_big = LadderEntry("too-big", PatchSpec(patch_size=64), "does not fit 40 px images")
    decision = preflight(sorted(tmp_path.glob("*.png")), [too_big], VisibilityBudget(display_width=40),
                         PreflightOptions(), tmp_path / "out")  # fmt: skip
    assert decision.evidence[0].status == auto.FAILED and "does not fit" in (decision.evidence[0].error or "")
    assert decision.chosen is None
