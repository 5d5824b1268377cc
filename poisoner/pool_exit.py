"""A pool's workers end with their caller, and what multiprocessing leaves in the temporary folder goes.

A caller killed outright (SIGKILL, the OOM killer's choice of the main process) runs no clean-up.
Its pool's workers then wait for work forever: each holds the write end of its own call queue, so no
end-of-file ever reaches it, and a forkserver outlives them (they hold its liveness pipe): processes
holding a decoded photo's memory, and one that could finish an atomic replace while the next `ppd`
run recovers the same file. So each worker watches its caller (`exit_with_caller`: a pidfd, Linux
5.3+; elsewhere its parent's pid, polled) and exits at once when it ends: the state is then the one a
process-group kill leaves, which ppd's recovery handles. The forkserver's socket lives in a `pymp-*`
folder that multiprocessing removes only at a clean exit; the caller marks the folder as its own
with a lock held for its lifetime (`claim_temp_dir`, poisoner.scratch), and a folder whose lock nobody
holds is removed by the worker that saw its caller end, or by the next ppd process that makes one.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from poisoner import scratch

POLL_S = 1.0  # where no pidfd exists: how often a worker checks its parent


def claim_temp_dir() -> str:
    """multiprocessing's temporary folder for this process (made now if it is not yet), marked as a
    ppd process's until this process ends (poisoner.scratch); stale ones are swept first."""
    import multiprocessing.util

    scratch.sweep()
    folder = multiprocessing.util.get_temp_dir()
    scratch.claim(folder)
    return folder


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
    except (AttributeError, OSError):  # no pidfd (not Linux, before 5.3, a seccomp filter): poll
        if os.getppid() == caller:  # spawned by it: reparented when it ends
            return lambda: _poll(lambda: os.getppid() == caller)
        if not Path("/proc").is_dir():
            return lambda: _poll(lambda: _signalable(caller))
        started = _stat(caller)
        if started is None or started[0] == "Z":  # gone, or ended and not yet reaped
            return None
        return lambda: _poll(lambda: _same_process(caller, started[1]))
    return lambda: select.select([pidfd], [], [])


def _stat(pid: int) -> tuple[str, str] | None:
    """(state, start time in clock ticks since boot) from /proc; None: no such process."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return fields[0], fields[19]


def _same_process(pid: int, started: str) -> bool:
    """pid still names the process that started then, and it has not ended (a zombie, whose parent
    has not reaped it, has ended; a reused pid is another process)."""
    now = _stat(pid)
    return now is not None and now[0] != "Z" and now[1] == started


def _signalable(pid: int) -> bool:
    """Where there is no /proc (macOS): whether the pid alone still answers."""
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
            scratch.remove_if_stale(temp_dir)
    os._exit(1)
