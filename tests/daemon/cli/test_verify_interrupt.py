"""Ctrl-C during `ppd verify` ends it at once with one line: the running COLMAP children are ended,
no side still queued starts, and the run's folder (no report in it) is removed. Before, the pool
waited for every side still to run (16-41 s of silence on 12 small photos) and typer turned the
interrupt into a silent exit 130. A real `ppd` process, a real signal, real SfM children."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app

REPO = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_ctrl_c_ends_a_verification_at_once_and_leaves_no_run_behind(
    ppd_env: dict[str, Path], tmp_path: Path, how: str
) -> None:
    """sigterm: `kill PID`, `timeout`, `systemctl stop` (a second black-box review: status 143, no
    line, the run's folder left behind)."""
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    base = np.random.default_rng(7).integers(0, 256, (480, 1200, 3), dtype=np.uint8)
    for i in range(10):  # views of one textured wall: every COLMAP stage has work for a while
        Image.fromarray(base[:, 40 * i : 40 * i + 640]).save(shoot / f"view{i}.png")
    assert CliRunner().invoke(app, ["poison", str(shoot)]).exit_code == 0
    runs = ppd_env["data"] / "runs" / "shoot"
    env = dict(os.environ, PYTHONPATH=str(REPO), PPD_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.Popen([sys.executable, "-m", "daemon.cli", "verify", "shoot", "--profile", "all"],
                            env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while not list(runs.glob("**/sfm.log")):  # the moment: an SfM child is at work
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.5)
    sent = time.monotonic()
    if how == "ctrl-c":
        os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C: the foreground group (not the children's)
    else:
        os.kill(proc.pid, signal.SIGTERM)
    out, err = proc.communicate(timeout=300)
    waited = time.monotonic() - sent

    assert proc.returncode == 130, (out, err)
    assert err.strip().splitlines()[-1] == "ppd: interrupted", err
    assert "Traceback" not in err
    # the children get SIGTERM, then SIGKILL after 3 s: never the rest of the verification
    assert waited < 10, f"{waited:.1f} s after Ctrl-C"
    assert [p.name for p in runs.iterdir() if not p.name.startswith(".")] == []  # no half run
    assert not (runs / ".verifying.json").exists()  # status says no verification is running
    # the feature children it killed left their databases in the clean cache: the next run removes them
    cache = runs / ".clean-cache"
    from verifier.shared_sfm import clean_cache_for

    for key in [p.name for p in cache.iterdir() if p.is_dir()] if cache.is_dir() else []:
        clean_cache_for(cache, key, keep=3)
        assert not [p.name for p in (cache / key).glob(".ppd-tmp-*")], list((cache / key).iterdir())


def test_an_error_in_a_verification_leaves_the_callers_cancel_event_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Only Ctrl-C sets the cancel event: the daemon's scheduler passes its own long-lived one, and a
    failed verification (a full disk) that set it cancelled every later one until a restart (a diff
    review)."""
    import threading

    from verifier import verification
    from verifier.verification import VerifyOptions, verify_folders

    clean, patched = tmp_path / "clean", tmp_path / "patched"
    clean.mkdir(), patched.mkdir()
    for i in range(3):
        Image.new("RGB", (64, 48), (i * 40, 90, 90)).save(clean / f"v{i}.png")
        Image.new("RGB", (64, 48), (i * 40, 90, 91)).save(patched / f"v{i}.png")

    def full_disk(*_args: object) -> dict:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(verification, "_run_planned_side", full_disk)
    event = threading.Event()
    options = VerifyOptions(cancel=event, visibility_images=0)
    with pytest.raises(OSError, match="No space left"):
        verify_folders(clean, patched, tmp_path / "out", ("default",), options)
    assert not event.is_set()
