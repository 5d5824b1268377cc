"""What every `ppd` command prints through: the two rich consoles (made on first use, so a
command that prints nothing rich never imports rich), -v counting, and the log handler.

Colour and progress bars only on a terminal; soft_wrap: a long line is never broken (an error or
a path stays greppable); highlight off: rich would colour numbers and paths inside our words.
"""

from __future__ import annotations

import functools
import logging
import os
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rich.console import Console


@functools.cache
def console() -> Console:
    from rich.console import Console

    return Console(soft_wrap=True, highlight=False)


@functools.cache
def err_console() -> Console:
    from rich.console import Console

    return Console(stderr=True, soft_wrap=True, highlight=False)


def interactive() -> bool:
    """Progress bars and spinners only where a person watches a real terminal."""
    err = err_console()
    return err.is_terminal and not err.is_dumb_terminal


# ---- -v -------------------------------------------------------------------------------------
_verbosity = [0]


def verbosity() -> int:
    """How many -v the command line gave (0 = quiet)."""
    return _verbosity[0]


# ---- logging --------------------------------------------------------------------------------
_RECORD_FIELDS = set(vars(logging.LogRecord("x", 0, "x", 0, "x", None, None))) | {"message", "asctime"}


def _field(value: Any) -> str:
    text = str(value)
    if text == "" or any(c in text for c in ' "=\n\t'):
        return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    return text


class KeyValueFormatter(logging.Formatter):
    """`level=info logger=daemon.watcher msg="..." path=/x dataset=y`: one line per record, the
    record's `extra` fields as keys, for journald and grep. No time stamp: journald adds its own."""

    def __init__(self, with_time: bool = False) -> None:
        super().__init__()
        self.with_time = with_time

    def format(self, record: logging.LogRecord) -> str:
        parts = []
        if self.with_time:
            parts.append(f"ts={self.formatTime(record, '%Y-%m-%dT%H:%M:%S')}")
        parts += [f"level={record.levelname.lower()}", f"logger={record.name}",
                  f"msg={_field(record.getMessage())}"]  # fmt: skip
        message = record.getMessage()
        for key, value in vars(record).items():
            if key in _RECORD_FIELDS or key.startswith("_") or value is None:
                continue
            if isinstance(value, str) and len(value) > 8 and value in message:
                continue  # said in msg already: one copy per line (a full disk has little room)
            parts.append(f"{key}={_field(value)}")
        if record.exc_info:
            parts.append(f"exc={_field(self.formatException(record.exc_info))}")
        return " ".join(parts)


def log_level(verbose: int) -> int:
    """WARNING by default (quiet), INFO with -v, DEBUG with -vv; PPD_LOG_LEVEL overrides."""
    env = os.environ.get("PPD_LOG_LEVEL")
    if env and not verbose:
        return getattr(logging, env.upper(), logging.WARNING)
    return {0: logging.WARNING, 1: logging.INFO}.get(verbose, logging.DEBUG)


class _RichOnFirstRecord(logging.Handler):
    """The CLI's handler: a RichHandler on the stderr console, built at the first record, so a
    command that logs nothing (`ppd poison --help`) never imports rich.logging."""

    def __init__(self, **rich_options: Any) -> None:
        super().__init__()
        self._options = rich_options
        self._rich: logging.Handler | None = None

    def emit(self, record: logging.LogRecord) -> None:
        if self._rich is None:
            from rich.logging import RichHandler

            self._rich = RichHandler(console=err_console(), **self._options)
        self._rich.handle(record)


def setup_logging(verbose: int, *, daemon: bool = False) -> None:
    """One handler on the root logger. The CLI logs through the rich stderr console (so a record
    lands above a progress bar, never inside it); the daemon logs key=value lines, coloured only
    when stderr is a terminal."""
    _verbosity[0] = verbose
    root = logging.getLogger()
    for handler in list(root.handlers):
        if getattr(handler, "_ppd", False):
            root.removeHandler(handler)
    handler: logging.Handler
    if daemon and not err_console().is_terminal:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(KeyValueFormatter())
    elif daemon:
        handler = _RichOnFirstRecord(show_path=False, rich_tracebacks=False)
    else:
        handler = _RichOnFirstRecord(show_time=False, show_path=False, markup=False)
    handler._ppd = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(log_level(verbose) if not daemon else min(log_level(verbose), logging.INFO))
    if not daemon and verbose < 2:
        # The CLI names each file itself with -v; the core's per-file record would say it twice.
        logging.getLogger("daemon.protect").setLevel(logging.WARNING)
        logging.getLogger("poisoner").setLevel(logging.WARNING)
