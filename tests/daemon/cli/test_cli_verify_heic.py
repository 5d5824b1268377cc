"""An iPhone shoot, every photo HEIC: `ppd verify` said "no images in <a folder inside ppd's data>",
exit 2, nothing with --json, nothing recorded, and `ppd status` kept saying to run it (a seventh
black-box review, F2). No COLMAP reads HEIC, so an attacker converts first: the verification converts
too (verifier.pairs), and the shoot gets a verdict. A set none of whose photos can be given to COLMAP
is recorded as could-not-be-verified, and said so."""

from __future__ import annotations

import json
from pathlib import Path

import pillow_heif
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from verifier.synthetic import SyntheticOptions, render_scene

runner = CliRunner()


def said(result: object) -> str:
    return " ".join(str(getattr(result, "output", "")).split())


def heic_shoot(outbox: Path, renders: Path, views: int, arc_deg: float = 120.0) -> Path:
    """A patched outbox shoot of `views` synthetic views (over arc_deg) saved as HEIC, as an iPhone does."""
    pillow_heif.register_heif_opener()
    render_scene(renders, SyntheticOptions(num_views=views, arc_deg=arc_deg))
    shoot = outbox / "iphone"
    shoot.mkdir()
    for png in sorted(renders.glob("*.png")):
        Image.open(png).convert("RGB").save(shoot / f"{png.stem.upper()}.HEIC", quality=90)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    return shoot


def test_an_all_heic_shoot_gets_a_verdict(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    heic_shoot(ppd_env["outbox"], tmp_path / "renders", 8)
    result = runner.invoke(app, ["verify", "iphone", "-p", "default", "--json"])
    assert result.exit_code in (0, 1), result.output
    report = json.loads(result.stdout)
    p = report["profiles"]["default"]
    assert (report["num_images"], report["num_measured"], report["left_out"]) == (8, 8, []), p["reasons"]
    assert (p["clean"]["num_images"], p["poisoned"]["num_images"]) == (8, 8)  # COLMAP read every one
    assert p["clean"]["registered"] == 8 and report["verdict"] != "inconclusive", p["reasons"]
    assert result.exit_code == (0 if report["verdict"] == "protected" else 1)
    status = said(runner.invoke(app, ["status", "iphone"]))
    assert "`ppd verify iphone`" not in status and "verified: never" not in status


def test_a_set_of_photos_none_of_which_decodes_could_not_be_verified(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Each patched file cut short since (a sync tool's half copy): nothing can be given to COLMAP.
    One line says so, exit 1, --json says it, it is recorded, and status says "could not be verified"
    and suggests no verification again (it says the files changed: `ppd poison` checks them)."""
    shoot = heic_shoot(ppd_env["outbox"], tmp_path / "renders", 3)
    for photo in shoot.iterdir():
        photo.write_bytes(photo.read_bytes()[:3000])
    result = runner.invoke(app, ["verify", "iphone", "-p", "default"])
    assert result.exit_code == 1, result.output
    text = said(result)
    assert "none of the 3 photos could be given to COLMAP (VIEW_00.HEIC: " in text and ", and 2 more)" in text
    # the files changed since patched are not ppd's output: NOT protected, whatever was measured (F8)
    overall = "overall: NOT protected: 3 changed since patched; the 0 patched (weakest of default): could not"
    assert f"{overall} be verified" in text and "ppd: error" not in text, text
    as_json = runner.invoke(app, ["verify", "iphone", "-p", "default", "--json"])
    report = json.loads(as_json.stdout)
    assert as_json.exit_code == 1 and report["patched_files_verdict"] == "inconclusive", report
    assert report["verdict"] == "not_protected", report
    assert report["left_out"] == ["VIEW_00.HEIC", "VIEW_01.HEIC", "VIEW_02.HEIC"]
    assert report["num_measured"] == 0
    d = json.loads(runner.invoke(app, ["status", "iphone", "--json"]).stdout)["datasets"][0]
    assert d["verdicts"]["default"]["verdict"] == "inconclusive" and len(d["not_measured"]) == 3
    status = said(runner.invoke(app, ["status", "iphone"]))
    assert "default: could not be verified (inconclusive)" in status and "`ppd verify iphone`" not in status
    page = tmp_path / "r.html"
    assert runner.invoke(app, ["report", "iphone", "--out", str(page)]).exit_code == 0
    assert 'data-verdict="protected"' not in page.read_text()
