"""The event layer: inotify events in, complete file paths out, never blocking (OutboxWatcher),
and the start-up scan of the outbox (scan_outbox).

A file is handed on only when it is complete:
- close-after-write (IN_CLOSE_WRITE, watchdog's FileClosedEvent) or a rename into place
  (IN_MOVED_TO: browsers, rsync, editors and `mv` all finish that way), then
- a short debounce: the file's (inode, size, mtime) must be unchanged for `settle_s` after the
  last such event, for writers that close and reopen (chunked uploads, some sync tools).
A file that only ever got IN_CREATE (a hard link, or a file written inside a new folder
before its watch existed) is handed on after `unclosed_settle_s` of stable size and mtime.

Never handed on: dot-files and anything under a dot-folder (ppd's own `.ppd-tmp-*` atomic
temporaries included), partial downloads (`.crdownload`, `.part`, ...), editor backups and
swap files (`~`, `.swp`, `.tmp`), files that are not images or videos (by suffix; a suffix that
names no format by the file's first bytes, once complete: the worker asks). A partial download
is picked up when it is renamed to its final name (a moved-in event).

ppd's own atomic replace is a rename from `.ppd-tmp-*` onto the file: it is recognised by
its source name and dropped before it is queued. A stat signature recorded after each
processed file drops any other echo of ppd's own work (the vault's hard link changes ctime
only; a late close event sees the signature of the file ppd wrote).

The watcher runs on watchdog's observer thread and one debounce thread; both only do dict
updates and stat calls and hand paths to `submit`, which never blocks (daemon.watch.workers).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from watchdog.events import (
    DirDeletedEvent,
    DirMovedEvent,
    FileClosedEvent,
    FileCreatedEvent,
    FileDeletedEvent,
    FileMovedEvent,
    FileSystemEvent,
    FileSystemEventHandler,
)
from watchdog.observers.api import BaseObserver

from daemon.platform import inotify_observer
from poisoner.atomic import TEMP_PREFIX, is_temp_name, remove_stale_temp
from poisoner.media import MEDIA_SUFFIXES, judged_by_content, unpatched_name

log = logging.getLogger(__name__)


FileSignature = tuple[int, int, int]  # (inode, size, mtime_ns): changes whenever content can have


def ignore_reason(name: str) -> str | None:
    """Why a file name is never processed as it is (None: it may be): poisoner.media.unpatched_name,
    the rule `ppd status` and `ppd poison` name such a file by."""
    return "ppd temporary file" if is_temp_name(name) else unpatched_name(name)


def relative_parts(outbox: Path, path: Path) -> tuple[str, ...] | None:
    """path's components below outbox, or None when it is not inside."""
    try:
        return Path(path).relative_to(outbox).parts
    except ValueError:
        return None


def is_candidate(outbox: Path, path: Path, suffixes: frozenset[str], *, by_content: bool = True) -> bool:
    """Whether path (inside outbox) may name a file ppd would protect, by its name alone: a media
    suffix, or (by_content) a suffix that names no format, whose first bytes the worker judges once it
    is complete (poisoner.media.media_class: a JPEG named .jpg_original or with no suffix)."""
    parts = relative_parts(outbox, path)
    if not parts:
        return False
    if any(part.startswith(".") for part in parts[:-1]):
        return False  # under a dot-folder (.Trash-1000, .thumbnails, .git, ...)
    if ignore_reason(parts[-1]) is not None:
        return False
    return os.path.splitext(parts[-1])[1].lower() in suffixes or (by_content and judged_by_content(parts[-1]))


FolderIdentity = tuple[int, int]  # (device, inode): the folder itself, whatever its path


def folder_identity(path: Path) -> FolderIdentity | None:
    """The folder at path now (None: none there). A folder moved away and another made under its
    name has the path, never the identity, of the one watched."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_dev, st.st_ino)


def signature(path: Path) -> FileSignature | None:
    try:
        st = os.stat(path, follow_symlinks=False)
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


# ---- start-up scan --------------------------------------------------------------------------
@dataclass(frozen=True)
class ScanResult:
    files: list[Path]  # candidate files, in walk order
    stale_temps_removed: list[Path]  # `.ppd-tmp-*` leftovers of a crash, deleted
    young_temps: list[Path]  # `.ppd-tmp-*` too recent to call leftovers (another ppd may write them)


def walk_files(root: Path) -> Iterator[Path]:
    """Every regular file under root, not following symlinks, skipping dot-folders."""
    for folder, dirnames, filenames in os.walk(root, onerror=_log_walk_error):
        dirnames[:] = [d for d in dirnames if not d.startswith(".")]
        for name in filenames:
            yield Path(folder) / name


def _log_walk_error(exc: OSError) -> None:
    log.warning("cannot list folder %s: %s", exc.filename, exc.strerror, extra={"path": exc.filename})


def scan_outbox(
    outbox: Path, suffixes: frozenset[str], tmp_grace_s: float | None, now: float | None = None
) -> ScanResult:
    """List the outbox's candidate files and delete ppd temporaries older than tmp_grace_s
    (None: delete none).

    A temporary goes only when no living writer holds its lock (`ppd poison` in another
    process may be writing one right now); one made by name, not locked before it had one,
    also only once tmp_grace_s old."""
    now = time.time() if now is None else now
    files: list[Path] = []
    removed: list[Path] = []
    young: list[Path] = []
    for path in walk_files(outbox):
        if is_temp_name(path.name):  # ppd's form only: a user's `.ppd-tmp-notes.txt` is not ppd's
            try:
                if tmp_grace_s is not None and remove_stale_temp(path, min_age_s=tmp_grace_s, now=now):
                    removed.append(path)
                else:
                    young.append(path)
            except FileNotFoundError:
                pass
            except OSError as exc:
                log.warning("cannot remove leftover temporary %s: %s", path, exc.strerror)
        elif is_candidate(outbox, path, suffixes):
            files.append(path)
    return ScanResult(files, removed, young)


# ---- live events ----------------------------------------------------------------------------
@dataclass(frozen=True)
class WatchOptions:
    settle_s: float = 2.0  # quiet time after close-after-write (config: debounce_seconds)
    moved_settle_s: float = 0.2  # a rename is atomic: only coalesce bursts
    unclosed_settle_s: float = 10.0  # created, never closed/renamed (hard link, race in a new folder)
    # A file that keeps changing (a writer appending in bursts, closing between them) gets a quiet
    # time that doubles each time it is found changed or closed again soon after it was handed
    # on, up to max_settle_s (config: [daemon] max_debounce_seconds).
    max_settle_s: float = 30.0


@dataclass
class _Armed:
    deadline: float
    delay: float
    closed: bool  # a close/rename was seen (else only a creation)
    last: FileSignature | None
    recheck: bool = False  # asked by the consumer (a file waited for): handed on even if settled


class OutboxWatcher(FileSystemEventHandler):
    """Turns inotify events under outbox into `submit(path)` calls for complete files, and
    `submit(path)` for vanished files and folders (the consumer records them removed)."""

    def __init__(
        self,
        outbox: Path,
        submit: Callable[[Path], object],
        options: WatchOptions | None = None,
        suffixes: frozenset[str] | None = None,
        on_overflow: Callable[[], None] | None = None,
        on_moved: Callable[[], None] | None = None,
    ) -> None:
        """on_moved: a watched folder was renamed (perhaps the outbox itself: the owner compares
        folder_identity(outbox) with `identity`, what was watched)."""
        super().__init__()
        self.outbox = Path(outbox).absolute()
        self.options = options or WatchOptions()
        self.suffixes = suffixes if suffixes is not None else MEDIA_SUFFIXES
        self._submit = submit
        self._on_overflow = on_overflow or (lambda: None)
        self._on_moved = on_moved
        self.identity: FolderIdentity | None = None  # the outbox folder watched (set by start)
        self._cond = threading.Condition()
        self._armed: dict[Path, _Armed] = {}
        self._fired: dict[Path, tuple[float, float]] = {}  # path -> (when handed on, its quiet time)
        self._settled: dict[Path, FileSignature] = {}
        self._settled_lock = threading.Lock()
        self._observer: BaseObserver | None = None
        self._debouncer: threading.Thread | None = None
        self._stopping = False

    # ---- lifecycle --------------------------------------------------------------------------
    def start(self) -> None:
        # Full events: a rename from outside the outbox arrives as a move (complete file),
        # not as a creation (which would mean "a writer is starting"). An inotify queue overflow
        # (events lost) calls on_overflow: the owner rescans.
        # The folder's identity is taken before its watch: a folder swapped in between is told apart
        # on the next check (and watched again), never taken for the one watched.
        self.identity = folder_identity(self.outbox)
        observer = inotify_observer(self._on_overflow, full_events=True, on_moved_self=self._on_moved)
        observer.schedule(
            self, str(self.outbox), recursive=True,
            event_filter=[FileClosedEvent, FileCreatedEvent, FileMovedEvent, DirMovedEvent,
                          FileDeletedEvent, DirDeletedEvent],
        )  # fmt: skip
        observer.start()
        self._observer = observer
        self._stopping = False
        self._debouncer = threading.Thread(target=self._debounce_loop, name="ppd-debounce", daemon=True)
        self._debouncer.start()
        log.info("watching %s", self.outbox, extra={"outbox": str(self.outbox)})

    def stop(self) -> None:
        with self._cond:
            self._stopping = True
            self._armed.clear()
            self._cond.notify_all()
        if self._observer is not None:
            self._observer.stop()
            self._observer.join(timeout=10)
        if self._debouncer is not None:
            self._debouncer.join(timeout=10)

    def is_alive(self) -> bool:
        """False once the observer died (e.g. the outbox itself was deleted or moved away)."""
        observer = self._observer
        if observer is None or not observer.is_alive():
            return False
        return all(emitter.is_alive() for emitter in observer.emitters)

    @property
    def armed_count(self) -> int:
        with self._cond:
            return len(self._armed)

    # ---- what the consumer tells us ---------------------------------------------------------
    def mark_settled(self, path: Path) -> None:
        """Remember path's current signature: events that find it unchanged are echoes."""
        self.settle_as(path, signature(path))

    def settle_as(self, path: Path, sig: FileSignature | None) -> None:
        """Remember sig (what ppd judged or wrote at path) as settled; None forgets path."""
        with self._settled_lock:
            if sig is None:
                self._settled.pop(path, None)
            else:
                self._settled[path] = sig

    def is_settled(self, path: Path, sig: FileSignature | None = None) -> bool:
        sig = signature(path) if sig is None else sig
        with self._settled_lock:
            return sig is not None and self._settled.get(path) == sig

    def forget(self, path: Path) -> None:
        with self._settled_lock:
            self._settled.pop(path, None)

    def recheck(self, path: Path, delay: float) -> None:
        """Hand path on again after delay (a file waited for: its writer may not be done), even
        if it is unchanged and settled by then; an event for it meanwhile takes over."""
        with self._cond:
            if self._stopping or path in self._armed:
                return
            self._armed[path] = _Armed(
                time.monotonic() + delay, self.options.settle_s, True, signature(path), recheck=True
            )
            self._cond.notify()

    def _grown(self, path: Path, delay: float, now: float) -> float:
        """delay, doubled from the last one when path was handed on recently (within twice the
        quiet time it had then): a writer that closes, pauses and appends again gets more time."""
        fired = self._fired.get(path)
        if fired is None or now - fired[0] > 2 * fired[1] + self.options.settle_s:
            return delay
        return max(delay, min(self.options.max_settle_s, 2 * fired[1]))

    # ---- events (watchdog's observer thread) --------------------------------------------------
    def _candidate(self, raw: str | bytes) -> Path | None:
        if not raw:
            return None
        path = Path(os.fsdecode(raw))
        return path if is_candidate(self.outbox, path, self.suffixes) else None

    def _inside(self, raw: str | bytes) -> Path | None:
        if not raw:
            return None
        path = Path(os.fsdecode(raw))
        parts = relative_parts(self.outbox, path)
        if not parts or any(part.startswith(".") for part in parts):
            return None
        return path

    def on_closed(self, event: FileSystemEvent) -> None:
        if (path := self._candidate(event.src_path)) is not None:
            self._arm(path, self.options.settle_s, closed=True)

    def on_created(self, event: FileSystemEvent) -> None:
        if event.is_directory:
            return  # watchdog reports the new folder's content itself
        if (path := self._candidate(event.src_path)) is not None:
            self._arm(path, self.options.unclosed_settle_s, closed=False)

    def on_moved(self, event: FileSystemEvent) -> None:
        src = os.fsdecode(event.src_path) if event.src_path else ""
        if src and os.path.basename(src).startswith(TEMP_PREFIX):
            return  # ppd's own atomic replace: the destination is ppd's output
        if event.is_directory:
            if (gone := self._inside(src)) is not None:
                self._submit(gone)  # rows under it are recorded removed (if it is really gone)
            # A folder from outside: its files are complete; the consumer walks it. (A rename
            # inside the outbox also gets one moved event per file from watchdog.)
            if (new := self._inside(event.dest_path)) is not None and self._inside(src) is None:
                self._submit(new)
            return
        if (gone := self._candidate(src)) is not None:
            self._disarm(gone)
            self._submit(gone)
        if (dest := self._candidate(event.dest_path)) is not None:
            self._arm(dest, self.options.moved_settle_s, closed=True)

    def on_deleted(self, event: FileSystemEvent) -> None:
        src = os.fsdecode(event.src_path)
        if event.is_directory:
            if Path(src) == self.outbox:
                log.error("the outbox %s was deleted or moved away", src)
                self._on_overflow()  # the owner notices the dead observer and restarts
            elif (gone := self._inside(src)) is not None:
                self._submit(gone)
            return
        if (path := self._candidate(src)) is not None:
            self._disarm(path)
            self._submit(path)

    # ---- debounce ---------------------------------------------------------------------------
    def _arm(self, path: Path, delay: float, closed: bool) -> None:
        now = time.monotonic()
        with self._cond:
            if self._stopping:
                return
            armed = self._armed.get(path)
            if armed is not None and armed.closed and not closed:
                return  # a creation never weakens a close already seen
            if closed:
                delay = self._grown(path, delay, now)
            self._armed[path] = _Armed(deadline=now + delay, delay=delay, closed=closed, last=signature(path))
            self._cond.notify()

    def _disarm(self, path: Path) -> None:
        with self._cond:
            self._armed.pop(path, None)

    def _due(self) -> list[tuple[Path, _Armed]]:
        """Wait for the earliest deadline; return the entries that are due (removed)."""
        with self._cond:
            while not self._stopping:
                if not self._armed:
                    self._cond.wait()
                    continue
                now = time.monotonic()
                earliest = min(a.deadline for a in self._armed.values())
                if earliest > now:
                    self._cond.wait(earliest - now)
                    continue
                due = [(p, a) for p, a in self._armed.items() if a.deadline <= now]
                for p, _ in due:
                    del self._armed[p]
                return due
            return []

    def _debounce_loop(self) -> None:
        while due := self._due():
            for path, armed in due:
                try:
                    self._fire(path, armed)
                except Exception:  # never let the debounce thread die
                    log.exception("debounce failed", extra={"path": str(path)})

    def _fire(self, path: Path, armed: _Armed) -> None:
        now_sig = signature(path)
        if now_sig is not None and now_sig != armed.last:
            # Still changing (a writer that closed early and reopened): wait another, longer round.
            delay = min(self.options.max_settle_s, max(armed.delay * 2, self.options.settle_s))
            with self._cond:
                if path not in self._armed and not self._stopping:
                    self._armed[path] = _Armed(time.monotonic() + delay, delay, armed.closed, now_sig)
                    self._cond.notify()
            return
        if now_sig is not None and not armed.recheck and self.is_settled(path, now_sig):
            return  # ppd's own output, or content already processed
        with self._cond:
            self._fired[path] = (time.monotonic(), armed.delay)
            if len(self._fired) > 10_000:  # old entries only matter for a few quiet times
                cutoff = time.monotonic() - 4 * self.options.max_settle_s
                self._fired = {p: f for p, f in self._fired.items() if f[0] > cutoff}
        self._submit(path)
