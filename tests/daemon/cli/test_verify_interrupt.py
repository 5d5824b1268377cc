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
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app

REPO = Path(__file__).resolve().parents[3]


def test_ctrl_c_ends_a_verification_at_once_and_leaves_no_run_behind(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
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
    os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C: the foreground group (not the children's)
    out, err = proc.communicate(timeout=300)
    waited = time.monotonic() - sent

    assert proc.returncode == 130, (out, err)
    assert err.strip().splitlines()[-1] == "ppd: interrupted", err
    assert "Traceback" not in err
    # the children get SIGTERM, then SIGKILL after 3 s: never the rest of the verification
    assert waited < 10, f"{waited:.1f} s after Ctrl-C"
    assert [p.name for p in runs.iterdir() if not p.name.startswith(".")] == []  # no half run
