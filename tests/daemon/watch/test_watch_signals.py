"""A stop signal sent to the whole process group (`timeout`, `kill -- -PGID`), and delivered twice, is one
request (a black-box review and a diff review: `timeout 20 ppd watch` left at once without its "stopped:"
line, leaking its pool's semaphores and abandoning the file in flight, and the next start warned that ppd
had died while patching; a group SIGTERM to `ppd poison` killed its forkserver and with it the workers
mid-file). Real `ppd watch` and `ppd poison` processes in a session of their own, real files."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from testkit.daemon_proc import start_daemon, wait_for
from testkit.reliability import DAEMON_ARGS, app_paths, make_media, subprocess_env


def _children(pid: int) -> list[int]:
    found = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout.split()
    return [int(p) for p in found]


def _ppd_in_own_session(root: Path, log: Path, *args: str) -> subprocess.Popen[bytes]:
    with open(log, "wb") as fh:
        return subprocess.Popen([sys.executable, "-m", "daemon.cli", *args], env=subprocess_env(root),
                                stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip


def _group_sigterm_twice(proc: subprocess.Popen[bytes]) -> None:
    for _ in range(2):  # `timeout` signals the child, then the group; the second is the same request
        os.killpg(proc.pid, signal.SIGTERM)
        time.sleep(0.05)


def test_a_group_sigterm_twice_stops_the_daemon_once_and_cleanly(tmp_path: Path) -> None:
    log = tmp_path / "watch.log"
    daemon = _ppd_in_own_session(tmp_path, log, "watch", *DAEMON_ARGS)
    wait_for(lambda: "ready" in log.read_text(), 60, "the daemon to start")
    shoot = app_paths(tmp_path).outbox / "shoot"
    shoot.mkdir(parents=True)
    for i in range(12):
        make_media(shoot / f"v{i}.png", seed=i, size=2400)
    wait_for(lambda: _children(daemon.pid) != [], 30, "work in flight")
    _group_sigterm_twice(daemon)
    assert daemon.wait(120) == 0, log.read_text()
    said = log.read_text()
    assert "stopped:" in said and "leaked semaphore" not in said and "stopping at once" not in said, said
    again = start_daemon(tmp_path, *DAEMON_ARGS)
    time.sleep(1.0)
    again.proc.send_signal(signal.SIGTERM)
    assert again.proc.wait(120) == 0
    again.sock.close()
    assert "died while patching" not in again.log.read_text(), again.log.read_text()


def test_a_group_sigterm_to_ppd_poison_finishes_the_files_in_flight(tmp_path: Path) -> None:
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    for i in range(16):
        make_media(shoot / f"v{i}.png", seed=i, size=1600)
    log = tmp_path / "poison.log"
    run = _ppd_in_own_session(tmp_path, log, "poison", str(shoot), "--workers", "2")
    wait_for(lambda: len(_children(run.pid)) >= 2, 60, "the workers")
    time.sleep(1.0)
    _group_sigterm_twice(run)
    assert run.wait(120) == 130, log.read_text()  # interrupted: what it did not reach is said
    attempts = tmp_path / "data" / "attempts"
    left = [p for p in attempts.rglob("*") if p.is_file()] if attempts.exists() else []
    assert left == [], left  # no file abandoned mid-patch (an attempt marker names one)
    resumed = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "poison", str(shoot)], env=subprocess_env(tmp_path),
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert resumed.returncode == 0 and "failed 0" in resumed.stdout, resumed.stdout + resumed.stderr


@pytest.mark.integration  # a minute of real daemon work: opt-in (`make test-all`)
def test_a_second_stop_later_leaves_at_once_and_is_no_crash_at_the_next_start(tmp_path: Path) -> None:
    """A second Ctrl-C after the first leaves at once (files in flight finished at the next start); the
    next start said "ppd died while patching" of each and ran it isolated (black-box review 9, F9)."""
    from daemon.cli.interrupt import SAME_STOP_S

    log = tmp_path / "watch.log"
    daemon = _ppd_in_own_session(tmp_path, log, "watch", *DAEMON_ARGS)
    wait_for(lambda: "ready" in log.read_text(), 60, "the daemon to start")
    shoot = app_paths(tmp_path).outbox / "shoot"
    shoot.mkdir(parents=True)
    for i in range(4):  # minutes of work for the daemon: still in flight at the second stop
        make_media(shoot / f"v{i}.png", seed=i, size=6000)
    attempts = tmp_path / "data" / "attempts"
    wait_for(lambda: attempts.is_dir() and any(attempts.glob("*.json")), 60, "a file in flight")
    daemon.send_signal(signal.SIGINT)
    time.sleep(SAME_STOP_S + 0.5)
    daemon.send_signal(signal.SIGINT)
    code = daemon.wait(120)
    said = log.read_text()
    assert code == 130 and "stopping at once" in said, said
    again = start_daemon(tmp_path, *DAEMON_ARGS)
    wait_for(lambda: "catch-up scan" in again.log.read_text(), 60, "the catch-up scan")
    again.proc.send_signal(signal.SIGTERM)
    assert again.proc.wait(120) == 0
    again.sock.close()
    assert "died while patching" not in again.log.read_text(), again.log.read_text()
