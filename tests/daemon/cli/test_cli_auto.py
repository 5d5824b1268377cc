"""`ppd auto FOLDER`: the scene hint (poisoner/scene.py) is said up front, before the preflight's
decision, and travels in --json. The preflight itself is tested in test_auto / test_auto_daemon; here
a one-second time budget stops it before any SfM (the ladder's visibility is still measured)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli.scene_note import PREFIX
from verifier.synthetic import SyntheticOptions, render_scene

FAST = ["--sample", "3", "--time-budget", "1"]


@pytest.fixture
def fast_config(ppd_env: dict[str, Path]) -> dict[str, Path]:
    # LPIPS (reported only, slow on a shared CPU) is tested in test_auto
    (ppd_env["config"] / "config.toml").write_text('[preflight]\nlpips_net = "none"\n')
    return ppd_env


def _render(folder: Path, backdrop: str) -> Path:
    render_scene(folder, SyntheticOptions(num_views=3, width=200, height=150, focal=240.0, backdrop=backdrop))
    return folder


def test_auto_says_the_scene_hint_before_the_decision(fast_config: dict[str, Path], tmp_path: Path) -> None:
    from daemon.cli import app

    folder = _render(tmp_path / "studio", "plain")
    result = CliRunner().invoke(app, ["auto", str(folder), *FAST])
    assert result.exit_code in (0, 1), result.output
    lines = result.output.splitlines()
    hint = [i for i, line in enumerate(lines) if line.startswith(PREFIX)]
    assert len(hint) == 1, result.output
    assert lines[hint[0]].startswith(f"{PREFIX}studio: plain background around the subject")
    assert "`ppd verify`" in lines[hint[0]]
    decision = next(i for i, line in enumerate(lines) if "candidates" in line or "stopped at" in line)
    assert hint[0] < decision  # up front: before the preflight's outcome


def test_auto_json_carries_the_hint_and_prints_nothing_else(
    fast_config: dict[str, Path], tmp_path: Path
) -> None:
    from daemon.cli import app

    folder = _render(tmp_path / "room", "textured")
    result = CliRunner().invoke(app, ["auto", str(folder), *FAST, "--json"])
    assert result.exit_code in (0, 1), result.output
    decision = json.loads(result.output)  # the JSON alone: the hint is not printed as a line
    assert decision["scene_hint"].startswith(f"{PREFIX}room: richly textured everywhere")
    assert decision["sample"] and "chosen" in decision


def test_auto_of_a_restored_dataset_says_why_it_has_nothing_to_measure(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd auto A` after `ppd restore A` said "need at least 3 images COLMAP can read (...), got 0"
    of a folder of 4 JPEGs (a black-box review): it measures patched files' vault originals."""
    from daemon.cli import app

    shoot = tmp_path / "A"
    render_scene(shoot, SyntheticOptions(num_views=4, width=96, height=96))
    runner = CliRunner()
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["restore", "A"]).exit_code == 0
    result = runner.invoke(app, ["auto", "A", "--no-apply"])
    said = " ".join(result.output.split())
    assert result.exit_code == 2 and "has 0 patched file(s)" in said and "`ppd poison`" in said, said


@pytest.mark.parametrize("area", ["2", "-1"])
def test_a_bad_budget_is_one_line_before_any_work(ppd_env: dict[str, Path], tmp_path: Path,
                                                  area: str) -> None:  # fmt: skip
    """`ppd auto X --max-noticeable-area 2` analysed the photos and printed the scene hint's paragraph
    before its error (a black-box review, F11): now the error alone, as `--sample 1` is."""
    from daemon.cli import app

    folder = _render(tmp_path / "room", "textured")
    result = CliRunner().invoke(app, ["auto", str(folder), "--max-noticeable-area", area])
    lines = result.output.splitlines()
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert lines[0].startswith("ppd: error: ") and "max_noticeable_area must be 0..1" in lines[0], lines


def test_the_candidates_fit_80_columns_and_no_token_is_a_line(fast_config: dict[str, Path],
                                                               tmp_path: Path) -> None:  # fmt: skip
    """At 80 columns (a pipe, a log file) the candidate table cut SSIM 0.9938 into "0.993" and an "8" a row
    below, a name over five rows, and a bare "time_budget" line preceded the reason (a black-box review,
    F8): one block per candidate, every value whole; the table where it fits."""
    import os
    import re
    import subprocess
    import sys

    folder = _render(tmp_path / "studio", "plain")

    def run(columns: int) -> list[str]:
        proc = subprocess.run([sys.executable, "-m", "daemon.cli", "auto", str(folder), *FAST],
                              capture_output=True, text=True, timeout=300, check=False,
                              env={**os.environ, "COLUMNS": str(columns)})  # fmt: skip
        assert proc.returncode in (0, 1), proc.stderr
        return proc.stdout.splitlines()

    narrow = run(80)
    assert all(len(line) <= 80 for line in narrow[2:]), narrow  # the hint and reason: one line each
    assert "time_budget" not in narrow and not any("┃" in line for line in narrow), narrow
    heads = [line for line in narrow if re.fullmatch(r"[\w-]+: \w+(?: \(.*\))?, \d+ s", line)]
    ssim = [m for line in narrow for m in re.findall(r"SSIM min (\S+);", line)]
    assert heads and len(ssim) == len(heads) and all(re.fullmatch(r"\d\.\d{4}", v) for v in ssim), narrow
    wide = run(250)
    assert any(line.startswith("┃ candidate ") for line in wide), wide
