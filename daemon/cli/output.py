"""What every `ppd` command prints through: the two rich consoles (made on first use, so a
command that prints nothing rich never imports rich), -v counting, and the log handler.

Colour and progress bars only on a terminal; soft_wrap: a long line is never broken (an error or
a path stays greppable); highlight off: rich would colour numbers and paths inside our words; emoji
off: rich would turn a name's own ":thumbs_up:" (a dataset's, a folder's) into a picture.
"""

from __future__ import annotations

import functools
import logging
import os
import re
import sys
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from rich.console import Console


@functools.cache
def console() -> Console:
    from rich.console import Console

    return Console(soft_wrap=True, highlight=False, emoji=False)


@functools.cache
def err_console() -> Console:
    from rich.console import Console

    return Console(stderr=True, soft_wrap=True, highlight=False, emoji=False)


def print_line(out: Console, line: str) -> None:
    """One line of plain words wrapped at spaces to the console's width, never inside a word: a path
    or a command to copy stays whole (rich folds a word longer than the width). Into a pipe or a file
    with no COLUMNS set there is no width (rich's 80 is a guess): one line, a command whole for grep."""
    import textwrap

    if not out.is_terminal and not os.environ.get("COLUMNS"):
        out.print(line, markup=False, soft_wrap=True)
        return
    # a `command` in backticks is one word: broken across lines it cannot be copied whole (a review
    # at 40 columns); its spaces are held by a character no message uses while wrapping
    held = re.sub(r"`[^`]*`", lambda m: m.group(0).replace(" ", _HELD_SPACE), line)
    wrapped = textwrap.wrap(held, out.width, break_long_words=False, break_on_hyphens=False,
                            subsequent_indent=" " * (len(line) - len(line.lstrip(" "))))  # fmt: skip
    out.print("\n".join(wrapped).replace(_HELD_SPACE, " ") or line, markup=False, soft_wrap=True)


_HELD_SPACE = "\x00"


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
    """A value as logfmt writes it: quoted, with \\ \" \\n escaped, when it holds a space, a quote, an
    equals sign, a newline, a tab or a backslash (an escaped name, caf\\xe9.png, then reads the same in
    every field of a line: a black-box review, F7)."""
    text = str(value)
    if text == "" or any(c in text for c in ' "=\n\t\\'):
        return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    return text


# The keys of the daemon's line per file: always there, so `grep outcome=quarantined` finds each.
ALWAYS_SHOWN = frozenset({"event", "dataset", "file", "outcome", "seconds"})


class KeyValueFormatter(logging.Formatter):
    """`level=info logger=daemon.watch.watcher msg="..." path=/x dataset=y`: one line per record, the
    record's `extra` fields as keys, for journald and grep. No time stamp: journald adds its own."""

    def __init__(self, with_time: bool = False, terminal: bool = False) -> None:
        """terminal: for a person at 80 columns: the time of day first, the level only when it is
        not info, no logger (the journal's lines keep all three)."""
        super().__init__()
        self.with_time = with_time
        self.terminal = terminal

    def format(self, record: logging.LogRecord) -> str:
        parts = []
        if self.terminal:
            parts.append(f"ts={self.formatTime(record, '%H:%M:%S')}")
            if record.levelno != logging.INFO:
                parts.append(f"level={record.levelname.lower()}")
        else:
            if self.with_time:
                parts.append(f"ts={self.formatTime(record, '%Y-%m-%dT%H:%M:%S')}")
            parts += [f"level={record.levelname.lower()}", f"logger={record.name}"]
        parts.append(f"msg={_field(record.getMessage())}")
        message = record.getMessage()
        for key, value in vars(record).items():
            if key in _RECORD_FIELDS or key.startswith("_") or value is None:
                continue
            if key not in ALWAYS_SHOWN and isinstance(value, str) and len(value) > 8 and value in message:
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


class LineHandler(logging.Handler):
    """The CLI's handler: one unpadded line per record on the stderr console (so a record lands
    above a progress bar, never inside it), `ppd: warning: MESSAGE` in the style of ppd's errors;
    INFO and DEBUG (-v, -vv) as the message alone."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
            if record.levelno >= logging.WARNING:
                message = f"ppd: {record.levelname.lower()}: {message}"
            err_console().print(message, markup=False, highlight=False, soft_wrap=True)
        except Exception:
            self.handleError(record)


def daemon_handler() -> logging.Handler:
    """`ppd watch` (and its worker processes): key=value lines on stderr, on a terminal too, with a
    time stamp unless they go to journald (which adds its own), one line per record."""
    handler = logging.StreamHandler(sys.stderr)
    on_terminal = err_console().is_terminal
    # a file or pipe (`nohup ppd watch > log`) gets the date and time too: only journald adds its own
    handler.setFormatter(KeyValueFormatter(with_time=not to_journal(), terminal=on_terminal))
    return handler


def to_journal() -> bool:
    """Whether stderr is systemd's journal stream (JOURNAL_STREAM names its device:inode)."""
    stream = os.environ.get("JOURNAL_STREAM", "")
    try:
        st = os.fstat(sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):
        return False
    return stream == f"{st.st_dev}:{st.st_ino}"


def setup_logging(verbose: int, *, daemon: bool = False) -> None:
    """One handler on the root logger: the CLI's one-line records (LineHandler), the daemon's
    key=value lines (daemon_handler)."""
    _verbosity[0] = verbose
    root = logging.getLogger()
    for handler in list(root.handlers):
        if getattr(handler, "_ppd", False):
            root.removeHandler(handler)
    handler = daemon_handler() if daemon else LineHandler()
    cast(Any, handler)._ppd = True  # ours: the next setup_logging replaces it
    root.addHandler(handler)
    root.setLevel(log_level(verbose) if not daemon else min(log_level(verbose), logging.INFO))
    if not daemon and verbose < 2:
        # The CLI names each file itself with -v, and prints the corner it chose; the core's
        # records would say each twice.
        for name in ("daemon.protect.one_file", "daemon.datasets.subject_masks", "poisoner"):
            logging.getLogger(name).setLevel(logging.WARNING)
    if daemon and verbose < 2:  # the daemon's terminal says what it did to each file, once
        logging.getLogger("daemon.protect.one_file").setLevel(logging.WARNING)
    # a library's Python warnings (Pillow's "Corrupt EXIF data", numpy's on an odd picture) went to
    # stderr as two raw lines beside ppd's one-line messages (a black-box review): logged, and shown
    # with -vv only; what they were about is in the file's own outcome
    logging.captureWarnings(True)
    logging.getLogger("py.warnings").setLevel(logging.DEBUG if verbose >= 2 else logging.ERROR)
