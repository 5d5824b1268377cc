"""`run_child()`: the one way ppd runs a child process (SfM, preflight, splat training).

Every child gets its own process group (so a kill reaches whatever it started), an optional time
limit, an optional cancel event, and ends in exactly one `ChildOutcome`: it exited (with its return
code), it was killed by a signal (a crash, e.g. a pycolmap segfault), it ran past its limit, or it
was cancelled. Timeout and cancel kill the whole group: SIGTERM, then SIGKILL after a grace period.
On Linux a child also dies with its parent (`die_with_parent`): a parent killed outright runs no
kill_group, and a child in its own session would otherwise go on alone.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

POLL_S = 0.2  # how often a running child is checked for its deadline and the cancel event


@dataclass(frozen=True)
class ChildOutcome:
    """How a child ended. `kind` is one of "exited", "crashed", "timeout", "cancelled"."""

    kind: str
    returncode: int | None
    elapsed_s: float
    signal_name: str | None = None  # for "crashed": SIGSEGV, SIGKILL, ...

    @property
    def exited(self) -> bool:
        return self.kind == "exited"


def signal_name(number: int) -> str:
    """SIGSEGV for 11; the number itself for a signal Python does not name."""
    try:
        return signal.Signals(number).name
    except ValueError:
        return str(number)


@cache
def _prctl() -> Any | None:
    """libc's prctl, looked up in the parent (a forked child only calls it: no dlopen there), or None
    where there is none (not Linux)."""
    import ctypes

    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


def die_with_parent(parent: int | None, prctl: Any | None = None) -> None:
    """Linux: this process is SIGKILLed when the thread that started it dies (PR_SET_PDEATHSIG), as
    systemd stopping the unit kills them all, so a parent killed outright leaves no child going on
    alone. parent: the pid that must still be the parent (None: not checked, e.g. under a
    forkserver); where it died before the signal took effect, this process exits at once.
    prctl: _prctl(), looked up beforehand (between fork and exec)."""
    call = prctl if prctl is not None else _prctl()
    if call is None:
        return
    call(1, signal.SIGKILL, 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    if parent is not None and os.getppid() != parent:
        os._exit(1)


CHILD_SETUP_ENV = "PPD_CHILD_SETUP"  # "PARENT_PID:NICE": what a child of run_child applies to itself


def child_setup_env(nice: int = 0) -> dict[str, str]:
    """The environment entry that asks a ppd child to lower its priority and die with this process
    (adopt_child_setup, first thing in the child). Not a preexec_fn: Python code between fork and exec
    runs CPython's after-fork cleanup, which freed another thread's PyAV scaler there and hung the child
    on a lock of a thread that does not exist in it (a CI run hung 15 minutes in `ppd verify`)."""
    return {CHILD_SETUP_ENV: f"{os.getpid()}:{max(0, nice)}"}


def adopt_child_setup() -> None:
    """In a child started with child_setup_env: nice() and die_with_parent (exits at once when the
    parent died before the signal took effect); nothing without that entry. The entry goes: its own
    children are asked anew."""
    value = os.environ.pop(CHILD_SETUP_ENV, "")
    parent, _, nice = value.partition(":")
    if not parent.isdigit() or not nice.isdigit():
        return
    if int(nice) > 0:
        with contextlib.suppress(OSError):
            os.nice(int(nice))
    die_with_parent(int(parent))


def run_child(
    cmd: Sequence[str],
    *,
    log_path: Path,
    stdin_data: bytes | None = None,
    timeout_s: float | None = None,
    cancel: threading.Event | None = None,
    env: Mapping[str, str] | None = None,
    nice: int = 0,
    append_log: bool = False,
    grace_s: float = 3.0,
    discard_stdout: bool = False,
    on_start: Callable[[int], None] | None = None,
) -> ChildOutcome:
    """Run cmd in a new session (its own process group); stderr (and stdout unless discard_stdout)
    goes to log_path.

    Returns when the child has ended; a child still running at timeout_s, or when cancel is set,
    is killed with its whole group. nice > 0 lowers the child's priority before it starts. The
    child dies with the calling thread (die_with_parent): run_child waits in it until the end.
    """
    started = time.monotonic()
    env = {**(os.environ if env is None else env), **child_setup_env(nice)}
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "ab" if append_log else "wb") as log_fh:
        proc = subprocess.Popen(  # no preexec_fn: the child sets itself up (adopt_child_setup)
            list(cmd),
            stdin=subprocess.PIPE if stdin_data is not None else subprocess.DEVNULL,
            stdout=subprocess.DEVNULL if discard_stdout else log_fh,
            stderr=log_fh,
            env=dict(env),
            start_new_session=True,
        )
        if on_start is not None:
            on_start(proc.pid)
        if stdin_data is not None:
            assert proc.stdin is not None
            with contextlib.suppress(BrokenPipeError):  # a child that died at once: its code says why
                proc.stdin.write(stdin_data)
            with contextlib.suppress(BrokenPipeError):
                proc.stdin.close()
        stopped = _wait(proc, started, timeout_s, cancel, grace_s)
    elapsed = time.monotonic() - started
    if stopped is not None:
        return ChildOutcome(stopped, proc.returncode, elapsed)
    if proc.returncode < 0:
        return ChildOutcome("crashed", proc.returncode, elapsed, signal_name(-proc.returncode))
    return ChildOutcome("exited", proc.returncode, elapsed)


def _wait(
    proc: subprocess.Popen[bytes],
    started: float,
    timeout_s: float | None,
    cancel: threading.Event | None,
    grace_s: float,
) -> str | None:
    """None once the child ended by itself; "timeout" or "cancelled" after killing its group."""
    while True:
        try:
            proc.wait(timeout=POLL_S)
            return None
        except subprocess.TimeoutExpired:
            pass
        reason = None
        if cancel is not None and cancel.is_set():
            reason = "cancelled"
        elif timeout_s is not None and time.monotonic() - started > timeout_s:
            reason = "timeout"
        if reason:
            kill_group(proc, grace_s)
            return reason


def kill_group(proc: subprocess.Popen[bytes], grace_s: float = 3.0) -> None:
    """SIGTERM the child's process group, then SIGKILL it if it has not ended after grace_s."""
    for sig, wait in ((signal.SIGTERM, grace_s), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(wait)
            return
        except subprocess.TimeoutExpired:
            continue
