"""What every `ppd` command shares: the two consoles, the one error style, exit codes, logging.

Errors are one unwrapped line on stderr, `ppd: error: ...`, whatever the terminal width or where
the output goes; colour and progress bars only on a terminal. Light at import (typer, rich).
"""

from __future__ import annotations

import errno
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from typer.core import TyperArgument, TyperGroup

try:  # typer >= 0.22 vendors click: its exceptions are the ones raised
    from typer._click.exceptions import ClickException, NoArgsIsHelpError, UsageError
except ImportError:  # pragma: no cover - older typer on the real click
    from click.exceptions import ClickException, NoArgsIsHelpError, UsageError  # type: ignore[no-redef]

# ---- exit codes (the epilog of `ppd --help` lists them) -------------------------------------
EXIT_OK = 0
EXIT_FAILED = 1  # some files failed, or the verification verdict is not "protected"
EXIT_USAGE = 2  # bad input: unknown option, missing file, bad spec value, unknown dataset
EXIT_ENVIRONMENT = 3  # ppd cannot work here: folder not writable, disk full, damaged store, lock held
EXIT_INTERRUPTED = 130

EXIT_CODES_HELP = """\b
Exit status:
  0    done
  1    some files failed, or the verdict is not "protected"
  2    bad input: option, path, dataset name, spec value
  3    cannot work here: folder not writable, disk full, damaged store,
       another ppd holds the lock
  130  interrupted
"""

# soft_wrap: a long line is never broken (an error or a path stays greppable);
# highlight off: rich would colour numbers and paths in the middle of our own words.
console = Console(soft_wrap=True, highlight=False)
err_console = Console(stderr=True, soft_wrap=True, highlight=False)


def one_line(text: object) -> str:
    """The first non-empty line of text (exception messages may carry tracebacks or hints)."""
    for line in str(text).splitlines():
        if line.strip():
            return line.strip()
    return type(text).__name__ if isinstance(text, BaseException) else ""


def error(message: object) -> None:
    """Print one error line on stderr in the one style. Written raw: no wrapping, no markup."""
    sys.stderr.write(f"ppd: error: {one_line(message)}\n")
    sys.stderr.flush()


def warning(message: object) -> None:
    sys.stderr.write(f"ppd: warning: {one_line(message)}\n")
    sys.stderr.flush()


def die(message: object, code: int = EXIT_USAGE) -> typer.Exit:
    """Print the error; return the Exit to raise (`raise die(...) from None`)."""
    error(message)
    return typer.Exit(code)


def os_error_text(exc: OSError, hint_out: bool = True) -> str:
    """An OSError as a sentence that says what to do, not `[Errno 13] ... '.ppd-tmp-x.jpg'`."""
    where = Path(exc.filename) if exc.filename else None
    folder = where.parent if where is not None and not where.is_dir() else where
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        hint = "; use --out DIR" if hint_out else ""
        return f"folder not writable: {folder or 'unknown'}{hint}"
    if exc.errno == errno.ENOSPC:
        return f"disk full while writing in {folder or 'unknown'}"
    return f"{exc.strerror or exc}: {where}" if where else one_line(exc)


def reason_text(reason: str | None) -> str:
    """A failure reason recorded by the core (one line) with raw errno text made readable."""
    if not reason:
        return "unknown reason"
    for code, name in ((errno.EACCES, "Permission denied"), (errno.EROFS, "Read-only file system")):
        if f"[Errno {code}]" in reason or name in reason:
            path = reason.rsplit(":", 1)[-1].strip().strip("'\"")
            return f"folder not writable: {Path(path).parent if path else '?'}; use --out DIR"
    return one_line(reason)


# ---- the top-level group: one error style for click's own errors too ------------------------
_TYPE_WORDS = {"int": "N", "int range": "N", "float": "NUM", "float range": "NUM", "path": "PATH",
               "list[Path]": "PATH", "list[str]": "TEXT"}  # fmt: skip


def _readable_type(param: Any, original: Any) -> Any:
    """`--workers N` and `--dataset DATASET`, not `<int range>` and `<str>`."""

    def display(ctx: Any) -> str | None:
        label = original(ctx)
        if label is None or not label.startswith("<"):
            return label
        word = label.strip("<>")
        return _TYPE_WORDS.get(word) or (param.name or "value").upper()

    return display


def _tidy_help(command: Any) -> None:
    """Readable help in every command: no `<bool>` on flags, `PATHS...` not `{paths}`, words
    for types. Set on the parameter objects, once per process."""
    for param in command.params:
        if getattr(param, "_ppd_tidy", False):
            continue
        param._ppd_tidy = True
        if param.param_type_name == "option":
            if getattr(param, "is_flag", False) or param.count:
                param.metavar = ""
            elif param.metavar is None:
                param.display_type_rich = _readable_type(param, param.display_type_rich)
        elif isinstance(param, TyperArgument):
            name = (param.name or "arg").upper()
            usage = name if param.required else f"[{name}]"
            usage += "..." if param.nargs != 1 else ""
            param.display_type_rich = lambda ctx: None
            param._usage_display_name = lambda usage=usage: usage
            param._rich_display_name = lambda name=name: name
    for sub in getattr(command, "commands", {}).values():
        _tidy_help(sub)


class PpdGroup(TyperGroup):
    """typer's group with click's errors (usage, missing files) in ppd's one-line style."""

    def main(  # type: ignore[override]
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        _tidy_help(self)
        try:
            rv = super().main(
                args=args, prog_name=prog_name or "ppd", complete_var=complete_var,
                standalone_mode=False, **extra,
            )  # fmt: skip
        except NoArgsIsHelpError as exc:  # `ppd` alone: the help, on stdout, is the answer
            sys.stdout.write(exc.format_message() + "\n")
            code = EXIT_OK
        except UsageError as exc:
            hint = f" (see `{exc.ctx.command_path} --help`)" if exc.ctx is not None else ""
            error(f"{exc.format_message()}{hint}")
            code = exc.exit_code
        except ClickException as exc:
            error(exc.format_message())
            code = exc.exit_code
        except typer.Abort:
            code = EXIT_INTERRUPTED
        except KeyboardInterrupt:
            code = EXIT_INTERRUPTED
        except Exception as exc:
            code = _known_error(exc)
            if code is None:
                raise
        else:
            code = rv if isinstance(rv, int) else EXIT_OK
        if not standalone_mode:
            return code
        sys.exit(code)


def _known_error(exc: Exception) -> int | None:
    """ppd's own one-line errors that reach the top (named, not imported: this module stays
    light): print them in the one style and give their exit code; None = a bug, let it show."""
    if isinstance(exc, OSError):
        if exc.errno == errno.EPIPE:  # `ppd status | head`: the reader left
            return EXIT_FAILED
        error(os_error_text(exc))
        return EXIT_ENVIRONMENT
    names = {cls.__name__ for cls in type(exc).__mro__}
    if names & {"LockHeld", "StoreError"}:
        error(exc)
        return EXIT_ENVIRONMENT
    if "DatabaseError" in names:  # sqlite3's, from a damaged store file
        error(f"ppd's store is damaged ({one_line(exc)}); see `ppd config path` for where it is")
        return EXIT_ENVIRONMENT
    if names & {"ConfigError", "SpecError"}:
        error(exc)
        return EXIT_USAGE
    return None


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


_verbosity = [0]


def verbosity() -> int:
    """How many -v the command line gave (0 = quiet)."""
    return _verbosity[0]


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
    if daemon and not err_console.is_terminal:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(KeyValueFormatter())
    elif daemon:
        from rich.logging import RichHandler

        handler = RichHandler(console=err_console, show_path=False, rich_tracebacks=False)
    else:
        from rich.logging import RichHandler

        handler = RichHandler(console=err_console, show_time=False, show_path=False, markup=False)
    handler._ppd = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(log_level(verbose) if not daemon else min(log_level(verbose), logging.INFO))
    if not daemon and verbose < 2:
        # The CLI names each file itself with -v; the core's per-file record would say it twice.
        logging.getLogger("daemon.protect").setLevel(logging.WARNING)
        logging.getLogger("poisoner").setLevel(logging.WARNING)
