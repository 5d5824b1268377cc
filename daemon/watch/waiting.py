"""What the daemon's files wait for: their writer (WriterWaits), their subject masks (FolderWaits),
free disk space (SpaceWaits).

Incomplete files the daemon waits for (their writer may append more after a pause, issue 29):
each is re-checked after a growing quiet time and refused (quarantined whole) only once it has not
changed for `incomplete_wait_s`. Its row says it is waited for, not failed.

Said once: the first check logs at info, the re-checks at debug (a truncated file said "incomplete,
waiting for its writer" about 8 times over 2 minutes: a black-box review). The file's event (`new`
or `changed`) is the one judged when it was first seen: ppd's own waiting row made a new file's
line say `event=changed` once it was complete."""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.datasets.subject_masks import readable_folder
from daemon.watch.outbox import FileSignature, OutboxWatcher, signature
from daemon.watch.outcomes import is_no_space

log = logging.getLogger("daemon.watch.watcher")  # the daemon's lines keep the logger they always had


@dataclass(frozen=True)
class _Waited:
    signature: FileSignature | None  # as last checked
    since: float  # unchanged since (monotonic)
    checks: int  # re-checks so far
    event: str  # "new" or "changed", judged when the file was first seen


class WriterWaits:
    def __init__(self, store: Any, wait_s: float, settle_s: float, max_settle_s: float) -> None:
        self.store = store
        self.wait_s = wait_s
        self.settle_s = settle_s
        self.max_settle_s = max_settle_s
        self._waited: dict[Path, _Waited] = {}
        self._lock = threading.Lock()

    def event_of(self, path: Path) -> str | None:
        """The event judged when a file waited for was first seen (None: not waited for)."""
        with self._lock:
            waited = self._waited.get(path)
        return None if waited is None else waited.event

    def done(self, path: Path) -> None:
        with self._lock:
            self._waited.pop(path, None)

    def wait(self, path: Path, judged: FileSignature | None, event: str, watcher: OutboxWatcher) -> bool:
        """An incomplete file is waited for, not refused, while its writer may still be at it.
        True: waiting (nothing moved); False: unchanged for the whole wait, refuse it."""
        now = time.monotonic()
        after = signature(path)
        with self._lock:
            seen = self._waited.get(path)
            since = seen.since if seen is not None and seen.signature == after else now
            checks = seen.checks + 1 if seen is not None else 0
            self._waited[path] = _Waited(after, since, checks, seen.event if seen is not None else event)
        # Re-checked just before any refusal: changed while it was judged, or within the wait.
        if after != judged or after is None or now - since < self.wait_s:
            watcher.forget(path)
            left = max(0.0, self.wait_s - (now - since))
            grown = self.settle_s * 2 ** min(checks, 16)
            delay = max(0.5, min(self.max_settle_s, grown, left))
            watcher.recheck(path, delay)
            log.log(
                logging.INFO if checks == 0 else logging.DEBUG,
                "incomplete, waiting for its writer: %s (re-checked in %.0f s)", path, delay,
                extra={"path": str(path), "reason": "incomplete", "wait_s": round(delay, 1)},
            )  # fmt: skip
            return True
        self.done(path)
        return False

    def record(self, path: Path, outcome: Any) -> None:
        """The row of a file waited for says so (skipped, for now), not the failure its worker
        recorded: `ppd status --failed` listed a file still being written as failed while the
        daemon's own count said failed 0. Patched or quarantined later, the row says that."""
        from daemon.protect.job import storable
        from daemon.states import WAITING_PREFIX, FileState

        if not outcome.dataset or not storable(path):
            return
        why = f"{WAITING_PREFIX} (patched once complete)"
        try:
            self.store.record_file(
                path, outcome.dataset, FileState.SKIPPED, error=why, durable=False, event="waiting",
                detail={"reason": outcome.reason},
            )  # fmt: skip
        except Exception:  # the store failing must not stop the wait: the failed row stays
            log.exception("could not record a waited-for file", extra={"path": str(path)})


class FolderWaits:
    """Files that failed because their dataset's subject-mask folder is not there (a drive unplugged:
    daemon.datasets.subject_masks.MaskFolderMissing): each is retried once its folder is a readable
    folder again (the main loop asks every no-space poll), not left failed until a restart."""

    def __init__(self) -> None:
        self._waiting: dict[Path, Path] = {}  # file -> the folder it waits for
        self._lock = threading.Lock()

    def __bool__(self) -> bool:
        with self._lock:
            return bool(self._waiting)

    def note(self, path: Path, folder: Path | None) -> None:
        """Wait for folder (None: path waits for nothing now)."""
        with self._lock:
            if folder is None:
                self._waiting.pop(path, None)
            else:
                self._waiting[path] = folder

    def back(self) -> list[Path]:
        """The files whose folder is readable again, forgotten here (their retry may wait again)."""
        with self._lock:
            folders = set(self._waiting.values())
            ready = {f for f in folders if readable_folder(f)}
            paths = [p for p, f in self._waiting.items() if f in ready]
            for p in paths:
                del self._waiting[p]
        if paths:
            log.info("subject masks back (%s): retrying %d file(s)", ", ".join(map(str, sorted(ready))),
                     len(paths), extra={"files": len(paths)})  # fmt: skip
        return paths


class SpaceWaits:
    """Files that failed for lack of disk space (no event tells when space returns): all queued again
    once free space has grown by 1 MiB since the first of them failed, or after retry_s in any case
    (the main loop asks every no-space poll)."""

    def __init__(self, folders: tuple[Path, ...], retry_s: float) -> None:
        self.folders = folders  # the fuller of their filesystems is the one watched
        self.retry_s = retry_s
        self._waiting: dict[Path, None] = {}
        self._since = (0.0, 0)  # (monotonic time, free bytes) of the first such failure
        self._lock = threading.Lock()

    def __bool__(self) -> bool:
        with self._lock:
            return bool(self._waiting)

    def note(self, path: Path, reason: str | None) -> bool:
        """A file that failed for lack of space (reason says so: True), or that did not (forgotten)."""
        with self._lock:
            if not is_no_space(reason):
                self._waiting.pop(path, None)
                return False
            if not self._waiting:
                self._since = (time.monotonic(), self.free_bytes())
            self._waiting[path] = None
            return True

    def free_bytes(self) -> int:
        """Free bytes on the fuller of the folders' filesystems."""
        free = []
        for folder in self.folders:
            try:
                st = os.statvfs(folder)
            except OSError:
                continue
            free.append(st.f_bavail * st.f_frsize)
        return min(free) if free else 0

    def due(self) -> list[Path]:
        """The files to retry now (all of them, forgotten here: a retry that fails again notes its own)."""
        with self._lock:
            if not self._waiting:
                return []
            since, free_then = self._since
            grown = self.free_bytes() > free_then + (1 << 20)
            if not grown and time.monotonic() - since < self.retry_s:
                return []
            paths, self._waiting = list(self._waiting), {}
        log.info("disk space returned: retrying %d file(s)", len(paths), extra={"files": len(paths)})
        return paths
