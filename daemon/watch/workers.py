"""A bounded pool of worker threads fed by path, with de-duplication and back-pressure.

Why threads: the CPU work (Pillow decode/encode, numpy blend, sha256) releases the GIL, and
threads share one SQLite connection pool and one vault without pickling. Why by path: the
watcher hands over *names*, not work items; what to do with a name (protect it, record it
removed, walk a moved-in folder) is decided by the handler when a worker gets to it, from
the filesystem as it is then. So a burst of events for one file costs one job.

Back-pressure (a flood of 10k files): `submit` never blocks. A path goes into the bounded
ready queue while there is room, else into an ordered pending set that refills the queue
as workers take jobs. Both de-duplicate: a path already waiting is not added twice. A path
submitted while a worker holds it is marked to run once more after (its content may have
changed under the worker). Past `max_pending` distinct waiting paths the pool stops
remembering names and raises `overflowed`; the owner then rescans the folder when the pool
drains (a rescan finds everything the dropped names pointed at).
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PoolOptions:
    workers: int = 2
    queue_size: int = 256  # the ready queue; the rest waits in the pending set
    max_pending: int = 100_000  # distinct waiting paths remembered before falling back to a rescan

    def __post_init__(self) -> None:
        if self.workers < 1 or self.queue_size < 1 or self.max_pending < 1:
            raise ValueError(f"pool sizes must be >= 1: {self}")


@dataclass(frozen=True)
class PoolStats:
    queued: int  # in the ready queue
    pending: int  # waiting for room in the ready queue
    in_flight: int
    done: int
    errors: int  # handler raised (the handler records ordinary failures itself)
    overflowed: bool


class WorkerPool:
    def __init__(
        self,
        handle: Callable[[Path], None],
        options: PoolOptions | None = None,
        name: str = "ppd-worker",
        on_idle: Callable[[], None] | None = None,
    ) -> None:
        """on_idle: called (from a worker thread) each time the last running job finishes with
        nothing left waiting."""
        self.options = options or PoolOptions()
        self._handle = handle
        self._on_idle = on_idle
        self._name = name
        self._cond = threading.Condition()
        self._ready: deque[Path] = deque()
        self._pending: OrderedDict[Path, None] = OrderedDict()
        self._waiting: set[Path] = set()  # in _ready or _pending
        self._in_flight: set[Path] = set()
        self._again: set[Path] = set()  # submitted while in flight: run once more after
        self._threads: list[threading.Thread] = []
        self._stopping = False
        self._done = 0
        self._errors = 0
        self._overflowed = False

    # ---- producer side (the watcher; must never block) ------------------------------------
    def submit(self, path: Path) -> bool:
        """Queue path unless it is already waiting; False when it was a duplicate or dropped."""
        with self._cond:
            if self._stopping:
                return False
            if path in self._in_flight:
                self._again.add(path)
                return True
            if path in self._waiting:
                return False
            return self._enqueue_locked(path)

    def _enqueue_locked(self, path: Path) -> bool:
        if len(self._ready) < self.options.queue_size:
            self._ready.append(path)
        elif len(self._pending) < self.options.max_pending:
            self._pending[path] = None
        else:
            if not self._overflowed:
                log.warning(
                    "work queue overflow; a rescan will follow",
                    extra={"max_pending": self.options.max_pending},
                )
            self._overflowed = True
            return False
        self._waiting.add(path)
        self._cond.notify()
        return True

    def take_overflow(self) -> bool:
        """True once after an overflow, when the pool has drained: time for the owner's rescan."""
        with self._cond:
            if self._overflowed and not self._ready and not self._pending:
                self._overflowed = False
                return True
            return False

    # ---- lifecycle --------------------------------------------------------------------------
    def start(self) -> None:
        for i in range(self.options.workers):
            thread = threading.Thread(target=self._run, name=f"{self._name}-{i}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def stop(self, timeout: float | None = None) -> list[Path]:
        """Stop taking work, let in-flight jobs finish, return the paths that never started."""
        with self._cond:
            self._stopping = True
            dropped = list(self._ready) + list(self._pending)
            self._ready.clear()
            self._pending.clear()
            self._waiting.clear()
            self._again.clear()
            self._cond.notify_all()
        for thread in self._threads:
            thread.join(timeout)
        return dropped

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until nothing is queued or running (tests, `ppd watch --once`)."""
        with self._cond:
            return self._cond.wait_for(self._idle, timeout)

    def stats(self) -> PoolStats:
        with self._cond:
            return PoolStats(
                len(self._ready),
                len(self._pending),
                len(self._in_flight),
                self._done,
                self._errors,
                self._overflowed,
            )

    # ---- worker side ----------------------------------------------------------------------
    def _idle(self) -> bool:
        return not self._ready and not self._pending and not self._in_flight

    def _next(self) -> Path | None:
        with self._cond:
            while not self._ready and not self._stopping:
                self._cond.wait()
            if self._stopping:
                return None
            path = self._ready.popleft()
            if self._pending:  # refill the ready queue from the pending set, oldest first
                self._ready.append(self._pending.popitem(last=False)[0])
            self._waiting.discard(path)
            self._in_flight.add(path)
            return path

    def _finish(self, path: Path, failed: bool) -> None:
        with self._cond:
            self._in_flight.discard(path)
            self._done += 1
            self._errors += int(failed)
            if path in self._again and not self._stopping:
                self._again.discard(path)
                self._enqueue_locked(path)  # under the same lock: wait_idle never sees a gap
            became_idle = self._idle()
            self._cond.notify_all()  # wakes wait_idle as well as workers
        if became_idle and self._on_idle is not None:
            self._on_idle()

    def _run(self) -> None:
        while (path := self._next()) is not None:
            failed = False
            try:
                self._handle(path)
            except Exception:  # one bad file must never take a worker down
                failed = True
                log.exception("worker job failed", extra={"path": str(path)})
            self._finish(path, failed)


def release_free_memory() -> None:
    """Give freed heap back to the OS once a batch is done (glibc's malloc_trim).

    Decoding a 12 MP photo takes ~100 MB that glibc keeps in its per-thread arenas after the
    batch; trimming brings an idle daemon back near its start-up size. No-op elsewhere."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
