"""Experiment harness (issue 7): sweep parsing, the grid, poisoned copies, cost2, resumable results,
the paper-layout tables; integration: a real sweep (real COLMAP) on the synthetic scene."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from poisoner.baselines import BaselineSpec
from poisoner.spec import PatchSpec
from verifier import experiment as ex

ROOT = Path(__file__).resolve().parents[2]


# ---- parsing and the grid -----------------------------------------------------------------------
def test_parse_sweep_values_and_aliases() -> None:
    assert ex.parse_sweep("patch_size=12,48,100") == ("patch_size", [12, 48, 100])
    assert ex.parse_sweep("b=2,4") == ("block_size", [2, 4])
    assert ex.parse_sweep("P=0.06") == ("patch_size", [0.06])  # a fraction of the width
    assert ex.parse_sweep("alpha=0.1,1") == ("alpha", [0.1, 1.0])
    assert ex.parse_sweep("pattern=checkerboard,circles") == ("pattern", ["checkerboard", "circles"])


@pytest.mark.parametrize("bad", ["patch_size", "colour=1,2", "alpha=", "contrast=high"])
def test_bad_sweep_is_one_clear_line(bad: str) -> None:
    with pytest.raises(ex.ExperimentError) as info:
        ex.parse_sweep(bad)
    assert "\n" not in str(info.value) and str(info.value)


def test_parse_baseline() -> None:
    assert ex.parse_baseline("blur=3,11") == [BaselineSpec("blur", 3), BaselineSpec("blur", 11)]
    assert ex.parse_baseline("shear-x=0.2") == [BaselineSpec("shear", 0.2, axis="x")]
    with pytest.raises(ex.ExperimentError):
        ex.parse_baseline("blur=4")  # even kernel
    with pytest.raises(ex.ExperimentError):
        ex.parse_baseline("sharpen=1")


def test_grid_is_one_parameter_at_a_time_and_shares_the_base() -> None:
    sweeps = [ex.parse_sweep(s) for s in ("patch_size=12,48,100", "block=2,4,8", "alpha=0.1,1")]
    settings = ex.build_settings(sweeps, ex.DEFAULT_BASELINES)
    labels = [s.label for s in settings]
    assert len(labels) == len(set(labels))
    # clean + P{12,48,100} + b{2,8} + a{0.1} (P=100 b=4 a=1 is one setting) + 4 baselines
    assert len(settings) == 1 + 3 + 2 + 1 + 4
    base = next(s for s in settings if s.patch == ex.BASE_PATCH)
    assert set(base.groups) == {"patch_size", "block_size", "alpha"}
    p12 = next(s for s in settings if s.patch is not None and s.patch.patch_size == 12)
    assert (p12.patch.block_size, p12.patch.alpha) == (4, 1.0)  # the rest stays at the base
    assert [s.kind for s in settings].count("baseline") == 4


def test_setting_id_is_stable_and_ignores_the_seed() -> None:
    a = ex.Setting("patch", "x", patch=PatchSpec(patch_size=12, block_size=4))
    assert a.setting_id == a.with_seed(3).setting_id
    assert a.setting_id != ex.Setting("patch", "x", patch=PatchSpec(patch_size=13, block_size=4)).setting_id
    b = ex.Setting("baseline", "blur", baseline=BaselineSpec("blur", 11))
    assert b.with_seed(2).baseline.seed == 2 and b.with_seed(2).setting_id == b.setting_id


# ---- poisoned copies and cost2 ------------------------------------------------------------------
def _scene(folder: Path, n: int = 4, size: int = 160) -> Path:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(n):
        Image.fromarray(rng.integers(0, 256, (size, size, 3), dtype=np.uint8)).save(folder / f"v{i}.png")
    return folder


def test_patch_copy_changes_only_the_patch(tmp_path: Path) -> None:
    clean = _scene(tmp_path / "clean")
    spec = PatchSpec(patch_size=24, block_size=4)
    changed = ex.make_poisoned_copy(clean, tmp_path / "p", ex.Setting("patch", "p", patch=spec))
    assert changed == 4
    x0, y0, x1, y1 = spec.resolve(160, 160).box
    for name in ex.image_names(clean):
        a = np.asarray(Image.open(clean / name)).astype(int)
        b = np.asarray(Image.open(tmp_path / "p" / name)).astype(int)
        outside = np.ones(a.shape[:2], bool)
        outside[y0:y1, x0:x1] = False
        assert np.array_equal(a[outside], b[outside])
        assert not np.array_equal(a[~outside], b[~outside])


def test_ratio_and_baseline_copies(tmp_path: Path) -> None:
    clean = _scene(tmp_path / "clean", n=12)
    spec = PatchSpec(patch_size=24, block_size=4, ratio=0.5, seed=1)
    changed = ex.make_poisoned_copy(clean, tmp_path / "r", ex.Setting("patch", "r", patch=spec))
    expected = [n for n in ex.image_names(clean) if spec.selects(n)]
    assert changed == len(expected) and 0 < changed < 12
    for name in ex.image_names(clean):
        same = (clean / name).read_bytes() == (tmp_path / "r" / name).read_bytes()
        assert same == (name not in expected)
    blur = ex.Setting("baseline", "blur", baseline=BaselineSpec("blur", 11))
    assert ex.make_poisoned_copy(clean, tmp_path / "b", blur) == 12
    a = np.asarray(Image.open(clean / "v0.png")).astype(float)
    b = np.asarray(Image.open(tmp_path / "b" / "v0.png")).astype(float)
    assert b.std() < a.std()  # blurred noise loses contrast everywhere


def test_cost2_reproduces_the_papers_psnr_on_white(tmp_path: Path) -> None:
    clean = tmp_path / "clean"
    clean.mkdir()
    for i in range(3):
        Image.fromarray(np.full((800, 800, 3), 255, np.uint8)).save(clean / f"w{i}.png")
    setting = ex.Setting("patch", "p12", patch=PatchSpec(patch_size=12, block_size=4, alpha=1.0))
    ex.make_poisoned_copy(clean, tmp_path / "p", setting)
    c = ex.cost2(clean, tmp_path / "p", lpips_net=None)
    assert abs(c["psnr"] - 39.03) < 0.05  # PAPER.md: P=12 -> 39.03 dB
    assert 0.999 < c["ssim"] < 1.0 and c["images"] == 3 and c["lpips"] is None
    same = ex.cost2(clean, clean, lpips_net=None)
    assert same["ssim"] == 1.0 and same["psnr"] == math.inf and same["psnr_identical"] == 3


def test_cost2_lpips_on_a_sample(tmp_path: Path) -> None:
    from verifier.lpips import lpips_available

    ok, reason = lpips_available("alex")
    if not ok:
        pytest.skip(reason)
    clean = _scene(tmp_path / "clean", n=5, size=96)
    ex.make_poisoned_copy(
        clean, tmp_path / "p", ex.Setting("baseline", "n", baseline=BaselineSpec("noise", 25))
    )
    c = ex.cost2(clean, tmp_path / "p", lpips_net="alex", lpips_images=2)
    assert c["lpips_images"] == 2 and c["images"] == 5 and c["lpips"] > 0
    assert ex.evenly_spaced(["a", "b", "c", "d", "e"], 3) == ["a", "c", "e"]


# ---- resumable results --------------------------------------------------------------------------
class Interrupted(Exception):
    pass


def _fake_run_factory(calls: list[tuple[str, int]], die_after: int | None = None):
    """A stand-in for run_setting's SfM work (minutes per setting with real COLMAP; the real one runs
    in the integration test below): deterministic numbers from the setting, and a crash on demand."""

    def run(setting: ex.Setting, run: int, clean: Path, exp_dir: Path, options: ex.ExperimentOptions):
        if die_after is not None and len(calls) >= die_after:
            raise Interrupted
        calls.append((setting.setting_id, run))
        value = 0.9 - 0.01 * len(setting.label) - 0.05 * run
        return {"setting_id": setting.setting_id, "config_id": options.config_id(), "run": run,
                "kind": setting.kind, "label": setting.label, "groups": list(setting.groups),
                "params": setting.params(), "cost2": {"ssim": value, "psnr": 30.0 + run, "lpips": 0.01},
                "within5_of_clean": 0.1 * run, "verdict": "protected"}  # fmt: skip

    return run


def test_killed_sweep_continues_where_it_stopped(tmp_path: Path) -> None:
    clean = _scene(tmp_path / "clean")
    settings = ex.build_settings([ex.parse_sweep("patch_size=12,48")], [BaselineSpec("blur", 3)])
    options = ex.ExperimentOptions(runs=2)
    calls: list[tuple[str, int]] = []
    with pytest.raises(Interrupted):
        ex.run_experiment(clean, tmp_path / "exp", settings, options, run_fn=_fake_run_factory(calls, 3))
    first = list(calls)
    assert len(ex.load_rows(tmp_path / "exp" / ex.RESULTS_NAME)) == 3  # each row saved as it finished
    with open(tmp_path / "exp" / ex.RESULTS_NAME, "a") as f:
        f.write('{"setting_id": "torn')  # a kill in the middle of a write
    result = ex.run_experiment(clean, tmp_path / "exp", settings, options, run_fn=_fake_run_factory(calls))
    assert result.skipped == 3 and result.ran == len(settings) * 2 - 3
    assert not set(first) & set(calls[3:])  # nothing recomputed
    assert sorted(calls) == sorted({(s.setting_id, r) for s in settings for r in range(2)})
    again = ex.run_experiment(clean, tmp_path / "exp", settings, options, run_fn=_fake_run_factory(calls))
    assert again.ran == 0
    # another configuration does not reuse these rows
    other = ex.ExperimentOptions(runs=1, profiles=("hardened",))
    assert (
        len(ex.pending(settings, 1, ex.load_rows(tmp_path / "exp" / ex.RESULTS_NAME), other.config_id())) == 4
    )


def test_tables_show_mean_and_std_over_runs(tmp_path: Path) -> None:
    clean = _scene(tmp_path / "clean")
    settings = ex.build_settings([ex.parse_sweep("patch_size=12,48")], [BaselineSpec("blur", 3)])
    options = ex.ExperimentOptions(runs=3)
    result = ex.run_experiment(clean, tmp_path / "exp", settings, options, run_fn=_fake_run_factory([]))
    label = next(s.label for s in settings if s.patch is not None and s.patch.patch_size == 12)
    values = [0.9 - 0.01 * len(label) - 0.05 * r for r in range(3)]
    expected = f"{statistics.fmean(values):.4f} ± {statistics.stdev(values):.4f}"
    md = result.table_path.read_text()
    line = next(x for x in md.splitlines() if x.startswith(f"| {label} |"))
    assert expected in line and "| 3 |" in line
    assert "### Patch size P" in md and "### Baselines" in md
    assert "render SSIM" in md and "clean-vs-poisoned SSIM" in md
    rows = list(csv.DictReader(io.StringIO(result.csv_path.read_text())))
    assert len(rows) == len(settings) * 3
    got = sorted(float(r["cost2_ssim"]) for r in rows if r["label"] == label)
    assert got == pytest.approx(sorted(values))


def test_too_few_images_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "one").mkdir()
    with pytest.raises(ex.ExperimentError, match="at least 3 images"):
        ex.run_experiment(tmp_path / "one", tmp_path / "exp", [], ex.ExperimentOptions())


# ---- the command ------------------------------------------------------------------------------
def test_cli_bad_sweep_is_one_line_exit_2(tmp_path: Path, ppd_env: dict[str, Path]) -> None:
    from typer.testing import CliRunner

    from daemon.cli import app

    _scene(tmp_path / "clean")
    result = CliRunner().invoke(app, ["experiment", str(tmp_path / "clean"), "--sweep", "colour=1"])
    assert result.exit_code == 2
    assert "unknown sweep parameter" in result.output
    result = CliRunner().invoke(app, ["experiment", str(tmp_path / "nowhere"), "--baselines"])
    assert result.exit_code == 2 and "not a folder" in result.output



def test_cli_unknown_dataset_is_said_first(tmp_path: Path, ppd_env: dict[str, Path]) -> None:
    """`ppd experiment nosuch` said "nothing to run: give --sweep ..." and never that there is no dataset
    'nosuch' (a black-box review, F11): the dataset is judged before the other arguments."""
    from typer.testing import CliRunner

    from daemon.cli import app

    for args in ([], ["--sweep", "colour=1"]):
        result = CliRunner().invoke(app, ["experiment", "nosuch", *args])
        lines = result.output.splitlines()
        assert result.exit_code == 2 and len(lines) == 1, result.output
        assert lines[0].startswith("ppd: error: nosuch: not a dataset, not a folder of images"), lines


# ---- real COLMAP --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def synthetic_clean(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from verifier.synthetic import SyntheticOptions, render_scene

    root = tmp_path_factory.mktemp("exp-synthetic")
    render_scene(root / "clean", SyntheticOptions(num_views=12), gt_path=root / "gt.json")
    return {"clean": root / "clean", "gt": root / "gt.json"}


@pytest.mark.integration
def test_real_setting_row(synthetic_clean: dict[str, Path], tmp_path: Path) -> None:
    """One patch setting end to end: poisoned copy -> real COLMAP (default profile) -> a row."""
    options = ex.ExperimentOptions(ground_truth=synthetic_clean["gt"], sfm_timeout_s=300, cost2_lpips=False)
    setting = ex.Setting("patch", "default", patch=PatchSpec(), groups=("patch_size",))
    row = ex.run_setting(setting, 0, synthetic_clean["clean"], tmp_path, options)
    assert "error" not in row, row.get("error")
    assert row["clean_registered"] == 12 and row["images_changed"] == 12
    assert row["verdict"] in ("protected", "weak", "not_protected", "sfm_crashed")
    if row["poisoned_outcome"] == "ok":
        assert 0.0 <= row["within5_of_clean"] <= 1.0
    assert 20 < row["cost2"]["psnr"] < 60 and row["cost2"]["ssim"] < 1
    assert (Path(row["profiles"]["default"]["model_dir"]) / "clean" / "result.json").is_file()


@pytest.mark.integration
@pytest.mark.slow
def test_real_sweep_killed_and_resumed(synthetic_clean: dict[str, Path], tmp_path: Path) -> None:
    """A real sweep process is SIGKILLed after its first row; rerunning finishes without redoing it."""
    exp = tmp_path / "exp"
    script = (
        "import sys; from pathlib import Path; from verifier import experiment as ex;"
        "s = ex.build_settings([ex.parse_sweep('patch_size=0.06,0.1')], include_clean=False);"
        f"o = ex.ExperimentOptions(ground_truth=Path({str(synthetic_clean['gt'])!r}), cost2_lpips=False);"
        f"ex.run_experiment(Path({str(synthetic_clean['clean'])!r}), Path({str(exp)!r}), s, o)"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", script], env=env, start_new_session=True)
    results = exp / ex.RESULTS_NAME
    deadline = time.time() + 900
    while time.time() < deadline and not (results.is_file() and results.read_text().count("\n") >= 1):
        time.sleep(1)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    first = ex.load_rows(results)
    assert len(first) == 1
    subprocess.run([sys.executable, "-c", script], env=env, check=True, timeout=900)
    rows = ex.load_rows(results)
    assert len(rows) == 2 and rows[0] == first[0]
    assert json.loads(json.dumps(rows[1]))["setting_id"] != first[0]["setting_id"]


def _row(**kw: Any) -> dict[str, Any]:
    return {"setting_id": "x", "label": "x", "kind": "patch", "run": 0, **kw}


def test_stat_handles_missing_and_inf() -> None:
    assert ex.stat([None, None]).text(2) == "—"
    assert ex.stat([math.inf, 30.0]).text(2) == "inf"
    assert ex.stat([1.0]).text(1) == "1.0"
    assert ex.aggregate([_row(cost2={"ssim": 0.5}), _row(cost2={"ssim": 0.7}, run=1)])[0]["cvp_ssim"].n == 2


@pytest.mark.integration
@pytest.mark.slow
def test_cli_experiment_end_to_end(
    synthetic_clean: dict[str, Path], tmp_path: Path, ppd_env: dict[str, Path]
) -> None:
    """`ppd experiment` on a real folder: rows, CSV, Markdown, plots and a self-contained report."""
    from typer.testing import CliRunner

    from daemon.cli import app

    out = tmp_path / "exp"
    args = ["experiment", str(synthetic_clean["clean"]), "--sweep", "patch_size=0.06", "--gt",
            str(synthetic_clean["gt"]), "--lpips-images", "2", "--out", str(out)]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    rows = ex.load_rows(out / ex.RESULTS_NAME)
    assert [r["kind"] for r in rows] == ["clean", "patch"]
    assert rows[0]["within5_of_clean"] > 0.6  # clean vs a copy of itself: the noise floor
    for name in ("results.csv", "results.md", "tradeoff.png", "report.html"):
        assert (out / name).is_file(), name
    assert "data:image/png;base64," in (out / "report.html").read_text()
    again = CliRunner().invoke(app, args)  # resumable: nothing left to do
    assert again.exit_code == 0 and "0 setting-runs computed, 2 already done" in again.output


@pytest.mark.integration
@pytest.mark.slow
def test_real_setting_with_splat_has_cost1(synthetic_clean: dict[str, Path], tmp_path: Path) -> None:
    """Verifier II inside a setting: cost1 of both sides lands in the row and in the tables."""
    options = ex.ExperimentOptions(
        ground_truth=synthetic_clean["gt"], sfm_timeout_s=300, cost2_lpips=False, splat=True,
        splat_options={"long_edge": 64, "iterations": 30, "time_budget_s": 20, "cost2_long_edge": 64},
    )  # fmt: skip
    setting = ex.Setting("patch", "default", patch=PatchSpec(), groups=("patch_size",))
    row = ex.run_setting(setting, 0, synthetic_clean["clean"], tmp_path, options)
    assert row["splat_outcome"] == "ok", row.get("splat_error")
    for side in ("cost1", "cost1_clean"):
        assert 0 < row[side]["ssim"] <= 1 and row[side]["psnr"] > 0
    md = ex.markdown_tables([row])
    assert f"{row['cost1']['ssim']:.3f}" in md


def test_tables_carry_what_a_viewer_sees() -> None:
    """Each run's visibility (worst FLIP p99.9, area above 0.5) reaches the markdown and CSV tables."""
    base = {"kind": "patch", "groups": ["patch_size"], "params": {}, "verdict": "protected"}
    rows = [
        {**base, "setting_id": "a", "label": "P=12", "run": r,
         "visibility": {"flip_p999": 0.9 + 0.02 * r, "area_above_half": 0.004, "changed_area": 0.01}}
        for r in range(2)
    ] + [{**base, "setting_id": "b", "label": "P=48", "run": 0}]  # an older row: not measured  # fmt: skip
    md = ex.markdown_tables(rows)
    assert "| FLIP p99.9 | area FLIP > 0.5 |" in md
    line = next(x for x in md.splitlines() if x.startswith("| P=12 |"))
    flip = f"{statistics.fmean([0.9, 0.92]):.3f} ± {statistics.stdev([0.9, 0.92]):.3f}"
    assert f"| {flip} | 0.40% ± 0.00 |" in line
    old = next(x for x in md.splitlines() if x.startswith("| P=48 |"))
    assert old.count("| — |") >= 2
    table = list(csv.DictReader(io.StringIO(ex.csv_text(rows))))
    assert [r["area_above_half"] for r in table] == ["0.004", "0.004", ""]
    assert float(table[1]["flip_p999"]) == pytest.approx(0.92)
