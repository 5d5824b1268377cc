"""A dataset of phone photos, two stored turned (EXIF orientation 6): `ppd verify` measures all of
them, and a photo a verification did not measure keeps the dataset from being called protected in
`ppd status`, `--check`, `--json` and `ppd report` (black-box review 5, F1: "6/6 images" for a
dataset of 8, "protected", `--check` exit 0, report PROTECTED)."""

from __future__ import annotations

import json
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.cli import verified_shoot
from verifier.synthetic import SyntheticOptions, render_scene

runner = CliRunner()


def said(result: object) -> str:
    return " ".join(str(getattr(result, "output", "")).split())


def test_verify_measures_photos_stored_turned(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The review's set, small: 8 views at 320x240, two stored turned as a phone writes them."""
    render_scene(tmp_path / "renders", SyntheticOptions(num_views=8, width=320, height=240))
    shoot = ppd_env["outbox"] / "phone"
    shoot.mkdir()
    for i, png in enumerate(sorted((tmp_path / "renders").glob("*.png"))):
        im, exif = Image.open(png).convert("RGB"), Image.Exif()
        exif[0x0112] = 1
        if i in (2, 5):
            im, exif[0x0112] = im.transpose(Image.Transpose.ROTATE_90), 6
        im.save(shoot / f"P{i:02d}.jpg", quality=92, exif=exif.tobytes())
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    result = runner.invoke(app, ["verify", "phone", "-p", "default", "--json"])
    report = json.loads(result.stdout)
    p = report["profiles"]["default"]
    # convert.py's single camera: 6 of 8 in COLMAP's databases, unsaid
    assert (p["clean"]["num_images"], p["poisoned"]["num_images"]) == (8, 8), p["reasons"]
    assert report["num_images"] == report["num_measured"] == 8 and report["left_out"] == []
    assert report["sizes"] == {"320x240": 6, "240x320": 2}
    assert any("one camera per size" in line for line in report["summary"])


def test_a_photo_in_a_format_colmap_does_not_read_is_measured(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """ppd patches AVIF and HEIC, which no COLMAP reads: the verification's staging left them out (named,
    the set never "protected"); it now converts them as an attacker would (verifier.pairs), and they
    are measured with the others."""
    render_scene(tmp_path / "renders", SyntheticOptions(num_views=6))
    shoot = ppd_env["outbox"] / "mixed"
    shoot.mkdir()
    for png in sorted((tmp_path / "renders").glob("*.png")):
        name = png.name if png.stem != "view_05" else "view_05.avif"
        Image.open(png).convert("RGB").save(shoot / name)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    result = runner.invoke(app, ["verify", "mixed", "-p", "default", "--json"])
    report = json.loads(result.stdout)
    p = report["profiles"]["default"]
    assert report["left_out"] == [] and (report["num_images"], report["num_measured"]) == (6, 6), p["reasons"]
    assert (p["clean"]["num_images"], p["poisoned"]["num_images"]) == (6, 6)
    assert not any(r.startswith("not measured") for r in p["reasons"])
    d = json.loads(runner.invoke(app, ["status", "mixed", "--json"]).stdout)["datasets"][0]
    assert d["not_measured"] == []


def test_a_photo_no_verification_measured_is_not_called_protected(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Every attacker measured "protected" on the others; one photo was not in COLMAP's database (the
    Store row as record_report writes it): not protected, said, and `--check` says why."""
    verified_shoot(ppd_env["outbox"] / "set", 4, left_out_of_default=("v1.png",))
    check = runner.invoke(app, ["status", "set", "--check"])
    assert check.exit_code == 1, check.output
    assert "1 photo(s) no verification measured (v1.png)" in said(check)
    d = json.loads(runner.invoke(app, ["status", "set", "--json"]).stdout)["datasets"][0]
    assert d["not_measured"] == ["v1.png"] and d["verdicts"]["default"]["left_out"] == ["v1.png"]
    assert d["protection"]["state"] == "could not be verified" and d["protection"]["profiles"] == ["default"]
    assert "1 photo(s) no verification measured (v1.png)" in said(runner.invoke(app, ["status", "set"]))
    page = tmp_path / "r.html"
    assert runner.invoke(app, ["report", "set", "--out", str(page)]).exit_code == 0
    html = page.read_text()
    assert 'data-verdict="protected"' not in html and "Not measured: 1 photo(s) (v1.png)" in html


def test_every_photo_measured_is_protected_as_before(ppd_env: dict[str, Path]) -> None:
    verified_shoot(ppd_env["outbox"] / "set", 3, left_out_of_default=())
    assert runner.invoke(app, ["status", "set", "--check"]).exit_code == 0
    d = json.loads(runner.invoke(app, ["status", "set", "--json"]).stdout)["datasets"][0]
    assert d["not_measured"] == [] and d["protection"]["state"] == "protected"
