"""`ppd auto` of an iPhone shoot, every photo HEIC: it said "need at least 3 images COLMAP can read
(...), got 0", exit 2, while `ppd verify` gave the same shoot a verdict. The sample now takes any
photo ppd patches: the candidates are poisoned onto the HEIC originals in their own format (as the
product writes them), and what COLMAP is given, the clean sample and each candidate's copies, is
staged as `ppd verify` stages it (verifier.pairs: a lossless PNG of the decoded pixels)."""

from __future__ import annotations

import json
from pathlib import Path

import pillow_heif
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from poisoner.media import image_format, read_head
from tests.daemon.cli.test_cli_verify_heic import heic_shoot
from verifier.synthetic import SyntheticOptions, render_scene

runner = CliRunner()
# everything within the budget, so the least visible candidate reaches COLMAP; one profile, 3 photos
WALK = ["--sample", "3", "--profile", "default", "--max-noticeable-area", "1", "--max-p999-vs-jpeg", "0"]


def test_an_all_heic_shoot_gets_an_automatic_decision(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    # LPIPS is reported only (tested in test_auto); the poisoned sample is kept to be looked at
    (ppd_env["config"] / "config.toml").write_text('[preflight]\nlpips_net = "none"\nkeep_images = true\n')
    heic_shoot(ppd_env["outbox"], tmp_path / "renders", 3, arc_deg=30.0)  # close enough to reconstruct
    work = tmp_path / "work"
    result = runner.invoke(app, ["auto", "iphone", *WALK, "--time-budget", "240", "--no-apply",
                                 "--out", str(work), "--json"])  # fmt: skip
    assert result.exit_code in (0, 1), result.output
    decision = json.loads(result.stdout)
    assert decision["sample"] == ["VIEW_00.HEIC", "VIEW_01.HEIC", "VIEW_02.HEIC"]
    tried = [e for e in decision["evidence"] if e["profiles"]]
    assert tried, decision["reason"]
    first = tried[0]["profiles"]["default"]
    assert first["num_images"] == 3, first["reasons"]  # COLMAP was given every clean photo
    assert first["clean_registered"] == 3, first["reasons"]  # and reconstructed them
    kept = sorted((work / "candidates").glob("*/images/*"))
    assert kept and {p.suffix for p in kept} == {".HEIC"}
    assert {image_format(read_head(p)) for p in kept} == {"heif"}  # poisoned as the product writes it
    assert not list(work.glob("**/*.HEIC.png"))  # the staged copies go once verified


def test_a_sample_photo_that_does_not_decode_is_bad_input(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A HEIC cut short (a sync tool's half copy) in a folder of originals: named in one line, exit 2 as
    any bad input of `ppd auto` (ppd's error handler said it with exit 1, which says "none chosen")."""
    (ppd_env["config"] / "config.toml").write_text('[preflight]\nlpips_net = "none"\n')
    pillow_heif.register_heif_opener()
    render_scene(tmp_path / "renders", SyntheticOptions(num_views=3, width=96, height=96))
    shoot = tmp_path / "originals"
    shoot.mkdir()
    for png in sorted((tmp_path / "renders").glob("*.png")):
        Image.open(png).convert("RGB").save(shoot / f"{png.stem.upper()}.HEIC", quality=90)
    cut = shoot / "VIEW_01.HEIC"
    cut.write_bytes(cut.read_bytes()[:3000])
    result = runner.invoke(app, ["auto", str(shoot), "--sample", "3", "--time-budget", "1"])
    lines = result.output.splitlines()
    assert result.exit_code == 2 and lines[-1].startswith("ppd: error: VIEW_01.HEIC: "), result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
