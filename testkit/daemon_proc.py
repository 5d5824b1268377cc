"""`ppd watch` as a real process: started with its folders under one root and a systemd-style
notify socket (it returns once READY=1 arrives), stopped with SIGTERM, its /proc status read;
and a polling wait for what a daemon (a process or in this one) is expected to do."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


@dataclass
class Daemon:
    proc: subprocess.Popen[bytes]
    sock: socket.socket
    log: Path

    @property
    def pid(self) -> int:
        return self.proc.pid


def start_daemon(root: Path, *args: str, log_dir: Path | None = None, outbox: Path | None = None) -> Daemon:
    """`ppd watch` with its folders under root (its outbox root/outbox unless given: an outbox moved
    elsewhere); its stdout/stderr go to a log in log_dir (root when not given: a test that fills root's
    filesystem passes another, or the log loses lines)."""
    env = dict(os.environ)
    env.update(
        PPD_DATA_DIR=str(root / "data"), PPD_CONFIG_DIR=str(root / "config"),
        PPD_OUTBOX=str(outbox or root / "outbox"), PPD_CACHE_DIR=str(root / "cache"),
        NOTIFY_SOCKET=str(root / "notify.sock"),
        # this checkout's code, whichever one the venv's `ppd` was installed from (an editable
        # install points at one checkout; a test in another ran that one's daemon: a helper's note)
        PYTHONPATH=str(REPO),
    )  # fmt: skip
    sock_path = root / "notify.sock"
    sock_path.unlink(missing_ok=True)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    sock.settimeout(60)
    exe = Path(sys.executable).parent / "ppd"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "daemon.cli"]
    log = (log_dir or root) / f"daemon-{time.monotonic_ns()}.log"
    with open(log, "wb") as fh:
        proc = subprocess.Popen(
            [*cmd, "watch", *args], env=env, cwd=REPO, stdout=fh, stderr=subprocess.STDOUT
        )
    while not sock.recv(4096).startswith(b"READY=1"):
        pass
    # Keep reading, as systemd does: STATUS= updates arrive after every file.
    threading.Thread(target=_drain, args=(sock,), daemon=True).start()
    return Daemon(proc, sock, log)


def _drain(sock: socket.socket) -> None:
    sock.settimeout(None)
    with contextlib.suppress(OSError):
        while sock.recv(4096):
            pass


def stop_daemon(daemon: Daemon) -> float:
    started = time.monotonic()
    daemon.proc.terminate()
    code = daemon.proc.wait(60)
    with contextlib.suppress(OSError):
        daemon.sock.shutdown(socket.SHUT_RDWR)  # wakes the drain thread
    daemon.sock.close()
    if code != 0:
        raise RuntimeError(f"ppd watch exited {code}; see {daemon.log}")
    return time.monotonic() - started


def status_kb(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def wait_for(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")
