"""Files the daemon cannot patch leave the outbox, so nothing unpatched is published by accident.

- `quarantine(ctx, path, reason)`: moves the file (never following a symlink) from the outbox to
  the quarantine folder (config `[daemon] quarantine_dir`, default `<outbox>/../ppd-quarantine`,
  a visible folder next to the outbox and outside it), under `<dataset>/<its path below the
  dataset>`, never over an existing file; the store row becomes 'quarantined' with the reason.
- Attempt markers: before the heavy work on a file, the pipeline holds a flock()ed marker naming
  it in the private data folder (`attempts/`); a marker still there at the next attempt means the
  process died working on that file (OOM killer, a decoder segfault, or a plain kill -9: ppd
  cannot tell which). So the next attempt runs the poisoner in a child process
  (daemon.protect.poisoning.poison_isolated): if the child dies too, the file is the cause, and the daemon
  quarantines it with that reason; the daemon itself does not die again, so there is no crash
  loop. If the child succeeds, the earlier death was not the file's fault.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import sqlite3
import stat
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.datasets.dataset import DEFAULT_DATASET, dataset_root, ensure_dataset
from daemon.fsops import NotContained, move_out, open_dir, open_dir_below
from daemon.paths import make_dirs_private, make_private_dir
from daemon.protect.job import one_line, shown_name, shown_path, storable
from daemon.states import FileState
from poisoner.errors import PpdError

if TYPE_CHECKING:
    from daemon.context import AppContext

log = logging.getLogger(__name__)

CRASH_LOOP_TRIES = 3


def quarantine_dir(ctx: AppContext) -> Path:
    return ctx.config.quarantine_dir_for(ctx.paths.outbox)


def quarantine(ctx: AppContext, path: Path, dataset: str | None, reason: str) -> Path | None:
    """Move path out of the outbox into the quarantine folder; its new path (None: nothing moved)."""
    outbox = Path(ctx.paths.outbox).absolute()
    path = Path(path).absolute()
    try:
        rel = path.relative_to(outbox)
    except ValueError:
        return None  # only the outbox is ppd's to empty
    folder_rel = rel.parent if dataset and dataset != DEFAULT_DATASET else Path(DEFAULT_DATASET) / rel.parent
    anchor = open_dir(outbox)
    try:
        src_dir = open_dir_below(anchor, rel.parts[:-1], path)
    except (NotContained, OSError):
        return None
    finally:
        os.close(anchor)
    try:
        is_link = stat.S_ISLNK(os.lstat(rel.name, dir_fd=src_dir).st_mode)
        if not is_link and (joined := _join_fragment(ctx, path, src_dir, rel.name, dataset)) is not None:
            return joined
        target_dir = quarantine_dir(ctx) / folder_rel
        make_dirs_private(target_dir)  # 0700 whatever the umask: it holds unprotected originals
        target = _free_name(target_dir / rel.name)
        if is_link:  # the link made again there, its target never opened (any filesystem)
            _move_link(src_dir, rel.name, path.parent, target)
        else:
            _move_file(src_dir, rel.name, target)
    except FileNotFoundError:
        return None
    finally:
        os.close(src_dir)
    _record_quarantined(ctx, path, dataset, target, reason)
    return target


def _move_link(src_dir: int, name: str, folder: Path, target: Path) -> None:
    """A symlink moved as a link: the same target, made absolute (a relative one would point
    elsewhere from the quarantine folder); rename does not cross filesystems, link() then fails too."""
    text = os.readlink(name, dir_fd=src_dir)
    os.symlink(text if os.path.isabs(text) else os.path.normpath(folder / text), target)
    os.unlink(name, dir_fd=src_dir)


def _move_file(src_dir: int, name: str, target: Path) -> None:
    try:
        os.link(name, target, src_dir_fd=src_dir, follow_symlinks=False)  # never over a file
        os.unlink(name, dir_fd=src_dir)
    except OSError as exc:
        if exc.errno not in (errno.EXDEV, errno.EPERM, errno.EMLINK, errno.ENOTSUP):
            raise
        move_out(src_dir, name, target)


def _record_quarantined(ctx: AppContext, path: Path, dataset: str | None, target: Path, reason: str) -> None:
    """The quarantined file readable by its owner only, its row and event (after the move). A name that
    is not UTF-8 gets no row (the store cannot hold it; its folder says it: unrecorded_quarantined):
    recording it logged Python's codec error at error level beside the file's own line (F7)."""
    _owner_only(target)
    try:  # the move is what protects; a failing store must not undo it
        name = dataset or DEFAULT_DATASET
        ensure_dataset(ctx, name, dataset_root(Path(ctx.paths.outbox).absolute(), name), None)
        if storable(path):
            ctx.store.record_file(
                path, name, FileState.QUARANTINED, error=reason, event="quarantined",
                detail={"to": str(target), "reason": reason},
            )  # fmt: skip
    except Exception as exc:
        log.error("quarantined %s but could not record it: %s", shown_name(path), one_line(exc),
                  extra={"path": shown_path(path)})  # fmt: skip
    log.debug(  # the daemon's line for the file says it (daemon.watch.watcher.say_outcome)
        "quarantined %s: %s (moved to %s)", shown_name(path), reason, shown_path(target),
        extra={"path": shown_path(path), "to": shown_path(target), "reason": reason},
    )  # fmt: skip


def unrecorded_quarantined(ctx: AppContext, root: Path) -> list[Path]:
    """The files in the quarantine folder of the outbox's dataset at root whose names are not UTF-8:
    moved there with no row, so only that folder says they are there (status said "0 quarantined" of
    such a photo, and never named it: a black-box review, F7). [] for a dataset outside the outbox."""
    outbox, root = Path(ctx.paths.outbox).absolute(), Path(root).absolute()
    if not root.is_relative_to(outbox):
        return []
    folder = quarantine_dir(ctx) / (DEFAULT_DATASET if root == outbox else root.relative_to(outbox))
    found = []
    for dirpath, _folders, names in os.walk(folder):  # none there (the usual case): no walk at all
        found += [Path(dirpath) / n for n in names if not storable(Path(n))]
    return sorted(found)


def _join_fragment(ctx: AppContext, path: Path, src_dir: int, name: str, dataset: str | None) -> Path | None:
    """A file that reappears under a name quarantined as incomplete, and is not a file of its own
    (it does not begin like any image or video: a writer's next append to a head moved away), is
    joined to its history: appended to the quarantined head, so quarantine keeps one whole file.
    When that makes the file complete, it goes back to its name in the outbox (to be protected).
    The joined file's path, or None when this is not such a fragment."""
    from poisoner.completeness import incomplete_reason, starts_like_media

    try:
        event = ctx.store.last_event(path, "quarantined")
    except UnicodeEncodeError:  # a name the store cannot hold (not UTF-8) has no history there
        return None
    except (PpdError, sqlite3.Error) as exc:  # the store failing: quarantine as usual
        log.warning(
            "%s: the store cannot say whether it was quarantined before (%s)", path.name, exc,
            extra={"path": str(path)},
        )  # fmt: skip
        return None
    if event is None:
        return None
    head = Path(event["detail"].get("to", ""))
    if "incomplete" not in str(event["detail"].get("reason", "")) or not head.is_file():
        return None
    if incomplete_reason(head) is None:
        return None  # that head is whole already: this is another file
    fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, dir_fd=src_dir)
    try:
        if starts_like_media(os.pread(fd, 16, 0)) is not False:
            return None  # a file of its own (or too short to tell): quarantined as it is
        with open(head, "ab") as out:
            while chunk := os.read(fd, 1 << 20):
                out.write(chunk)
            out.flush()
            os.fsync(out.fileno())
    finally:
        os.close(fd)
    os.unlink(name, dir_fd=src_dir)
    whole = incomplete_reason(head) is None
    back = None
    if whole:  # the head and its tail are one complete file again: back to its name
        try:
            os.link(head, name, dst_dir_fd=src_dir, follow_symlinks=False)  # never over a file
            os.unlink(head)
            back = path
        except OSError as exc:
            log.warning("joined %s but cannot put it back: %s", path.name, exc.strerror)
    with contextlib.suppress(Exception):
        ctx.store.add_event(dataset, path, "joined", {"to": str(back or head), "whole": whole})
    again = " (whole again, back in the outbox)" if back else ""
    log.warning(
        "%s: a fragment of %s, joined to it%s", path.name, head, again,
        extra={"path": str(path), "to": str(back or head)},
    )  # fmt: skip
    return back or head


def _owner_only(target: Path) -> None:
    """A quarantined original is readable by its owner only (0600), whatever mode it came with (a
    quarantined symlink has no mode of its own: left as it is, its target never touched)."""
    if target.is_symlink():
        return
    try:
        fd = os.open(target, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        log.warning("cannot restrict %s: %s", target, exc.strerror)
        return
    try:
        os.fchmod(fd, 0o600)
    except OSError as exc:
        log.warning("cannot restrict %s: %s", target, exc.strerror)
    finally:
        os.close(fd)


def _free_name(target: Path) -> Path:
    n = 1
    candidate = target
    while candidate.exists() or candidate.is_symlink():
        candidate = target.with_name(f"{target.stem}.{n}{target.suffix}")
        n += 1
    return candidate


# ---- attempt markers ------------------------------------------------------------------------------
ATTEMPTS = "attempts"  # the markers' folder in the data folder


def _attempts_dir(data_dir: Path) -> Path:
    folder = Path(data_dir) / ATTEMPTS
    make_private_dir(folder)
    return folder


def _marker_of(path: Path) -> str:
    return f"{hashlib.sha256(os.fsencode(str(path))).hexdigest()[:32]}.json"


@contextlib.contextmanager
def attempt(data_dir: Path, path: Path, dataset: str | None) -> Iterator[int]:
    """Hold a marker naming path while the heavy work runs (see the module docstring); yields how
    many attempts on it died before this one."""
    marker = _attempts_dir(data_dir) / _marker_of(path)
    fd = os.open(marker, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:  # a marker still there is an attempt that died: count it
            tries = int(json.loads(os.pread(fd, 1 << 16, 0) or b"{}").get("tries", 0)) + 1
        except (ValueError, TypeError, AttributeError):
            tries = 1
        doc = {"path": os.fsdecode(str(path)), "dataset": dataset, "pid": os.getpid(), "started": time.time(),
               "tries": tries}  # fmt: skip
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(doc).encode(), 0)
        yield tries - 1
        with contextlib.suppress(FileNotFoundError):
            os.unlink(marker)
    finally:
        os.close(fd)  # a SIGKILL skips the unlink: the marker stays, unlocked


def forget_attempt(data_dir: Path, path: Path) -> None:
    """A dead attempt's marker for path, removed once the file is settled without a new attempt (an
    interrupted run's file found patched, or recovered): else every start reports a crash that was
    recovered from, and the next attempt on the path runs isolated for nothing. A live one's stays."""
    marker = Path(data_dir) / ATTEMPTS / _marker_of(path)  # not made here: most files never crash
    try:
        fd = os.open(marker, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:  # none (every file that never crashed): nothing to do
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        marker.unlink(missing_ok=True)
    except BlockingIOError:
        pass  # an attempt at work on it now
    finally:
        os.close(fd)


def abandon_attempts(data_dir: Path, pid: int) -> int:
    """Remove the markers of the attempts in progress in process pid or its worker processes
    (daemon.protect.pool), as it leaves at once on the user's word (a second Ctrl-C): a stop asked for
    is no crash. The next start said "ppd died while patching" and ran the file isolated (black-box
    review 9, F9); its pending row still has it finished then. How many were removed. Called from a
    signal handler: no lock taken (these processes hold them)."""
    from daemon.platform import parent_pid

    removed = 0
    folder = Path(data_dir) / ATTEMPTS
    for marker in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        try:
            doc = json.loads(marker.read_bytes() or b"{}")
            owner = int(doc.get("pid", -1))
            ours = owner == pid or parent_pid(owner) == pid
            if ours and int(doc.get("tries", 1)) <= 1:  # one that died before this attempt: kept
                marker.unlink()
                removed += 1
        except (OSError, ValueError, TypeError, AttributeError):
            continue
    return removed


@dataclass(frozen=True)
class CrashedAttempt:
    path: Path
    dataset: str | None
    pid: int
    started: float
    marker: Path
    tries: int  # attempts in a row that died on this file (a single kill -9 is not a crash loop)

    @property
    def reason(self) -> str:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.started))
        return (
            f"ppd died {self.tries} times in a row while patching it (last: pid {self.pid}, started {when}; "
            "out of memory or a decoder crash); quarantined instead of retried"
        )


def crashed_attempts(data_dir: Path) -> list[CrashedAttempt]:
    """Markers left by a process that died mid-work (unlocked); markers of live work are skipped."""
    found = []
    for marker in sorted(_attempts_dir(data_dir).glob("*.json")):
        try:
            fd = os.open(marker, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                continue  # someone is working on it now
            try:
                doc = json.loads(os.pread(fd, 1 << 16, 0) or b"{}")
                path, pid, started = Path(doc["path"]), int(doc["pid"]), float(doc["started"])
                tries = int(doc.get("tries", 1))
                found.append(CrashedAttempt(path, doc.get("dataset"), pid, started, marker, tries))
            except (ValueError, KeyError, TypeError):
                marker.unlink(missing_ok=True)  # torn write at the instant of the crash: nothing to name
        finally:
            os.close(fd)
    return found
