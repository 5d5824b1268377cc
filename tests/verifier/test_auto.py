"""verifier.auto_search: visibility measured as a viewer sees it (FLIP) with the paper's SSIM/LPIPS reported,
the budget, the sample, and the preflight's ladder walk (over-budget candidates never reach SfM; one
end-to-end preflight with real COLMAP)."""

from __future__ import annotations

import logging
from pathlib import Path

import msgspec
import numpy as np
import pillow_heif
import pytest
from PIL import Image

from poisoner.ladder import named_spec
from poisoner.spec import PatchSpec
from verifier import auto_search
from verifier.auto_search import (
    NO_CANDIDATE,
    AutoDecision,
    LadderEntry,
    PreflightInputError,
    PreflightOptions,
    VisibilityBudget,
    choose_sample,
    preflight,
)
from verifier.pairs import stage_photos
from verifier.synthetic import SyntheticOptions, render_scene

BIG = LadderEntry("big-static", PatchSpec(patch_size=0.4), "a large patch: far over any sensible budget")
# enough images to measure; SfM never runs with these; LPIPS (reported only) is tested on its own
SMALL = PreflightOptions(sample_size=4, lpips_net="none")
PAPER = LadderEntry("paper-static", PatchSpec(), "the paper's checkerboard, 6% of the width, top-left")
MOVING = LadderEntry("texture-drift", named_spec("roaming"), "the roaming kind: random texture, moving")
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


def test_sample_takes_every_photo_ppd_patches_and_stages_it_as_verify_does(tmp_path: Path) -> None:
    """An iPhone shoot (all HEIC) had no sample ("need at least 3 images COLMAP can read", got 0) and a
    mixed one's left its HEICs out. A photo COLMAP does not read by its name is sampled by its first
    bytes (a dataset's vault original has no suffix), and staged for COLMAP as `ppd verify` stages it."""
    pillow_heif.register_heif_opener()
    (tmp_path / "vault").mkdir()
    shoot = [("IMG_0001.HEIC", "HEIF"), ("IMG_0002.JPG", "JPEG"), ("IMG_0003.avif", "AVIF"),
             ("IMG_0004.HEIC", "HEIF"), ("IMG_0005.PNG", "PNG")]  # fmt: skip
    items = []
    for i, (name, fmt) in enumerate(shoot):
        original = tmp_path / "vault" / f"{i:064x}"  # named by its hash, as the vault names them
        Image.new("RGB", (32, 24), (40 * i, 80, 120)).save(original, fmt)
        items.append((original, name))
    (tmp_path / "notes.txt").write_text("not a photo")
    items.append((tmp_path / "notes.txt", "notes.txt"))
    sample = choose_sample(items, 12)
    assert [n for _, n in sample] == [name for name, _ in shoot]
    assert [n for _, n in choose_sample(items, 3)] == ["IMG_0001.HEIC", "IMG_0003.avif", "IMG_0005.PNG"]
    staged = stage_photos(sample, tmp_path / "staged")
    assert staged == ["IMG_0001.HEIC.png", "IMG_0002.JPG", "IMG_0003.avif.png", "IMG_0004.HEIC.png",
                      "IMG_0005.PNG"]  # fmt: skip
    with Image.open(tmp_path / "staged" / "IMG_0004.HEIC.png") as png, Image.open(items[3][0]) as heic:
        assert png.format == "PNG" and np.array_equal(np.asarray(png), np.asarray(heic.convert("RGB")))
    with pytest.raises(PreflightInputError, match="got 2"):
        choose_sample([items[1], items[4], items[5]], 12)


def test_the_daemons_child_measures_a_heic_sample(tmp_path: Path) -> None:
    """The daemon's preflight child (`python -m verifier.auto_search JOB.json`) read the sample with
    Pillow alone, which opens no HEIC until pillow-heif is registered: the first HEIC's JPEG reference
    failed ("cannot identify image file"). The sample is read as ppd decodes what it patches."""
    import subprocess
    import sys

    from verifier.auto_options import PreflightJob

    pillow_heif.register_heif_opener()  # here, to write them: the child registers nothing up front
    render_scene(tmp_path / "renders", SyntheticOptions(num_views=3, width=96, height=96))
    (tmp_path / "shoot").mkdir()
    for png in sorted((tmp_path / "renders").glob("*.png")):
        Image.open(png).convert("RGB").save(tmp_path / "shoot" / f"{png.stem.upper()}.HEIC", quality=90)
    measure_only = PreflightOptions(sample_size=3, time_budget_s=0.001, lpips_net="none")
    shoot = [(str(p), p.name) for p in sorted((tmp_path / "shoot").iterdir())]
    job = PreflightJob(
        images=shoot, out_dir=str(tmp_path / "out"), result=str(tmp_path / "result.json"), ladder=[PAPER],
        budget=VisibilityBudget(display_width=96), options=measure_only,
    )  # fmt: skip
    (tmp_path / "job.json").write_bytes(msgspec.json.encode(job))
    ran = subprocess.run([sys.executable, "-m", "verifier.auto_search", str(tmp_path / "job.json")],
                         capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    result = msgspec.json.decode((tmp_path / "result.json").read_bytes())
    assert ran.returncode == 0 and "error" not in result, (result, ran.stderr[-2000:])
    assert result["sample"] == ["VIEW_00.HEIC", "VIEW_01.HEIC", "VIEW_02.HEIC"]
    (measured,) = result["evidence"]
    assert measured["status"] != "failed" and measured["visibility"]["images"] == 3, measured


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
    assert e.status == auto_search.OVER_BUDGET and e.profiles == {}  # no SfM ran
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
    assert decision.evidence[0].status == auto_search.NOT_REACHED


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
    assert moving.status == auto_search.OVER_BUDGET and moving.visibility.in_one_corner is False
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
    assert big.status == auto_search.OVER_BUDGET and big.profiles == {}
    assert paper.status == auto_search.PROTECTED
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
    assert paper.status == auto_search.NOT_PROTECTED
    assert paper.profiles["default"].verdict == "protected"
    assert paper.profiles["hardened"].verdict == "not_protected"
    assert moving.status == auto_search.PROTECTED, moving.profiles
    assert {p: v.verdict for p, v in moving.profiles.items()} == {
        "default": "protected", "hardened": "protected"
    }  # fmt: skip
    assert decision.chosen == "texture-drift" and decision.spec == named_spec("roaming")
    # the same ladder without the moving rung: nothing qualifies, and the decision says so
    # (same work folder: the clean reconstructions are reused from its cache)
    without = preflight(sorted(scene.glob("*.png")), [PAPER], budget, options, tmp_path)
    assert without.chosen is None and NO_CANDIDATE in without.reason and "paper-static" in without.reason


def test_candidate_that_does_not_fit_is_recorded_not_fatal(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    for i in range(3):
        Image.fromarray((_textured(40, 40, i) * 255).astype(np.uint8)).save(tmp_path / f"v{i}.png")
    too_big = LadderEntry("too-big", PatchSpec(patch_size=64), "does not fit 40 px images")
    with caplog.at_level(logging.INFO, logger="verifier.auto_search"):
        decision = preflight(sorted(tmp_path.glob("*.png")), [too_big], VisibilityBudget(display_width=40),
                             PreflightOptions(), tmp_path / "out")  # fmt: skip
    first = decision.evidence[0]
    assert first.status == auto_search.FAILED and "does not fit" in (first.error or "")
    said = [r.__dict__ for r in caplog.records if r.getMessage() == "candidate not measurable"]
    assert [(s["candidate"], s["file"], s["error"]) for s in said] == [("too-big", "v0.png", first.error)]
    assert decision.chosen is None
