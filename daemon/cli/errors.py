"""ppd's one error style and its exit codes: one unwrapped line on stderr, `ppd: error: ...`,
whatever the terminal width or where the output goes. Standard library and typer only."""

from __future__ import annotations

import errno
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from poisoner.errors import ExitStatus, PpdError

if TYPE_CHECKING:
    from daemon.context import AppContext

# ---- exit statuses: poisoner.errors.ExitStatus (the epilog of `ppd --help` lists them) ----------
EXIT_CODES_HELP = """\b
Exit status:
  0    done
  1    some files failed, or the verdict is not "protected"
  2    bad input: option, path, dataset name, spec value
  3    cannot work here: folder not writable, disk full, damaged store,
       another ppd holds the lock
  130  interrupted
"""


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


def die(message: object, code: int = ExitStatus.USAGE) -> typer.Exit:
    """Print the error; return the Exit to raise (`raise die(...) from None`)."""
    error(message)
    return typer.Exit(code)


def refuse_missing_folder(file: Path) -> None:
    """The one rule for a file a command writes where the user says (`ppd report --out`, `ppd key
    export`): its folder must exist, else one line, exit 2 (the path is bad input, `--help`'s 2). report
    made the missing folders (as root: /nonexistent/dir/) and key export said exit 3, "cannot work here"
    (a black-box review, F11); a typo is not made into a tree of folders, and creating it is one mkdir."""
    folder = file.expanduser().absolute().parent
    if not folder.exists():
        raise die(f"no such folder: {folder}; create it first")
    if not folder.is_dir():
        raise die(f"not a folder: {folder}")


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


def reason_text(reason: str | None, folder: Path | None = None, hint_out: bool = True) -> str:
    """A failure reason recorded by the core (one line) with raw errno text made readable. folder:
    the failed file's, named where the error's path is relative (a temporary written beside it:
    "folder not writable: ."); hint_out: the command has --out (`ppd restore` has not)."""
    if not reason:
        return "unknown reason"
    for code, name in ((errno.EACCES, "Permission denied"), (errno.EROFS, "Read-only file system")):
        if f"[Errno {code}]" in reason or name in reason:
            path = reason.rsplit(":", 1)[-1].strip().strip("'\"")
            where = Path(path).parent if path else None
            if folder is not None and (where is None or not where.is_absolute()):
                where = folder
            return f"folder not writable: {where or '?'}" + ("; use --out DIR" if hint_out else "")
    return one_line(reason)


def file_reason(path: Path | str, reason: str | None) -> str:
    """reason_text without the file name the core's reasons often start with (the line has it)."""
    text = reason_text(reason, Path(path).absolute().parent)
    name = Path(path).name
    return text[len(name) + 2 :] if text.startswith(f"{name}: ") else text


def known_error(exc: Exception) -> int | None:
    """ppd's own one-line errors that reach the top, by type: print them in the one style and give
    their exit status; None = a bug, let it show."""
    if isinstance(exc, OSError):
        if exc.errno == errno.EPIPE:  # `ppd status | head`: the reader left
            return ExitStatus.FAILED
        error(os_error_text(exc))
        return ExitStatus.ENVIRONMENT
    if isinstance(exc, PpdError):  # every ppd error, wherever it arose, carries its exit status
        error(exc)
        return exc.exit_status
    # sqlite3's, from a damaged store file. Looked up, not imported (this module stays light): a
    # process that never loaded sqlite3 cannot be raising its errors.
    sqlite3 = sys.modules.get("sqlite3")
    if sqlite3 is not None and isinstance(exc, sqlite3.DatabaseError):
        error(f"ppd's store is damaged ({one_line(exc)}); see `ppd config path` for where it is")
        return ExitStatus.ENVIRONMENT
    return None


def open_ctx(*, needs_key: bool = False, store_held: bool = False) -> AppContext:
    """ppd's folders, config and store, or one line that says why they cannot be opened. needs_key:
    the command patches or recognises files by their seal: the key is loaded here, made while the vault
    is empty (before a worker vaults an original: later it would count as lost), and a lost one stops
    the command (exit 3) before a file is touched (daemon.store.sealkey). store_held: the caller holds
    the store lock alone (AppContext.open)."""
    from daemon.config import ConfigError
    from daemon.context import AppContext
    from daemon.locks import LockHeld
    from daemon.store import StoreError
    from daemon.store.sealkey import SealKeyError

    try:
        ctx = AppContext.open(store_held=store_held)
    except (ConfigError, StoreError, LockHeld) as exc:  # each with its status: a damaged store is 3, not 2
        raise die(one_line(exc), exc.exit_status) from None
    except OSError as exc:
        raise die(
            f"cannot set up ppd's folders: {os_error_text(exc, hint_out=False)}", ExitStatus.ENVIRONMENT
        ) from None
    if needs_key:
        try:
            ctx.seal_key()
        except SealKeyError as exc:
            ctx.close()
            raise die(one_line(exc), exc.exit_status) from None
    # a lost store: Store.open_or_warn logged its warning, which every command prints until `ppd store
    # rebuild` (printing ctx.store.lost_warning here too said it twice: a black-box review)
    return ctx
