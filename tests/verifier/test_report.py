"""HTML reports (issue 7): self-contained pages with the verdict, history, tables, trajectories and the
patch preview; the real Store/Vault/protect_file for a daemon dataset; headless Chromium loads the page
with no console error and its screenshot shows the verdict banner."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from PIL import Image

from daemon.verification import dataset_report as dataset_reports
from poisoner.spec import PatchSpec
from verifier import html_report as rp
from verifier import report_figures as rf
from verifier.poses import poses_to_json


# ---- fixtures -----------------------------------------------------------------------------------
def _ring_poses(n: int, twist_deg: float = 0.0) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    out = {}
    for i in range(n):
        a = np.radians(360 * i / n + (twist_deg * i if twist_deg else 0))
        r = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
        centre = np.array([4 * np.sin(a), 0.3 * i, -4 * np.cos(a)])
        out[f"v{i}.png"] = (r, -r @ centre)
    return out


def _profile_dir(folder: Path, profile: str, verdict: str) -> Path:
    """What verify_folders leaves: <profile>/{clean,poisoned}/result.json and <profile>/report.json."""
    d = folder / profile
    for side, poses in (("clean", _ring_poses(8)), ("poisoned", _ring_poses(8, twist_deg=7))):
        (d / side).mkdir(parents=True)
        (d / side / "result.json").write_text(json.dumps({"outcome": "ok", "poses": poses_to_json(poses)}))
    report = {
        "profile": profile,
        "verdict": verdict,
        "reasons": [f"{profile}: 0% of cameras within 5 deg"],
        "clean": {"outcome": "ok", "registered": 8, "num_images": 8},
        "poisoned": {"outcome": "ok", "registered": 8, "num_images": 8},
        "vs_clean": {"frac_within_5deg": 0.0, "median_rotation_error_deg": 31.5},
        "model_dir": str(d),
    }
    (d / "report.json").write_text(json.dumps(report))
    return d


def test_the_camera_plot_says_when_nothing_could_be_aligned(tmp_path: Path) -> None:
    """Found on an installed ppd: a clean run with no camera still had its plot captioned "aligned
    onto clean by a robust similarity"."""
    from verifier.report_figures import trajectory_figure

    d = _profile_dir(tmp_path, "default", "inconclusive")
    aligned = trajectory_figure(d, "default")
    assert aligned is not None and "aligned onto clean by a robust similarity" in aligned.caption
    (d / "clean" / "result.json").write_text(json.dumps({"outcome": "ok", "poses": {}}))
    alone = trajectory_figure(d, "default")
    assert alone is not None and "(0 cameras, green)" in alone.caption
    assert "NOT aligned" in alone.caption and "by a robust similarity" not in alone.caption
    assert "0 cameras registered on both sides (3 are needed)" in alone.caption, alone.caption
    clean_poses = json.loads((d / "poisoned" / "result.json").read_text())  # cameras on one side only
    (d / "clean" / "result.json").write_text(json.dumps(clean_poses))
    (d / "poisoned" / "result.json").write_text(json.dumps({"outcome": "ok", "poses": {}}))
    one_side = trajectory_figure(d, "default")
    assert one_side is not None and "(0 cameras, orange, NOT aligned: 0 cameras registered on both" in (
        one_side.caption), one_side.caption  # it said "too few cameras in both" of a clean side of 8
    assert "too few cameras in both" not in one_side.caption


def _srcs(page: str) -> list[str]:
    return re.findall(r'(?:src|href)="([^"]*)"', page)


# ---- the page -----------------------------------------------------------------------------------
def test_page_is_self_contained_and_shows_the_verdict(tmp_path: Path) -> None:
    _profile_dir(tmp_path / "run", "default", "protected")
    data = rp.build_report(str(tmp_path / "run"))
    assert data.verdict == "protected"
    page = rp.render_html(data)
    assert rp.VERDICT_COLOURS["protected"] in page and 'data-verdict="protected"' in page
    assert "default: 0% of cameras within 5 deg" in page  # the reasons
    assert "<script" not in page.lower() and "http://" not in page and "https://" not in page
    srcs = _srcs(page)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert any("Camera trajectories" in f.caption for f in data.figures)


def test_weakest_profile_decides_and_no_verdict_without_one(tmp_path: Path) -> None:
    _profile_dir(tmp_path / "run", "default", "protected")
    _profile_dir(tmp_path / "run", "hardened", "not_protected")
    page = rp.render_html(rp.build_report(str(tmp_path / "run")))
    assert 'data-verdict="not_protected"' in page and rp.VERDICT_COLOURS["protected"] not in page
    empty = rp.render_html(rp.ReportData(title="t", verdict=None))
    assert "data-verdict" not in empty and not any(c in empty for c in rp.VERDICT_COLOURS.values())


def test_the_banner_names_the_profiles_a_verdict_rests_on(tmp_path: Path) -> None:
    """A black-box review: "Verdict: PROTECTED" in the banner, measured under global alone while the
    other four profiles' COLMAP did not reconstruct the originals; said below it only."""
    _profile_dir(tmp_path / "run", "global", "protected")
    _profile_dir(tmp_path / "run", "default", "inconclusive")
    _profile_dir(tmp_path / "run", "hardened", "inconclusive")
    banner = _banner(tmp_path / "run")
    assert banner.startswith("Verdict: PROTECTED"), banner
    assert "(under global only; not verified under default, hardened)" in banner, banner
    _profile_dir(tmp_path / "all", "global", "protected")
    _profile_dir(tmp_path / "all", "default", "protected")
    assert "only" not in _banner(tmp_path / "all")


def _banner(folder: Path) -> str:
    found = re.search(r'<div class="banner"[^>]*>([^<]*)</div>', rp.render_html(rp.build_report(str(folder))))
    assert found is not None
    return found.group(1)


def test_nothing_to_report_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(rp.ReportError, match="no report.json"):
        rp.build_report(str(tmp_path / "empty"))
    with pytest.raises(rp.ReportError, match="no daemon store"):
        rp.build_report(str(tmp_path / "nowhere"))


def test_experiment_folder_report(tmp_path: Path) -> None:
    from verifier import experiment as ex

    exp = tmp_path / "exp"
    exp.mkdir()
    model = _profile_dir(tmp_path / "models", "default", "protected")
    for i, (kind, label, ssim) in enumerate([("clean", "clean", 1.0), ("patch", "P=12 b=4", 0.9996),
                                             ("patch", "P=48 b=4", 0.995)]):  # fmt: skip
        ex.append_row(exp / ex.RESULTS_NAME, {
            "setting_id": f"s{i}", "run": 0, "kind": kind, "label": label,
            "groups": ["clean"] if kind == "clean" else ["patch_size"],
            "params": {} if kind == "clean" else {"patch_size": int(label[2:4])},
            "cost2": {"ssim": ssim, "psnr": 40.0 - i}, "within5_of_clean": 1.0 - 0.5 * i,
            "verdict": "protected",
            "profiles": {"default": {"model_dir": str(model)}},
        })  # fmt: skip
    data = rp.build_report(str(exp))
    assert data.verdict is None
    captions = " ".join(f.caption for f in data.figures)
    assert "Trade-off" in captions and "patch_size" in captions and "Camera trajectories" in captions
    assert [r[0] for r in data.tables[0].rows] == ["clean", "P=12 b=4", "P=48 b=4"]


# ---- a daemon dataset, real Store / Vault / protect_file ------------------------------------------
def _protected_dataset(ppd_env: dict[str, Path], tmp_path: Path) -> Any:
    from daemon.protect.one_file import AppContext, protect_file

    ctx = AppContext.open()
    trip = ppd_env["outbox"] / "trip"
    trip.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        Image.fromarray(rng.integers(0, 256, (200, 240, 3), dtype=np.uint8)).save(trip / f"v{i}.png")
        assert protect_file(trip / f"v{i}.png", ctx).state == "patched"
    run_dir = ctx.paths.runs_dir / "trip" / "20260101T000000-abcdef"
    now = time.time()  # verified after the files were patched: the verdict is current (issue 25)
    for profile, verdict, t in (("default", "protected", now + 99), ("hardened", "not_protected", now + 100)):
        d = _profile_dir(run_dir, profile, verdict)
        ctx.store.add_verification_run(
            "trip", profile, verdict,
            {"reasons": [f"{profile} reason"], "vs_clean": {"frac_within_5deg": 0.5}},
            t - 50, t, str(d), None,
        )  # fmt: skip
    return ctx


def test_dataset_report_with_the_real_store(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    ctx = _protected_dataset(ppd_env, tmp_path)
    try:
        data = dataset_reports.build_dataset_report(ctx, "trip")
        assert data.verdict == "not_protected"  # the weakest profile of the latest run
        assert data.protection == "NOT protected (hardened): find a design that holds: `ppd auto trip`"
        assert 'id="protection"' in rp.render_html(data)
        assert data.reasons == {"hardened": ["hardened reason"], "default": ["default reason"]}
        history = next(t for t in data.tables if t.title.startswith("Verification history"))
        assert [r[1] for r in history.rows] == ["hardened", "default"]  # newest first
        captions = [f.caption for f in data.figures]
        assert sum("Camera trajectories" in c for c in captions) == 2
        preview = next(f for f in data.figures if f.caption.startswith("Patch preview"))
        assert Image.open(io.BytesIO(preview.png)).size[0] > 200
        with pytest.raises(rp.ReportError, match="no dataset"):
            dataset_reports.build_dataset_report(ctx, "elsewhere")
    finally:
        ctx.close()


def test_a_verdict_on_earlier_pixels_is_no_banner(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """Found on an installed ppd: after a file was restored, the report's banner still showed the
    old verdict. A verdict that measured earlier pixels is history (issue 25): the banner says the
    dataset's state now, the history table keeps the old runs."""
    from daemon.protect.one_file import AppContext, protect_file, restore_file

    ctx = AppContext.open()
    try:
        trip = ppd_env["outbox"] / "trip"
        trip.mkdir()
        for i in range(3):
            pixels = np.random.default_rng(i).integers(0, 256, (200, 240, 3), dtype=np.uint8)
            Image.fromarray(pixels).save(trip / f"v{i}.png")
            assert protect_file(trip / f"v{i}.png", ctx).state == "patched"
        now = time.time()  # verified after the patching, before the restore below
        for profile in ("default", "hardened"):
            d = _profile_dir(ctx.paths.runs_dir / "trip" / "run1", profile, "inconclusive")
            ctx.store.add_verification_run("trip", profile, "inconclusive", {"reasons": []}, now, now + 0.01,
                                           str(d), None)  # fmt: skip
        assert dataset_reports.build_dataset_report(ctx, "trip").verdict == "inconclusive"  # current
        time.sleep(0.05)
        assert restore_file(ctx, trip / "v0.png").state == "restored"
        data = dataset_reports.build_dataset_report(ctx, "trip")
        assert data.verdict is None and data.holding is None
        page = rp.render_html(data)
        assert 'id="verdict"' not in page and "not verified" in (data.protection or ""), data.protection
        assert any("it is history, not today's verdict" in n for n in data.notes)
        history = next(t for t in data.tables if t.title.startswith("Verification history"))
        assert len(history.rows) == 2
        # the files left unprotected are said, and the history is not "never verified" (a black-box
        # review: the page named neither the restored nor the new file, above its own history table)
        Image.fromarray(np.zeros((200, 240, 3), np.uint8) + 90).save(trip / "new.png")
        page = rp.render_html(dataset_reports.build_dataset_report(ctx, "trip"))
        assert "NOT protected: 1 not patched yet, 1 restored by you" in page, page[:2000]
        assert "never been verified" not in page
    finally:
        ctx.close()


def test_cli_report_and_status_link(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from daemon.cli import app

    _protected_dataset(ppd_env, tmp_path).close()
    runner = CliRunner()
    result = runner.invoke(app, ["report", "trip"])
    assert result.exit_code == 0, result.output
    latest = ppd_env["data"] / "reports" / "trip" / "latest.html"
    assert latest.is_file() and 'data-verdict="not_protected"' in latest.read_text()
    status = runner.invoke(app, ["status"])
    assert status.exit_code == 0, status.output
    assert f"file://{latest}" in status.output.replace("\n", "")
    bad = runner.invoke(app, ["report", "no-such-dataset"])
    assert bad.exit_code == 2 and "no dataset" in bad.output


# ---- headless Chromium --------------------------------------------------------------------------
def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("no chromium binary (scripts/setup.d/chromium.sh installs Debian's chromium)")
    return exe


def load_in_chromium(page: Path, shot: Path, profile: Path) -> list[str]:
    """Load a page headless; return its console lines (errors, failed loads, any console output)."""
    # chromium binds its singleton socket under TMPDIR: a short private one keeps that path under the
    # kernel's 107-byte AF_UNIX limit whatever temp path the suite runs under (Debian's wrapper script
    # also reads TMPDIR unquoted: a space there breaks it)
    short = tempfile.mkdtemp(prefix="ppd-chromium-", dir="/tmp" if os.path.isdir("/tmp") else None)
    try:
        proc = subprocess.run(
            [_chromium(), "--headless=new", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr",
             "--v=0", "--virtual-time-budget=3000", f"--screenshot={shot}", "--window-size=1280,1000",
             f"--user-data-dir={profile}", "--no-first-run", page.resolve().as_uri()],
            capture_output=True, text=True, timeout=120, check=False, env={**os.environ, "TMPDIR": short},
        )  # fmt: skip
    finally:
        shutil.rmtree(short, ignore_errors=True)
    assert shot.is_file(), proc.stderr[-2000:]
    return [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]


def _colour_pixels(png: Path, hex_colour: str) -> int:
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    rgb = np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(img - rgb).max(axis=-1) <= 2).sum())


def test_chromium_loads_the_report_cleanly_and_shows_the_verdict(tmp_path: Path) -> None:
    _chromium()
    _profile_dir(tmp_path / "run", "default", "protected")
    page = rp.write_report(rp.build_report(str(tmp_path / "run")), tmp_path / "report.html")
    console = load_in_chromium(page, tmp_path / "shot.png", tmp_path / "chrome1")
    assert console == []
    green = rp.VERDICT_COLOURS["protected"]
    assert _colour_pixels(tmp_path / "shot.png", green) > 20_000  # the banner, clearly visible

    # the detector catches a broken page, and a page without a verdict has no banner colour
    broken = tmp_path / "broken.html"
    broken.write_text(page.read_text().replace("</body>", "<script>notDefinedAnywhere();</script></body>"))
    assert any(
        "notDefinedAnywhere" in line for line in load_in_chromium(broken, tmp_path / "b.png", tmp_path / "c2")
    )
    plain = rp.write_report(rp.ReportData(title="no verdict", verdict=None), tmp_path / "plain.html")
    assert load_in_chromium(plain, tmp_path / "p.png", tmp_path / "c3") == []
    assert _colour_pixels(tmp_path / "p.png", green) == 0


def test_report_of_a_patch_spec_has_a_preview_size_that_fits(tmp_path: Path) -> None:
    a = np.full((120, 160, 3), 200, np.uint8)
    from poisoner.blend import poison_array

    b, _ = poison_array(a, PatchSpec(patch_size=24, block_size=4))
    Image.fromarray(a).save(tmp_path / "a.png")
    Image.fromarray(b).save(tmp_path / "b.png")
    fig = rf.patch_preview_figure(
        tmp_path / "a.png", tmp_path / "b.png", PatchSpec(patch_size=24, block_size=4)
    )
    assert fig is not None and Image.open(io.BytesIO(fig.png)).size[0] >= 2 * 160
    assert rf.patch_preview_figure(tmp_path / "a.png", tmp_path / "missing.png", PatchSpec()) is None


# ---- visibility and the profiles the protection does not hold under --------------------------------
def _marked_folders(root: Path, n: int = 4) -> tuple[Path, Path]:
    """Noise-free smooth originals and copies with a 16 px checkerboard in the top-left corner."""
    clean, pois = root / "clean", root / "poisoned"
    clean.mkdir(parents=True)
    pois.mkdir()
    yy, xx = np.mgrid[0:150, 0:200]
    for i in range(n):
        base = np.clip(120 + 50 * np.sin((xx + 9 * i) / 17.0) * np.cos(yy / 23.0), 0, 255)
        img = np.repeat(base[..., None], 3, axis=2).astype(np.uint8)
        Image.fromarray(img).save(clean / f"v{i}.png")
        checker = (np.indices((16, 16)).sum(axis=0) // 2) % 2 == 0
        img[4:20, 4:20] = np.where(checker, 0, 255)[..., None]
        Image.fromarray(img).save(pois / f"v{i}.png")
    return clean, pois


def _verification_folder(root: Path, verdicts: dict[str, str]) -> Path:
    """A verify_folders out dir: per-profile folders and the top report.json with measured visibility."""
    from verifier.verification import ProfileReport, VerificationReport, write_json
    from verifier.visibility import measure_pairs

    clean, pois = _marked_folders(root / "images")
    out = root / "run"
    profiles = {}
    for name, verdict in verdicts.items():
        d = _profile_dir(out, name, verdict)
        stored = json.loads((d / "report.json").read_text())
        fields = {k: v for k, v in stored.items() if k != "model_dir"}
        profiles[name] = ProfileReport(**fields, model_dir=str(d))
    pairs = [(clean / f"v{i}.png", pois / f"v{i}.png") for i in range(4)]
    report = VerificationReport(str(clean), str(pois), str(out), 4, profiles, measure_pairs(pairs, sample=2))
    write_json(out / "report.json", report.to_dict())
    return out


def test_verification_report_shows_visibility_masked_row_and_what_fails(tmp_path: Path) -> None:
    out = _verification_folder(tmp_path, {"default": "protected", "hardened": "not_protected"})
    data = rp.build_report(str(out))
    vis = next(t for t in data.tables if t.title.startswith("Visibility"))
    assert [r[0] for r in vis.rows] == ["v0.png", "v3.png", "worst of 2"]
    stored = json.loads((out / "report.json").read_text())["visibility"]["worst"]
    worst = vis.rows[-1]
    assert stored["area_above_half"] > 0 and worst[6] == f"{100 * stored['area_above_half']:.3f}%"
    assert worst[1] == "200" and worst[4] == f"{stored['flip_p999']:.3f}" and worst[8] == "yes"
    assert any("measured on 2 of 4 images" in n for n in data.notes)
    table = next(t for t in data.tables if t.title.startswith("Metrics per profile"))
    rows = {r[0]: r for r in table.rows}
    assert list(rows) == ["default", "hardened", "published", "global", "masked"]
    assert rows["masked"][1] == "not run" and rows["hardened"][1] == "not_protected"
    not_run = "(not run here: published, global, masked)"
    assert data.holding == f"The protection does NOT hold under: hardened {not_run}"
    page = rp.render_html(data)
    assert 'id="holding"' in page and "does NOT hold under: hardened" in page
    assert "area FLIP &gt; 0.5" in page
    picture = next(f for f in data.figures if "at display size" in f.caption)
    shown = Image.open(io.BytesIO(picture.png))
    assert shown.size[0] == 200 and shown.size[1] > 150  # the image at its own width, the zoom below
    assert "x 4–20, y 4–20" in picture.caption


def test_untouched_copy_has_no_visible_area_in_the_report(tmp_path: Path) -> None:
    from verifier.visibility import measure_pairs

    clean, _ = _marked_folders(tmp_path)
    vis = measure_pairs([(clean / "v0.png", clean / "v0.png")], sample=1)
    assert vis is not None
    row = rf.visibility_table(json.loads(json.dumps(msgspec.to_builtins(vis)))).rows[-1]
    assert row[6] == "0.000%" and row[7] == "0.000%" and row[8] == "nothing changed"


def test_old_run_folder_without_visibility_still_reads(tmp_path: Path) -> None:
    _profile_dir(tmp_path / "run", "default", "protected")
    (tmp_path / "run" / "report.json").write_text(
        json.dumps({"verdict": "protected", "profiles": {"default": json.loads(
            (tmp_path / "run" / "default" / "report.json").read_text())}})
    )  # fmt: skip
    data = rp.build_report(str(tmp_path / "run"))
    assert data.verdict == "protected"
    assert any("not measured" in n for n in data.notes)
    assert not any(t.title.startswith("Visibility") for t in data.tables)
    assert data.holding is not None
    assert data.holding.startswith("The protection holds under every profile run (default)")


def test_dataset_report_shows_the_recorded_visibility(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    from daemon.verification.verify import record_report
    from verifier.verification import ProfileReport, VerificationReport
    from verifier.visibility import measure_pairs

    ctx = _protected_dataset(ppd_env, tmp_path)
    try:
        from daemon.protect.one_file import dataset_pairs

        pairs = dataset_pairs(ctx, "trip")
        vis = measure_pairs(pairs, sample=3)
        assert vis is not None and vis.worst.area_above_half > 0  # ppd's default patch is seen
        run_dir = ctx.paths.runs_dir / "trip" / "20260102T000000-abcdef"
        masked = ProfileReport(
            profile="masked", verdict="not_protected", reasons=["masked reason"], clean={"outcome": "ok"},
            poisoned={"outcome": "ok"}, vs_clean=None, model_dir=str(run_dir / "masked"),
            started_at=time.time() + 200, finished_at=time.time() + 201,  # after _protected_dataset's run
        )  # fmt: skip
        record_report(ctx, "trip", VerificationReport("c", "p", str(run_dir), 3, {"masked": masked}, vis))
        data = dataset_reports.build_dataset_report(ctx, "trip")
        vis_table = next(t for t in data.tables if t.title.startswith("Visibility"))
        assert vis_table.rows[-1][6] == f"{100 * vis.worst.area_above_half:.3f}%"
        # the newest run of each profile on today's pixels, as `ppd status` judges: hardened's earlier
        # failure still counts beside masked's (the newest run alone said only masked)
        assert data.holding is not None and "does NOT hold under: hardened, masked" in data.holding
        assert any("at display size" in f.caption for f in data.figures)
    finally:
        ctx.close()


def test_dataset_report_counts_the_headline_and_says_the_masked_line_and_the_corner(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A corner-mark dataset: its report's verdict counts the masked attacker too (issue 25, round 2),
    which also has its own plain line saying why, and the placement (corner and why) is said."""
    from daemon.protect.one_file import AppContext, protect_file

    (ppd_env["config"] / "config.toml").write_text('[patch]\ndesign = "watermark"\n')
    ctx = AppContext.open()
    try:
        shoot = ppd_env["outbox"] / "shoot"
        shoot.mkdir()
        rng = np.random.default_rng(1)
        for i in range(3):
            pixels = rng.integers(0, 256, (200, 240, 3), dtype=np.uint8)
            pixels[150:, 180:] = 90  # a plain bottom-right corner: the least detail
            Image.fromarray(pixels).save(shoot / f"v{i}.png")
            assert protect_file(shoot / f"v{i}.png", ctx).state == "patched"
        run_dir = ctx.paths.runs_dir / "shoot" / "20260101T000000-abcdef"
        verdicts = (("default", "protected"), ("hardened", "protected"), ("masked", "not_protected"))
        now = time.time()  # verified after the patching: today's verdict (issue 25)
        for profile, verdict in verdicts:
            ctx.store.add_verification_run(
                "shoot", profile, verdict, {"reasons": [], "corner_mark": True}, now, now + 1,
                str(_profile_dir(run_dir, profile, verdict)), None,
            )  # fmt: skip
        data = dataset_reports.build_dataset_report(ctx, "shoot")
    finally:
        ctx.close()
    assert data.verdict == "not_protected"  # masked counts: no corner mark survives it
    assert data.holding is not None
    assert data.holding.startswith("The protection does NOT hold under: masked")
    assert "NOT protected against an attacker who masks the corners (a corner mark cannot be)" in data.holding
    assert "Placement: shoot: mark in the bottom-right corner (estimated: least detail)." in data.notes
    assert any("masks the four corner regions" in n for n in data.notes)


def test_dataset_report_verdict_is_status_s_across_separate_runs(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: `verify -p masked` (NOT protected), then `verify -p default` (protected):
    `ppd status` said NOT protected (masked), the report "Verdict: PROTECTED" (its newest run alone).
    Both now judge the newest run of every profile on today's pixels; and a file copied over a patched
    one since makes that verdict history in both."""
    from daemon.cli.status_queries import dataset_status

    ctx = _protected_dataset(ppd_env, tmp_path)  # default protected, hardened NOT protected
    try:
        later = time.time() + 300
        for n, (profile, verdict) in enumerate((("hardened", "protected"), ("masked", "not_protected"))):
            d = _profile_dir(ctx.paths.runs_dir / "trip" / f"2026010{n + 2}T000000-abcdef", profile, verdict)
            ctx.store.add_verification_run("trip", profile, verdict, {"reasons": [f"{profile} again"]},
                                           later + n, later + n + 1, str(d), None)  # fmt: skip
        d = _profile_dir(ctx.paths.runs_dir / "trip" / "20260109T000000-abcdef", "default", "protected")
        ctx.store.add_verification_run(
            "trip", "default", "protected", {}, later + 9, later + 10, str(d), None
        )
        data = dataset_reports.build_dataset_report(ctx, "trip")
        status = dataset_status(ctx, "trip")["protection"]
        assert status["state"] == "NOT protected" and status["profiles"] == ["masked"]
        assert data.verdict == "not_protected" and "does NOT hold under: masked" in (data.holding or "")
        assert data.protection is not None and data.protection.startswith("NOT protected (masked)")
        # masked passes later: protected in both; then an original over a patched file: history in both
        d = _profile_dir(ctx.paths.runs_dir / "trip" / "20260110T000000-abcdef", "masked", "protected")
        ctx.store.add_verification_run(
            "trip", "masked", "protected", {}, later + 20, later + 21, str(d), None
        )
        assert dataset_status(ctx, "trip")["protection"]["state"] == "protected"
        assert dataset_reports.build_dataset_report(ctx, "trip").verdict == "protected"
        Image.new("RGB", (240, 200), (1, 2, 3)).save(ppd_env["outbox"] / "trip" / "v1.png")
        assert dataset_status(ctx, "trip")["protection"]["state"] == "patched, not verified"
        again = dataset_reports.build_dataset_report(ctx, "trip")
        assert again.verdict is None and again.protection is not None
        assert again.protection.startswith("patched, not verified")
    finally:
        ctx.close()


def test_a_video_s_measured_frames_are_on_the_page(tmp_path: Path) -> None:
    """`ppd verify` says which frames of a video its verdict rests on; the page says it too."""
    d = _profile_dir(tmp_path / "run", "default", "protected")
    line = "orbit.mp4: 8 frames measured, every 6th frame from frame 0 to 42; an attacker may take others"
    profile = json.loads((d / "report.json").read_text())
    top = {"profiles": {"default": profile}, "video_frames": [line]}
    (tmp_path / "run" / "report.json").write_text(json.dumps(top))
    assert line in rp.render_html(rp.build_report(str(tmp_path / "run")))
    runs = [{"profile": "default", "verdict": "protected", "model_dir": str(d),
             "metrics": {"video_frames": [line]}}]  # fmt: skip
    page = rp.render_html(rp.dataset_history_report("t", runs, "patched", [], None, "never verified"))
    assert line in page
