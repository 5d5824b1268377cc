"""SfM child process: real pycolmap on the synthetic scene, and the crash/timeout/cancel paths
with real child processes (a real interpreter stand-in that dies of a real signal)."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from verifier import poses as pm
from verifier.sfm import SfmJob, SfmSettings, run_sfm_job
from verifier.synthetic import SyntheticOptions, render_scene


def fake_python(tmp_path: Path, body: str) -> str:
    """An executable that stands in for the interpreter: lets a test make the child die for real."""
    path = tmp_path / "fake-python"
    path.write_text("#!/bin/sh\n" + body + "\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return str(path)


def job_in(tmp_path: Path) -> SfmJob:
    return SfmJob(str(tmp_path / "img"), str(tmp_path / "cache.db"), str(tmp_path / "model"))


def test_segfaulting_child_is_an_outcome_not_a_crash(tmp_path: Path) -> None:
    result = run_sfm_job(job_in(tmp_path), python=fake_python(tmp_path, "cat >/dev/null; kill -SEGV $$"))
    assert result["outcome"] == "sfm_crashed"
    assert result["signal"] == "SIGSEGV"
    assert result["returncode"] < 0


def test_abort_is_recorded_with_its_signal(tmp_path: Path) -> None:
    result = run_sfm_job(job_in(tmp_path), python=fake_python(tmp_path, "cat >/dev/null; kill -ABRT $$"))
    assert (result["outcome"], result["signal"]) == ("sfm_crashed", "SIGABRT")


def test_timeout_kills_the_child(tmp_path: Path) -> None:
    result = run_sfm_job(job_in(tmp_path), timeout_s=0.5, python=fake_python(tmp_path, "exec sleep 60"))
    assert result["outcome"] == "timeout"
    assert result["elapsed_s"] < 15
    assert result["returncode"] is not None  # reaped: the child is gone


def test_cancel_kills_the_child(tmp_path: Path) -> None:
    cancel = threading.Event()
    threading.Timer(0.5, cancel.set).start()
    t = time.monotonic()
    result = run_sfm_job(job_in(tmp_path), cancel=cancel, python=fake_python(tmp_path, "exec sleep 60"))
    assert result["outcome"] == "cancelled"
    assert time.monotonic() - t < 15


def test_child_without_result_is_a_failure(tmp_path: Path) -> None:
    result = run_sfm_job(
        job_in(tmp_path), python=fake_python(tmp_path, "cat >/dev/null; echo boom >&2; exit 3")
    )
    assert result["outcome"] == "failed"
    assert "boom" in result["error"]


def test_child_runs_at_low_priority() -> None:
    code = "from verifier.child import lower_priority; import os; lower_priority(); print(os.nice(0))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])  # fmt: skip
    assert int(out.stdout.strip()) >= os.nice(0) + 10 or int(out.stdout.strip()) == 19


def test_missing_images_fail_cleanly_in_the_child(tmp_path: Path) -> None:
    (tmp_path / "img").mkdir()
    result = run_sfm_job(job_in(tmp_path), timeout_s=120)
    assert result["outcome"] in ("failed", "ok")
    if result["outcome"] == "ok":  # pycolmap may simply find nothing to reconstruct
        assert result["registered"] == 0


@pytest.mark.integration
def test_clean_sfm_recovers_synthetic_cameras(tmp_path: Path) -> None:
    options = SyntheticOptions(num_views=10)
    gt = render_scene(tmp_path / "img", options)
    result = run_sfm_job(job_in(tmp_path), timeout_s=300)
    assert result["outcome"] == "ok", result.get("error")
    assert result["registered"] == 10
    assert result["model_sizes"][0] == 10  # COLMAP may add a small overlapping second model
    assert result["mean_reprojection_error"] < 1.0
    m = pm.compare_poses(pm.poses_from_json(result["poses"]), gt)
    assert m["frac_within_5deg"] == 1.0
    assert m["median_rotation_error_deg"] < 1.0
    assert m["median_centre_error"] < 0.02
    assert (tmp_path / "model" / "images.bin").is_file()  # the model is kept for reports


@pytest.mark.integration
def test_known_intrinsics_are_kept_fixed(tmp_path: Path) -> None:
    options = SyntheticOptions(num_views=8)
    render_scene(tmp_path / "img", options)
    job = SfmJob(str(tmp_path / "img"), str(tmp_path / "c.db"), str(tmp_path / "model"),
                 SfmSettings(camera_params="384,384,160,160,0,0,0,0"))  # fmt: skip
    result = run_sfm_job(job, timeout_s=300)
    assert result["outcome"] == "ok", result.get("error")
    assert result["camera"]["params"][:4] == [384.0, 384.0, 160.0, 160.0]
