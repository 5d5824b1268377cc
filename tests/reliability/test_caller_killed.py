"""`ppd poison` killed outright (SIGKILL to its own pid only, as the OOM killer or `kill -9 PID` does;
the kill loops kill the whole process group): its forkserver, workers and resource tracker end too,
and the forkserver's pymp-* folder does not stay in the temporary folder (poisoner.pool_exit)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import PIL.Image
import pytest

from testkit.kill_loops import REPO, running_processes


def _descendants(pid: int) -> set[int]:
    tree: dict[int, list[int]] = {}
    for child, (parent, _) in running_processes().items():
        tree.setdefault(parent, []).append(child)
    found, todo = set(), [pid]
    while todo:
        for child in tree.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def _running(pids: set[int]) -> set[int]:
    return pids & running_processes().keys()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the forkserver and /proc are Linux's")
def test_sigkilled_ppd_poison_leaves_no_worker_running_and_no_pymp_folder(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    photos = tmp_path / "shoot"
    photos.mkdir()
    rng = np.random.default_rng(0)
    for i in range(24):  # noise photos: slow enough to be mid-batch when killed
        noise = rng.integers(0, 256, (900, 1200, 3), dtype=np.uint8)
        PIL.Image.fromarray(noise).save(photos / f"p{i:02d}.png")
    # A short temporary folder of its own: the forkserver's socket path must fit in 107 bytes
    # (under a longer one ppd uses "spawn" and there is no pymp-* folder to test).
    with tempfile.TemporaryDirectory(dir="/tmp" if Path("/tmp").is_dir() else None) as tmp:
        env = {**os.environ, "TMPDIR": tmp, "PYTHONUNBUFFERED": "1"}
        exe = Path(sys.executable).parent / "ppd"
        command = [str(exe)] if exe.exists() else [sys.executable, "-m", "daemon.cli"]
        proc = subprocess.Popen([*command, "poison", str(photos), "-j", "2"], env=env, cwd=REPO,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        started: set[int] = set()
        try:
            deadline = time.monotonic() + 60
            while len(started) < 4 and proc.poll() is None and time.monotonic() < deadline:
                started = _descendants(proc.pid)  # forkserver, its two workers, resource tracker
                time.sleep(0.02)
            assert len(started) >= 4 and proc.poll() is None, f"no pool seen running ({started})"
            assert list(Path(tmp).glob("pymp-*")), "the forkserver's folder was not made"
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(30)
            deadline = time.monotonic() + 30
            while (_running(started) or list(Path(tmp).glob("pymp-*"))) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert not _running(started), "processes of the killed ppd still running"
            assert not list(Path(tmp).glob("pymp-*")), "the killed ppd's pymp-* folder stayed"
        finally:
            for pid in _running(started | {proc.pid}):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)


def test_a_killed_verification_leaves_its_folder_to_the_next_ppd_only(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd verify P --clean C` without --out works in a ppd-verify-* folder of the temporary folder;
    killed outright, it stays there until the next ppd that makes one sweeps it."""
    rng = np.random.default_rng(1)
    for side, count in (("clean", 6), ("patched", 6), ("other", 5)):
        (tmp_path / side).mkdir()
        for i in range(count):
            noise = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
            PIL.Image.fromarray(noise).save(tmp_path / side / f"v{i}.png")
    exe = Path(sys.executable).parent / "ppd"
    command = [str(exe)] if exe.exists() else [sys.executable, "-m", "daemon.cli"]
    tmp = tmp_path / "t"
    tmp.mkdir()
    env = {**os.environ, "TMPDIR": str(tmp)}
    verify = [*command, "verify"]
    quiet = subprocess.DEVNULL
    proc = subprocess.Popen([*verify, str(tmp_path / "patched"), "--clean", str(tmp_path / "clean")],
                            env=env, cwd=REPO, stdout=quiet, stderr=quiet)  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while (
            not list(tmp.glob("ppd-verify-*/*.lock")) and proc.poll() is None and time.monotonic() < deadline
        ):
            time.sleep(0.02)
        assert proc.poll() is None, "the verification ended before it could be killed"
        time.sleep(0.5)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    (left,) = tmp.glob("ppd-verify-*")  # what the killed run left
    # The next verification (of mismatched folders: refused at once) sweeps it, and removes its own.
    refused = subprocess.run([*verify, str(tmp_path / "other"), "--clean", str(tmp_path / "clean")],
                             env=env, cwd=REPO, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert not left.exists() and list(tmp.iterdir()) == []
