"""Files the daemon cannot patch leave the outbox, so nothing unpatched is published by accident.

- `quarantine(ctx, path, reason)`: moves the file (never following a symlink) from the outbox to
  the quarantine folder (config `[daemon] quarantine_dir`, default `<outbox>/../ppd-quarantine`,
  a visible folder next to the outbox and outside it), under `<dataset>/<its path below the
  dataset>`, never over an existing file; the store row becomes 'quarantined' with the reason.
- Attempt markers: before the heavy work on a file, the pipeline holds a flock()ed marker naming
  it in the private data folder (`attempts/`); a marker still there at the next attempt means the
  process died working on that file (OOM killer, a decoder segfault, or a plain kill -9: ppd
  cannot tell which). So the next attempt runs the poisoner in a child process
  (daemon.pipeline.poison_isolated): if the child dies too, the file is the cause, and the daemon
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
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.dataset import DEFAULT_DATASET
from daemon.fsops import NotContained, move_out, open_dir, open_dir_below
from daemon.paths import make_private_dir
from daemon.states import FileState

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
        target_dir = quarantine_dir(ctx) / folder_rel
        target_dir.mkdir(parents=True, exist_ok=True)
        target = _free_name(target_dir / rel.name)
        try:
            os.link(rel.name, target, src_dir_fd=src_dir, follow_symlinks=False)  # never over a file
            os.unlink(rel.name, dir_fd=src_dir)
        except OSError as exc:
            if exc.errno not in (errno.EXDEV, errno.EPERM, errno.EMLINK, errno.ENOTSUP):
                if exc.errno == errno.ENOENT:
                    return None
                raise
            move_out(src_dir, rel.name, target)
    finally:
        os.close(src_dir)
    try:  # the move is what protects; a failing store must not undo it
        from daemon.dataset import dataset_root, ensure_dataset

        name = dataset or DEFAULT_DATASET
        ensure_dataset(ctx, name, dataset_root(outbox, name), None)
        ctx.store.record_file(
            path, dataset or DEFAULT_DATASET, FileState.QUARANTINED, error=reason, event="quarantined",
            detail={"to": str(target), "reason": reason},
        )  # fmt: skip
    except Exception as exc:
        log.error("quarantined %s but could not record it: %s", path.name, exc, extra={"path": str(path)})
    log.debug(  # the daemon's line for the file says it (daemon.watcher.say_outcome)
        "quarantined %s: %s (moved to %s)", path.name, reason, target,
        extra={"path": str(path), "to": str(target), "reason": reason},
    )  # fmt: skip
    return target


def _free_name(target: Path) -> Path:
    n = 1
    candidate = target
    while candidate.exists() or candidate.is_symlink():
        candidate = target.with_name(f"{target.stem}.{n}{target.suffix}")
        n += 1
    return candidate


# ---- attempt markers ------------------------------------------------------------------------------
def _attempts_dir(data_dir: Path) -> Path:
    folder = Path(data_dir) / "attempts"
    make_private_dir(folder)
    return folder


@contextlib.contextmanager
def attempt(data_dir: Path, path: Path, dataset: str | None) -> Iterator[int]:
    """Hold a marker naming path while the heavy work runs (see the module docstring); yields how
    many attempts on it died before this one."""
    marker = _attempts_dir(data_dir) / f"{hashlib.sha256(os.fsencode(str(path))).hexdigest()[:32]}.json"
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
