"""Verdict rule, inputs, round trip, run pruning, visibility in the report, and end-to-end verification on the
synthetic scene with real COLMAP."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from daemon.verification.verify import prune_runs, remove_unfinished_runs
from poisoner.blend import poison_array
from poisoner.spec import PatchSpec
from verifier import verdict as vd
from verifier.published import round_trip
from verifier.synthetic import SyntheticOptions, render_scene
from verifier.verification import (
    VerificationInputError,
    VerifyOptions,
    default_workers,
    expand_profiles,
    verify_folders,
)
from verifier.visibility import dataset_visibility_from_json

OK_CLEAN = {"outcome": "ok", "num_images": 20, "registered": 20, "num_models": 1}


def poisoned_result(registered: int = 20) -> dict[str, Any]:
    return {"outcome": "ok", "num_images": 20, "registered": registered, "num_models": 1}


# ---- verdict rule ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("frac", "expected"),
    [(0.0, vd.PROTECTED), (0.25, vd.PROTECTED), (0.26, vd.WEAK), (0.6, vd.WEAK), (0.61, vd.NOT_PROTECTED),
     (1.0, vd.NOT_PROTECTED)],
)  # fmt: skip
def test_verdict_thresholds(frac: float, expected: str) -> None:
    v = vd.decide(OK_CLEAN, poisoned_result(), {"frac_within_5deg": frac, "median_rotation_error_deg": 3.0})
    assert v.verdict == expected
    assert any(f"{100 * frac:.0f}%" in r for r in v.reasons)


def test_not_protected_says_so_plainly() -> None:
    v = vd.decide(OK_CLEAN, poisoned_result(), {"frac_within_5deg": 0.9})
    assert any(r.startswith("NOT protected") for r in v.reasons)


def test_failed_clean_run_is_inconclusive_never_protected() -> None:
    crashed_clean = {"outcome": "sfm_crashed", "signal": "SIGSEGV", "error": "killed"}
    assert vd.decide(crashed_clean, poisoned_result(0), {"frac_within_5deg": 0.0}).verdict == vd.INCONCLUSIVE
    weak_clean = {**OK_CLEAN, "registered": 6}
    v = vd.decide(weak_clean, poisoned_result(0), {"frac_within_5deg": 0.0})
    assert v.verdict == vd.INCONCLUSIVE
    assert "6/20" in v.reasons[0]
    half = {**OK_CLEAN, "registered": 10, "num_models": 2}  # half the views, the rest another model
    assert vd.decide(half, poisoned_result(0), {"frac_within_5deg": 0.0}).verdict == vd.INCONCLUSIVE
    more = {**OK_CLEAN, "registered": 11}
    assert vd.decide(more, poisoned_result(0), {"frac_within_5deg": 0.0}).verdict == vd.PROTECTED


def test_poisoned_crash_is_its_own_outcome() -> None:
    v = vd.decide(OK_CLEAN, {"outcome": "sfm_crashed", "signal": "SIGSEGV"}, None)
    assert v.verdict == vd.SFM_CRASHED
    assert "SIGSEGV" in v.reasons[0]
    assert vd.decide(OK_CLEAN, {"outcome": "timeout", "error": "t"}, None).verdict == vd.INCONCLUSIVE
    rerun = {**poisoned_result(), "crashes": ["SIGSEGV"]}
    v = vd.decide(OK_CLEAN, rerun, {"frac_within_5deg": 0.0})
    assert v.verdict == vd.PROTECTED
    assert any("first crashed (SIGSEGV)" in r for r in v.reasons)
    # the originals did not reconstruct either: no claim, and the crash is still said (it was not)
    weak_clean = {**OK_CLEAN, "registered": 2}
    v = vd.decide(weak_clean, {**poisoned_result(0), "crashes": ["SIGTERM"]}, {"frac_within_5deg": 0.0})
    assert v.verdict == vd.INCONCLUSIVE and any("first crashed (SIGTERM)" in r for r in v.reasons)
    assert not any("crashed" in r for r in vd.decide(weak_clean, poisoned_result(0), None).reasons)


def test_verdicts_are_a_str_enum_stored_as_their_value() -> None:
    v = vd.decide(OK_CLEAN, poisoned_result(), {"frac_within_5deg": 0.0})
    assert isinstance(v.verdict, vd.Verdict) and v.verdict is vd.Verdict.PROTECTED
    assert json.dumps({"v": v.verdict}) == '{"v": "protected"}' and vd.Verdict("weak") is vd.WEAK
    assert vd.overall(["weak", "protected"]) is vd.Verdict.WEAK  # plain strings from the Store compare
    assert vd.not_holding({"default": "protected", "masked": "not_protected", "published": "weak"}) == [
        "masked", "published"]  # fmt: skip
    assert vd.verdict_words(vd.Verdict.NOT_PROTECTED) == "NOT protected"


def test_overall_is_the_weakest_profile() -> None:
    assert vd.overall([vd.PROTECTED, vd.NOT_PROTECTED, vd.WEAK]) == vd.NOT_PROTECTED
    # a crash is no protection: an attacker whose run died is not one the mark held (only that
    # attacker's clean run worked), so the set is not called protected...
    assert vd.overall([vd.PROTECTED, vd.SFM_CRASHED]) == vd.SFM_CRASHED
    assert vd.headline_verdict({"default": "sfm_crashed", "hardened": "protected"}) == vd.SFM_CRASHED
    # ...but it never hides an attacker the mark measurably failed
    assert vd.overall([vd.WEAK, vd.SFM_CRASHED, vd.PROTECTED]) == vd.WEAK
    assert vd.overall([vd.SFM_CRASHED, vd.NOT_PROTECTED]) == vd.NOT_PROTECTED
    # an inconclusive profile (its COLMAP fails on the originals too) is no threat measured
    assert vd.overall([vd.PROTECTED, vd.INCONCLUSIVE]) == vd.PROTECTED
    assert vd.overall([vd.SFM_CRASHED, vd.INCONCLUSIVE]) == vd.SFM_CRASHED
    assert vd.overall([vd.INCONCLUSIVE]) == vd.INCONCLUSIVE


def test_the_headline_counts_every_attacker_and_masked_has_its_own_line_too() -> None:
    run = {"masked": "weak", "published": "protected", "default": "protected", "hardened": "protected"}
    # issue 25, round 2: the per-photo mark holds the masked attacker, so it counts like the others
    assert list(vd.headline(run)) == ["default", "hardened", "published", "masked"]  # in that order
    assert vd.headline_verdict(run) == vd.WEAK
    assert vd.headline_verdict({"default": "protected", "masked": "not_protected"}) == vd.NOT_PROTECTED
    assert vd.headline_verdict({"default": "protected", "masked": "protected"}) == vd.PROTECTED
    # issue 25/30: the global mapper is an attacker like the others: it counts
    with_global = {**run, "masked": "protected", "global": "not_protected"}
    assert list(vd.headline(with_global)) == ["default", "hardened", "published", "global", "masked"]
    assert vd.headline_verdict(with_global) == vd.NOT_PROTECTED
    run = {**run, "masked": "not_protected"}
    assert vd.headline({"masked": "weak"}) == {"masked": "weak"}  # only masked run: it is the headline
    corner = vd.masked_line(run, corner_mark=True)
    assert corner == "NOT protected against an attacker who masks the corners (a corner mark cannot be)"
    roaming = vd.masked_line(run, corner_mark=False)
    assert roaming is not None and roaming.startswith("NOT protected against an attacker who masks")
    assert "a corner mark cannot be" not in roaming and "defeats any corner" in roaming
    assert "(counted in the verdict above)" in roaming
    held = vd.masked_line({"default": "protected", "masked": "protected"}, corner_mark=False)
    assert held is not None and held.startswith("protected against an attacker who masks the corners too")
    assert vd.masked_line({"default": "protected"}, corner_mark=True) is None  # not run: nothing said
    assert vd.masked_line({"masked": "not_protected"}, corner_mark=True) is None  # it is the headline then


# ---- inputs and helpers -------------------------------------------------------------------------
def test_profiles_expand_and_reject_unknown() -> None:
    assert expand_profiles("all") == ["default", "hardened", "published", "global", "masked"]
    assert expand_profiles(["hardened", "default", "hardened"]) == ["hardened", "default"]
    with pytest.raises(VerificationInputError, match="unknown profile"):
        expand_profiles(["fast"])


def _write_images(d: Path, names: list[str]) -> None:
    d.mkdir(parents=True, exist_ok=True)
    for n in names:
        Image.new("RGB", (16, 16), (10, 20, 30)).save(d / n)


def test_mismatched_folders_are_a_clear_error(tmp_path: Path) -> None:
    _write_images(tmp_path / "c", ["a.png", "b.png", "c.png"])
    _write_images(tmp_path / "p", ["a.png", "b.png", "x.png"])
    with pytest.raises(VerificationInputError, match="same file names") as info:
        verify_folders(tmp_path / "c", tmp_path / "p", tmp_path / "out")
    assert "\n" not in str(info.value)
    with pytest.raises(VerificationInputError, match="not a folder"):
        verify_folders(tmp_path / "nope", tmp_path / "p", tmp_path / "out")
    assert sorted(os.listdir(tmp_path / "p")) == ["a.png", "b.png", "x.png"]  # inputs untouched


def test_round_trip_downscales_and_recompresses(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    Image.new("RGB", (3000, 1000), (200, 10, 10)).save(src / "wide.png")
    rgba = Image.new("RGBA", (100, 100), (0, 0, 0, 0))
    rgba.save(src / "clear.png")
    out = round_trip(src, tmp_path / "pub", ["wide.png", "clear.png"], 2048, 85)
    with Image.open(out / "wide.png.jpg") as im:
        assert im.format == "JPEG" and im.size == (2048, 683)
    with Image.open(out / "clear.png.jpg") as im:
        assert im.size == (100, 100)  # never upscaled
        assert min(im.convert("RGB").getpixel((50, 50))) >= 250  # transparent -> white, as 3DGS loads it


def test_prune_keeps_the_newest_runs(tmp_path: Path) -> None:
    for name in ["20260101T000000-a", "20260102T000000-b", "20260103T000000-c", "20260104T000000-d"]:
        (tmp_path / name).mkdir()
    autos = [f"auto-2026010{d}T000000" for d in (5, 6, 7)] + ["auto-interim-20260101T000000"]
    for name in autos:
        (tmp_path / name).mkdir()
    removed = prune_runs(tmp_path, keep_last=2)
    assert sorted(p.name for p in removed) == ["20260101T000000-a", "20260102T000000-b", autos[0]]
    assert sorted(os.listdir(tmp_path)) == ["20260103T000000-c", "20260104T000000-d", *autos[1:]]


def test_a_run_folder_without_its_report_is_a_killed_verifications_and_goes(tmp_path: Path) -> None:
    finished, killed = tmp_path / "20260103T000000-c0ffee", tmp_path / "20260104T000000-d00d1e"
    for run in (finished, killed):
        (run / ".images" / "clean").mkdir(parents=True)
        (run / ".images" / "clean" / "v0.png").write_bytes(b"staged")
    (finished / "report.json").write_text("{}")
    (tmp_path / ".verify.lock").write_text("")
    (tmp_path / ".clean-cache" / "key").mkdir(parents=True)  # the clean reference kept across runs
    autos = ("auto-20261206T100000", "auto-interim-20261206T090000")  # the automatic mode's folders
    for auto in autos:
        (tmp_path / auto / "sample").mkdir(parents=True)
    assert remove_unfinished_runs(tmp_path) == [killed]
    assert finished.is_dir() and not killed.exists() and (tmp_path / ".verify.lock").is_file()
    assert (tmp_path / ".clean-cache" / "key").is_dir()
    assert all((tmp_path / auto).is_dir() for auto in autos)
    assert remove_unfinished_runs(tmp_path / "no such dataset") == []


# ---- visibility in the verification's results ------------------------------------------------------
def _copy_and_mark(tmp_path: Path, n: int = 4) -> tuple[Path, Path, list[str]]:
    clean, pois = tmp_path / "clean", tmp_path / "poisoned"
    clean.mkdir()
    for i in range(n):
        Image.new("RGB", (80, 60), (10 + 20 * i, 120, 30)).save(clean / f"v{i}.png")
    shutil.copytree(clean, pois)
    for i in range(n):
        with Image.open(pois / f"v{i}.png") as im:
            arr = np.asarray(im.convert("RGB")).copy()
        arr[:6, :6] = 255 * (np.indices((6, 6)).sum(axis=0) % 2)[..., None]  # a corner checkerboard
        Image.fromarray(arr.astype(np.uint8)).save(pois / f"v{i}.png")
    return clean, pois, [f"v{i}.png" for i in range(n)]


def test_verification_results_carry_visibility_and_what_ppd_verify_prints(tmp_path: Path) -> None:
    from verifier.verification import ProfileReport, VerificationReport, measure_visibility

    clean, pois, names = _copy_and_mark(tmp_path)
    vis = measure_visibility(clean, pois, names, VerifyOptions(visibility_images=2))
    assert vis is not None and vis.measured == 2 and vis.total == 4
    assert vis.worst.area_above_half > 0 and vis.worst.in_one_corner is True
    assert measure_visibility(clean, pois, names, VerifyOptions(visibility_images=0)) is None
    untouched = measure_visibility(clean, clean, names, VerifyOptions(visibility_images=2))
    assert untouched is not None
    assert untouched.worst.area_above_half == 0 and untouched.worst.changed_area == 0
    profiles = {
        name: ProfileReport(profile=name, verdict=verdict, reasons=[], clean={"outcome": "ok"},
                            poisoned={"outcome": "ok"}, vs_clean=None)
        for name, verdict in (("default", vd.PROTECTED), ("masked", vd.NOT_PROTECTED))
    }  # fmt: skip
    # a corner mark (the visibility stage saw every change inside one corner)
    report = VerificationReport(str(clean), str(pois), str(tmp_path), 4, profiles, vis, corner_mark=True)
    data = json.loads(json.dumps(report.to_dict()))
    # masked counts (issue 25, round 2): a corner mark is NOT protected against it, and says why
    assert data["verdict"] == "not_protected" and data["profiles"]["masked"]["verdict"] == "not_protected"
    assert data["verdict_counts"] == ["default", "masked"]
    assert data["visibility"]["worst"]["area_above_half"] == vis.worst.area_above_half
    summary = "\n".join(data["summary"])
    assert f"{vis.worst.area_above_half:.2%} of the picture clearly visible (FLIP > 0.5)" in summary
    assert "the protection does NOT hold under: masked" in summary
    assert "NOT protected against an attacker who masks the corners (a corner mark cannot be)" in summary
    assert report.not_holding() == ["masked"]
    roaming = VerificationReport(str(clean), str(pois), str(tmp_path), 4, profiles, vis, corner_mark=False)
    assert "a corner mark cannot be" not in "\n".join(roaming.summary_lines())
    assert "NOT protected against an attacker who masks the corners" in "\n".join(roaming.summary_lines())
    only_masked = VerificationReport(str(clean), str(pois), str(tmp_path), 4, {"masked": profiles["masked"]})
    assert only_masked.verdict == vd.NOT_PROTECTED and only_masked.not_holding() == ["masked"]


def test_a_datasets_verification_gets_its_subject_masks_and_corner_kind(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """verify_dataset's options: the config's subject masks (visibility's "touches subject") and
    whether the dataset's mark is corner-bound (the masked attacker's line); a bad mask folder is one line."""
    from daemon.context import AppContext
    from daemon.verification.verify import dataset_options
    from poisoner.ladder import named_spec

    masks = tmp_path / "masks"
    masks.mkdir()
    (ppd_env["config"] / "config.toml").write_text(f'[datasets.obj]\nsubject_masks = "{masks}"\n')
    ctx = AppContext.open()
    try:
        ctx.store.ensure_dataset("obj", tmp_path / "obj", named_spec("watermark"))
        ctx.store.ensure_dataset("roam", tmp_path / "roam", named_spec("roaming"))
        options = dataset_options(ctx, "obj", VerifyOptions())
        assert options.subject_masks == masks and options.corner_mark is True
        roam = dataset_options(ctx, "roam", VerifyOptions())
        assert roam.subject_masks is None and roam.corner_mark is False
        given = dataset_options(ctx, "obj", VerifyOptions(subject_masks=tmp_path, corner_mark=False))
        assert given.subject_masks == tmp_path and given.corner_mark is False  # the caller's win
    finally:
        ctx.close()
    inside = ppd_env["outbox"] / "masks"
    inside.mkdir()
    (ppd_env["config"] / "config.toml").write_text(f'[datasets.obj]\nsubject_masks = "{inside}"\n')
    ctx = AppContext.open()
    try:
        with pytest.raises(VerificationInputError, match="inside the outbox"):
            dataset_options(ctx, "obj", VerifyOptions())
    finally:
        ctx.close()


# ---- end to end with real COLMAP -----------------------------------------------------------------
@pytest.fixture(scope="module")
def synthetic_sets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("synthetic")
    clean = root / "clean"
    render_scene(clean, SyntheticOptions(num_views=12), gt_path=root / "gt.json")
    pois = root / "poisoned"
    pois.mkdir()
    for p in sorted(clean.glob("*.png")):
        arr, _ = poison_array(np.asarray(Image.open(p)), PatchSpec())
        Image.fromarray(arr).save(pois / p.name)
    return {"clean": clean, "poisoned": pois, "gt": root / "gt.json", "root": root}


# An object on a plain backdrop (the lego case), verified with its true intrinsics: the paper's
# patch wins there on every run. On the textured render above the verdict of the same test
# depended on COLMAP's focal-length estimate and changed from run to run (CI saw it flip).
OBJECT = SyntheticOptions(num_views=12, backdrop="plain", arc_deg=90.0)


@pytest.fixture(scope="module")
def object_sets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("object")
    clean, pois = root / "clean", root / "poisoned"
    render_scene(clean, OBJECT, gt_path=root / "gt.json")
    pois.mkdir()
    for p in sorted(clean.glob("*.png")):
        arr, _ = poison_array(np.asarray(Image.open(p)), PatchSpec())
        Image.fromarray(arr).save(pois / p.name)
    return {"clean": clean, "poisoned": pois, "gt": root / "gt.json", "root": root}


@pytest.mark.integration
def test_unpoisoned_copy_is_not_protected(synthetic_sets: dict[str, Path], tmp_path: Path) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(synthetic_sets["clean"], copy)
    report = verify_folders(synthetic_sets["clean"], copy, tmp_path / "out", ["default"],
                            VerifyOptions(ground_truth=synthetic_sets["gt"], timeout_s=300))  # fmt: skip
    p = report.profiles["default"]
    assert p.verdict == vd.NOT_PROTECTED, p.reasons
    # the clean and poisoned sides are independent runs and ran at once (two SfM slots from 2 cores
    # up): one after the other, their times could not add up to more than the profile's wall time
    if default_workers() >= 2:
        assert p.clean["elapsed_s"] + p.poisoned["elapsed_s"] > p.finished_at - p.started_at
    assert p.vs_clean["frac_within_5deg"] == 1.0
    assert p.clean_vs_gt["frac_within_5deg"] == 1.0
    assert report.verdict == vd.NOT_PROTECTED


@pytest.mark.integration
def test_patch_breaks_default_colmap_and_hardened_colmap_resists(
    object_sets: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / "out"
    options = VerifyOptions(
        ground_truth=object_sets["gt"], timeout_s=300, camera_params=OBJECT.camera_params()
    )
    report = verify_folders(
        object_sets["clean"], object_sets["poisoned"], out, ["default", "hardened"], options
    )
    default, hardened = report.profiles["default"], report.profiles["hardened"]
    assert default.clean["registered"] == 12
    assert default.clean_vs_gt["frac_within_5deg"] == 1.0  # the reference itself is right
    assert default.vs_clean["frac_within_5deg"] <= 0.25, default.vs_clean
    assert default.verdict == vd.PROTECTED
    # COLMAP's stationary-match filter + watermark handling undoes this patch: said plainly
    assert hardened.verdict == vd.NOT_PROTECTED, hardened.reasons
    assert report.verdict == vd.NOT_PROTECTED
    assert default.poisoned["random_seed"] == default.clean["random_seed"] == 0
    for side in ("clean", "poisoned"):  # models kept for reports and the splat stage
        assert (out / "default" / side / "cameras.bin").is_file()
    stored = json.loads((out / "default" / "report.json").read_text())
    assert stored["verdict"] == default.verdict
    # what a viewer sees was measured on a few of the files, and written with the run
    assert report.visibility is not None and report.visibility.measured == 3
    assert report.visibility.worst.area_above_half > 0
    top = json.loads((out / "report.json").read_text())
    assert top["visibility"]["worst"]["area_above_half"] == report.visibility.worst.area_above_half
    assert any(line.startswith("the protection does NOT hold under: hardened") for line in top["summary"])
    assert not (out / ".cache").exists()  # feature databases are not left behind


@pytest.mark.integration
def test_verify_dataset_records_runs_and_keeps_models(
    synthetic_sets: dict[str, Path], ppd_env: dict[str, Path]
) -> None:
    protect = pytest.importorskip("daemon.protect.one_file")
    from daemon.verification.verify import verify_dataset

    ctx = protect.AppContext.open()
    try:
        trip = ppd_env["outbox"] / "trip"
        shutil.copytree(synthetic_sets["clean"], trip)
        for p in sorted(trip.glob("*.png")):
            assert protect.protect_file(p, ctx).state == "patched"
        options = VerifyOptions(timeout_s=300, splat=True)
        options.splat_options.update(long_edge=64, iterations=30, time_budget_s=20)
        report = verify_dataset(ctx, "trip", ["default"], options, keep_last=1)
        rows = ctx.store.verification_runs("trip")
        assert [r["profile"] for r in rows] == ["default"]
        assert rows[0]["verdict"] == report.profiles["default"].verdict
        assert rows[0]["metrics"]["clean"]["registered"] == 12
        # the run's visibility figures are stored with every profile's row (what `ppd report` shows)
        vis = rows[0]["metrics"]["visibility"]
        assert vis["measured"] == 3 and vis["total"] == 12 and vis["worst"]["area_above_half"] > 0
        assert dataset_visibility_from_json(vis) == report.visibility  # read back whole
        model_dir = Path(rows[0]["model_dir"])
        assert (model_dir / "clean" / "images.bin").is_file()
        assert (model_dir / "poisoned" / "images.bin").is_file()
        run_dirs = [p for p in (ctx.paths.runs_dir / "trip").iterdir() if not p.name.startswith(".")]
        assert len(run_dirs) == 1 and not (run_dirs[0] / ".images").exists()  # staged images removed
        # issue 30: the clean reference stays for the next verification (the originals' one key);
        # the progress file went with the run
        (cached,) = (ctx.paths.runs_dir / "trip" / ".clean-cache").iterdir()
        assert (cached / "clean-models").is_dir()
        assert not (ctx.paths.runs_dir / "trip" / ".verifying.json").exists()
        # Verifier II ran on the staged images before they were removed, and its costs are stored
        splat = rows[0]["metrics"]["splat"]
        assert splat["outcome"] == "ok", splat
        assert splat["clean"]["iterations"] > 0 and splat["poisoned"]["iterations"] > 0
        assert 0 < splat["cost2"]["ssim"] < 1 and splat["cost2"]["images"] == 12
        assert any(r.startswith("splat: poisoned model renders") for r in rows[0]["metrics"]["reasons"])
        assert Path(splat["preview"]).is_file()
    finally:
        ctx.close()


@pytest.mark.integration
def test_cli_verify_splat_json(synthetic_sets: dict[str, Path], tmp_path: Path) -> None:
    """`ppd verify PATH --clean DIR --splat --json` carries the splat stage's costs."""
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "verify", str(synthetic_sets["poisoned"]), "--clean",
         str(synthetic_sets["clean"]), "--profile", "default", "--out", str(out), "--splat",
         "--splat-budget", "5", "--json"],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert proc.returncode in (0, 1), proc.stderr[-2000:]
    data = json.loads(proc.stdout)
    splat = data["profiles"]["default"]["splat"]
    assert splat["outcome"] == "ok", splat
    assert splat["options"]["time_budget_s"] == 5
    assert splat["clean"]["train_seconds"] < 30  # the budget bounds training (checked per iteration)
    assert splat["cost2"]["psnr"] > 20 and splat["cost2"]["ssim"] < 1
    assert (out / "default" / "splat" / "splat.json").is_file()


def test_cli_verify_bad_folders_is_one_clear_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import tempfile

    from typer.testing import CliRunner

    from daemon.cli import app

    _write_images(tmp_path / "c", ["a.png", "b.png", "c.png"])
    _write_images(tmp_path / "p", ["a.png", "b.png"])
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    result = CliRunner().invoke(
        app, ["verify", str(tmp_path / "p"), "--clean", str(tmp_path / "c"), "--json"]
    )
    assert result.exit_code == 2
    assert "same file names" in result.output
    assert list((tmp_path / "tmp").iterdir()) == []  # the report folder it made is gone with the run
    result = CliRunner().invoke(app, ["verify", str(tmp_path / "p")])
    assert result.exit_code == 2
    assert "--clean" in result.output


@pytest.mark.parametrize(("runs", "retried_with"), [(1, 1), (3, 3)])
def test_crashed_side_is_retried_with_another_seed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, runs: int, retried_with: int
) -> None:
    """A crash is rerun once with the next seed no other run of the profile uses (--seeds 3 runs
    seeds 0, 1 and 2: seed 0's retry is seed 3)."""
    from verifier import shared_sfm as vmod
    from verifier.sfm import SfmSettings

    # a real interpreter stand-in that segfaults on the first run and succeeds on the second
    marker = tmp_path / "crashed-once"
    script = tmp_path / "fake-python"
    script.write_text(
        "#!/bin/sh\njob=$(cat)\n"
        f"if [ ! -e {shlex.quote(str(marker))} ]; then touch {shlex.quote(str(marker))}; kill -SEGV $$; fi\n"
        'out=$(printf %s "$job" | sed -E \'s/.*"result_path": "([^"]*)".*/\\1/\')\n'
        'printf \'{"outcome": "ok", "registered": 0, "poses": {}}\' > "$out"\n'
    )
    script.chmod(0o755)
    real = vmod.run_sfm_job
    seeds: list[int] = []

    def run_with_fake(job, timeout_s=None, cancel=None, exclusive=True):  # same protocol, other interpreter
        seeds.append(job.settings.random_seed)
        return real(job, timeout_s=timeout_s, cancel=cancel, python=str(script), exclusive=exclusive)

    monkeypatch.setattr(vmod, "run_sfm_job", run_with_fake)
    side = vmod.SfmSide(tmp_path / "img", tmp_path / "c.db", tmp_path / "m", SfmSettings())
    (tmp_path / "c.db").write_bytes(b"")  # features already built: the mapping run is what crashes
    result = vmod.run_side(side, VerifyOptions(seeds=runs))
    assert result["outcome"] == "ok"
    assert result["crashes"] == ["SIGSEGV"]
    assert seeds == [0, retried_with]
    assert result["random_seed"] == retried_with


def test_a_profile_reports_the_attackers_best_run_of_its_seeds() -> None:
    """--seeds N: the weakest decisive verdict counts (then the most cameras recovered); a crashed
    or unfinished run counts only when no run decided."""
    protected, weak, not_protected = (vd.Decision(v) for v in (vd.PROTECTED, vd.WEAK, vd.NOT_PROTECTED))
    crashed, unfinished = vd.Decision(vd.SFM_CRASHED), vd.Decision(vd.INCONCLUSIVE)
    assert vd.worst_seed([protected, weak, protected], [0.0, 0.42, 0.1]) == 1
    assert vd.worst_seed([protected, not_protected, weak], [0.0, 0.9, 0.5]) == 1
    assert vd.worst_seed([protected, protected], [0.1, 0.2]) == 1  # the more cameras within 5 deg
    assert vd.worst_seed([protected, protected], [0.2, 0.2]) == 0  # ties: the first seed
    assert vd.worst_seed([crashed, protected], [None, 0.0]) == 1  # a crash is no verdict
    assert vd.worst_seed([unfinished, crashed], [None, None]) == 1
    assert vd.worst_seed([protected], [0.0]) == 0


def test_cli_verify_seeds_out_of_range_is_one_clear_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from daemon.cli import app

    _write_images(tmp_path / "c", ["a.png", "b.png"])
    _write_images(tmp_path / "p", ["a.png", "b.png"])
    for seeds in ("0", "11"):
        result = CliRunner().invoke(app, ["verify", str(tmp_path / "p"), "--clean", str(tmp_path / "c"),
                                          "--seeds", seeds])  # fmt: skip
        assert result.exit_code == 2, result.output
        assert f"--seeds must be a whole number from 1 to 10, got {seeds}" in result.output


# ---- shared datasets (slow: minutes of SfM each; run with `pytest -m slow`) -----------------------
@pytest.mark.slow
@pytest.mark.integration
def test_fountain_small_patch_is_not_protected(shared_dir: Path, tmp_path: Path) -> None:
    """A textured real scene shrugs off a 2%-width patch: the verdict must say NOT protected."""
    fountain = shared_dir / "datasets" / "fountain_P11"
    pois = tmp_path / "poisoned"
    pois.mkdir()
    for p in sorted((fountain / "images").glob("*.jpg")):
        arr, _ = poison_array(np.asarray(Image.open(p).convert("RGB")), PatchSpec(patch_size=0.02))
        Image.fromarray(arr).save(pois / p.name, quality=95)
    report = verify_folders(fountain / "images", pois, tmp_path / "out", ["default"],
                            VerifyOptions(ground_truth=fountain / "gt_dense_cameras"))  # fmt: skip
    p = report.profiles["default"]
    assert p.clean_vs_gt["frac_within_5deg"] == 1.0
    assert p.verdict == vd.NOT_PROTECTED, p.reasons


@pytest.mark.slow
@pytest.mark.integration
def test_lego_clean_sfm_matches_ground_truth(shared_dir: Path, tmp_path: Path) -> None:
    """Attacker-default COLMAP on 40 clean lego views (on white) gets most cameras right."""
    from verifier import poses as pm
    from verifier.sfm import SfmJob, run_sfm_job

    lego = shared_dir / "datasets" / "nerf_synthetic_lego"
    clean = tmp_path / "clean"
    clean.mkdir()
    for i in range(40):
        rgba = Image.open(lego / "train" / f"r_{i}.png").convert("RGBA")
        white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        Image.alpha_composite(white, rgba).convert("RGB").save(clean / f"r_{i}.png")
    result = run_sfm_job(SfmJob(str(clean), str(tmp_path / "c.db"), str(tmp_path / "m")), timeout_s=1800)
    assert result["outcome"] == "ok", result.get("error")
    gt = pm.load_ground_truth(lego / "transforms_train.json")
    m = pm.compare_poses(pm.poses_from_json(result["poses"]), {n: gt[n] for n in os.listdir(clean)})
    assert m["frac_within_5deg"] >= 0.7, m


@pytest.mark.integration
def test_several_seeds_report_the_weakest_run(object_sets: dict[str, Path], tmp_path: Path) -> None:
    """--seeds 2: the patched set mapped at seeds 0 and 1 on the same features, one clean reference;
    the profile's figures are the run an attacker would keep, each run is listed and has its model."""
    from verifier.verification import seeds_sentence

    options = VerifyOptions(timeout_s=300, camera_params=OBJECT.camera_params(), seeds=2)
    out = tmp_path / "o"
    report = verify_folders(object_sets["clean"], object_sets["poisoned"], out, ["default"], options)
    p = report.profiles["default"]
    assert p.seeds is not None and [e["seed"] for e in p.seeds] in ([0, 1], [0, 3], [2, 1], [2, 3])
    assert p.clean["random_seed"] == 0
    fracs = [e["frac_within"] for e in p.seeds]
    decided = [f for f, e in zip(fracs, p.seeds, strict=True) if e["outcome"] == "ok"]
    assert decided and p.vs_clean is not None and p.vs_clean["frac_within_5deg"] == max(decided)
    assert p.poisoned["random_seed"] == p.seeds[fracs.index(max(decided))]["seed"]
    assert p.reasons[0] == seeds_sentence(p.seeds, 5)
    assert [e["model"] for e in p.seeds] == ["poisoned", "poisoned-run2"]
    assert all((out / "default" / e["model"] / "result.json").is_file() for e in p.seeds)
    stored = json.loads((out / "report.json").read_text())
    assert stored["profiles"]["default"]["seeds"] == p.seeds


@pytest.mark.integration
def test_random_seed_reaches_colmap_and_is_recorded(object_sets: dict[str, Path], tmp_path: Path) -> None:
    """An attacker reruns COLMAP with other seeds; the verifier can too, and says which it used."""
    options = VerifyOptions(timeout_s=300, camera_params=OBJECT.camera_params(), random_seed=7)
    report = verify_folders(
        object_sets["clean"], object_sets["poisoned"], tmp_path / "o", ["default"], options
    )
    p = report.profiles["default"]
    assert p.clean["random_seed"] == 7 and p.poisoned["random_seed"] in (7, 8)  # 8: after a crash retry
    assert p.clean["registered"] == 12


@pytest.mark.integration
def test_verify_dataset_reports_masked_apart_and_measures_the_subject(
    object_sets: dict[str, Path], ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A corner-mark dataset with subject masks in the config, verified by the daemon's path under
    default and masked: masked is recorded, counted (issue 25, round 2) and said on its own line,
    and the visibility stage measured the subject."""
    from daemon.context import AppContext
    from daemon.protect.one_file import protect_file
    from daemon.verification.verify import verify_dataset

    obj, masks = ppd_env["outbox"] / "obj", tmp_path / "masks"
    shutil.copytree(object_sets["clean"], obj)
    masks.mkdir()
    for p in sorted(obj.glob("*.png")):
        pixels = np.asarray(Image.open(p).convert("RGB")).astype(int)
        backdrop = pixels[0, 0]
        subject = np.abs(pixels - backdrop).sum(axis=2) > 30  # the object on its plain backdrop
        Image.fromarray((subject * 255).astype(np.uint8)).save(masks / p.name)
    (ppd_env["config"] / "config.toml").write_text(
        '[patch]\ndesign = "watermark"\n'  # the tumbling corner mark (random blocks, 7.5%, 20% corner)
        f'[datasets.obj]\nsubject_masks = "{masks}"\n'
    )
    ctx = AppContext.open()
    try:
        assert all(protect_file(p, ctx).state == "patched" for p in sorted(obj.glob("*.png")))
        report = verify_dataset(ctx, "obj", ["default", "masked"], VerifyOptions(timeout_s=300))
        rows = {r["profile"]: r for r in ctx.store.verification_runs("obj")}
        assert set(rows) == {"default", "masked"} and rows["masked"]["metrics"]["corner_mark"] is True
        assert report.verdict == vd.headline_verdict(report.verdicts())  # masked counts
        assert list(vd.headline(report.verdicts())) == ["default", "masked"]
        assert report.visibility is not None and report.visibility.worst.touches_subject is False
        said = vd.masked_line(report.verdicts(), corner_mark=True)  # whatever this run's masked verdict
        assert said is not None and said in report.summary_lines() and "masks the" in said
    finally:
        ctx.close()
