"""A pool's workers end with their caller, and what multiprocessing leaves in the temporary folder goes.

A caller killed outright (SIGKILL, the OOM killer's choice of the main process) runs no clean-up.
Its pool's workers then wait for work forever: each holds the write end of its own call queue, so no
end-of-file ever reaches it, and a forkserver outlives them (they hold its liveness pipe): processes
holding a decoded photo's memory, and one that could finish an atomic replace while the next `ppd`
run recovers the same file. So each worker watches its caller (`exit_with_caller`: a pidfd, Linux
5.3+; elsewhere its parent's pid, polled) and exits at once when it ends: the state is then the one a
process-group kill leaves, which ppd's recovery handles. The forkserver's socket lives in a `pymp-*`
folder that multiprocessing removes only at a clean exit; the caller marks the folder as its own
with a lock held for its lifetime (`claim_temp_dir`), and a folder whose lock nobody holds is removed
by the worker that saw its caller end, or by the next pool's caller (`sweep_stale_temp_dirs`).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import select
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

LOCK_NAME = "ppd.lock"  # in multiprocessing's pymp-* folder: this folder is a ppd process's
POLL_S = 1.0  # where no pidfd exists: how often a worker checks its parent
_claimed: dict[str, int] = {}  # folder -> the open, locked lock file's descriptor (this process)


def claim_temp_dir() -> str:
    """multiprocessing's temporary folder for this process (made now if it is not yet), marked as
    a ppd process's by a lock held until this process ends. Stale folders of dead ppd processes
    are removed first."""
    import multiprocessing.util

    sweep_stale_temp_dirs()
    folder = multiprocessing.util.get_temp_dir()
    if folder not in _claimed:
        fd = os.open(os.path.join(folder, LOCK_NAME), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        fcntl.flock(fd, fcntl.LOCK_EX)  # released by the kernel when this process ends, however
        _claimed[folder] = fd
    return folder


def remove_if_stale(folder: str | Path) -> bool:
    """Remove a pymp-* folder of ours whose ppd process has ended (its lock is free); True if removed.
    A folder without ppd's lock, someone else's, or one still held is left alone."""
    path = Path(folder)
    if not path.name.startswith("pymp-"):
        return False
    try:
        if path.lstat().st_uid != os.getuid() or not path.is_dir():
            return False
        fd = os.open(path / LOCK_NAME, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:  # gone, not ours, or no lock file: not a ppd process's folder
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # its process is alive
        os.close(fd)
        return False
    try:
        shutil.rmtree(path, ignore_errors=True)
    finally:
        os.close(fd)
    return not path.exists()


def sweep_stale_temp_dirs(root: str | Path | None = None) -> int:
    """Remove the pymp-* folders that dead ppd processes left in root (the temporary folder)."""
    base = Path(root if root is not None else tempfile.gettempdir())
    try:
        candidates = [p for p in base.iterdir() if p.name.startswith("pymp-")]
    except OSError:
        return 0
    return sum(remove_if_stale(p) for p in candidates)


def exit_with_caller(caller: int, temp_dir: str | None) -> None:
    """In a worker: a daemon thread ends this process the moment `caller` ends, first removing the
    caller's temp_dir if no one holds it any more. Returns at once; exits at once if caller is gone."""
    wait = _waiter(caller)
    if wait is None:
        _caller_ended(temp_dir)
        return

    def watch() -> None:
        wait()
        _caller_ended(temp_dir)

    threading.Thread(target=watch, name="ppd-caller-watch", daemon=True).start()


def _waiter(caller: int) -> Callable[[], Any] | None:
    """A function that returns when caller ends, or None when it has already ended."""
    try:
        pidfd = os.pidfd_open(caller)
    except ProcessLookupError:
        return None
    except (AttributeError, OSError):  # no pidfd here (not Linux, or before 5.3): poll the parent
        if os.getppid() != caller:
            return None if not _alive(caller) else (lambda: _poll(lambda: _alive(caller)))
        return lambda: _poll(lambda: os.getppid() == caller)
    return lambda: select.select([pidfd], [], [])


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _poll(alive: Callable[[], bool]) -> None:
    while alive():
        time.sleep(POLL_S)


def _caller_ended(temp_dir: str | None) -> None:
    if temp_dir is not None:
        with contextlib.suppress(OSError):
            remove_if_stale(temp_dir)
    os._exit(1)
