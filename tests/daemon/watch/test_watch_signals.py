"""A stop signal delivered twice is one request (a black-box review: `timeout 20 ppd watch` signals the
daemon and its process group; the daemon left at once, without its "stopped:" line, leaked its pool's
semaphores, abandoned the file in flight, and the next start warned that ppd had died while patching).
Real `ppd watch` processes, real files."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

from testkit.daemon_proc import start_daemon
from testkit.reliability import DAEMON_ARGS, app_paths, make_media, wait_for


def _children(pid: int) -> list[int]:
    found = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout.split()
    return [int(p) for p in found]


def test_sigterm_to_the_daemon_and_its_group_twice_stops_it_once_and_cleanly(tmp_path: Path) -> None:
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)
    shoot = app_paths(tmp_path).outbox / "shoot"
    shoot.mkdir(parents=True)
    for i in range(12):
        make_media(shoot / f"v{i}.png", seed=i, size=2400)
    wait_for(lambda: _children(daemon.proc.pid) != [], 30, "work in flight")
    for _ in range(2):  # what `timeout` does: the daemon, then its whole group (the workers too)
        for pid in [daemon.proc.pid, *_children(daemon.proc.pid)]:
            os.kill(pid, signal.SIGTERM)
        time.sleep(0.05)
    assert daemon.proc.poll() is None  # still finishing the files in flight (no exit at once)
    assert daemon.proc.wait(120) == 0
    daemon.sock.close()
    said = daemon.log.read_text()
    assert "stopped:" in said and "leaked semaphore" not in said and "stopping at once" not in said, said
    again = start_daemon(tmp_path, *DAEMON_ARGS)
    time.sleep(1.0)
    again.proc.send_signal(signal.SIGTERM)
    assert again.proc.wait(120) == 0
    again.sock.close()
    assert "died while patching" not in again.log.read_text(), again.log.read_text()
