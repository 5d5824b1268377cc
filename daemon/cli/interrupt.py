"""Ctrl-C and SIGTERM for a command that works through files (`ppd poison`): the first asks it
to stop between files, so the file in progress is finished and nothing is left half-done; a second
within SAME_STOP_S is the same request (`timeout` and `kill -- -PGID` signal the process and its
group, a Ctrl-C pressed twice); a later one acts at once, as it would have without ppd (the crash-safe
order of daemon.protect.stages makes that safe too)."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# A second stop signal within this many seconds of the first is the same request; a later one means
# "now" (`ppd poison` here, `ppd watch` in daemon.cli.watch_cmd).
SAME_STOP_S = 3.0


class StopOnSignal:
    """A context manager and a predicate: true once SIGINT or SIGTERM arrived inside it.
    on_stop runs in the signal handler (keep it short: a progress bar's label)."""

    def __init__(self, on_stop: Callable[[str], None] | None = None) -> None:
        self.signal_name: str | None = None
        self._first = 0.0
        self._on_stop = on_stop
        self._previous: dict[int, Any] = {}

    def __call__(self) -> bool:
        return self.signal_name is not None

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        now = time.monotonic()
        if self.signal_name is not None:
            if now - self._first < SAME_STOP_S:  # the same request (a group signal, a double Ctrl-C)
                return
            self._restore()  # asked again later: acts at once, as without ppd
            os.kill(os.getpid(), signum)
            return
        self.signal_name, self._first = signal.Signals(signum).name, now
        if self._on_stop is not None:
            self._on_stop(self.signal_name)

    def _restore(self) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous = {}

    def __enter__(self) -> StopOnSignal:
        if threading.current_thread() is threading.main_thread():  # only there can handlers be set
            for signum in STOP_SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._restore()


class TermAsInterrupt:
    """SIGTERM inside it acts as Ctrl-C does (KeyboardInterrupt): for a command whose Ctrl-C path ends
    its children and removes what it made (`ppd verify`). SIGTERM's default killed it silently with
    status 143 and left its run folder behind (a second black-box review); `timeout` and `systemctl
    stop` send it."""

    def __enter__(self) -> TermAsInterrupt:
        self._previous: Any = None
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGTERM, self._handle)
        return self

    @staticmethod
    def _handle(_signum: int, _frame: FrameType | None) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a group's second SIGTERM: the same request
        raise KeyboardInterrupt

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGTERM, self._previous)
