"""protect_file in worker processes: `protect_many` for a batch (`ppd poison --workers`) and
`ProtectWorkers` for the daemon (`ppd watch`).

Each worker process opens its own AppContext from the caller's paths and config: its own SQLite
connection (WAL: one connection per process), the same vault and the same per-file locks
(flock()s, shared by every ppd process). It runs daemon.protect.one_file.protect_file unchanged, so the
stages, their crash-safe order (daemon.protect.stages) and the bytes written are those of a serial run.

A worker killed in the middle of a file (out of memory, a decoder crash) is an outcome, as when
ppd itself dies there: the file's attempt marker (daemon.protect.quarantine.attempt) stays behind, and
the one retry that follows runs its poisoner isolated in a child (daemon.protect.stages.poison); a
child that dies too makes the outcome 'failed' and hopeless, so the daemon quarantines the file.

The daemon process itself then never imports numpy, PIL or PyAV: its workers start on the first
file (spawn: nothing of them stays behind) and exit after `idle_s` without work.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar, cast

import msgspec

from daemon.platform import keep_freed_memory
from daemon.protect.job import Outcome, ProtectOutcome

if TYPE_CHECKING:
    from daemon.config import Config
    from daemon.context import AppContext
    from daemon.paths import AppPaths
    from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

T = TypeVar("T")
DIED = "worker process died"
DEFAULT_IDLE_S = 30.0  # a daemon's workers exit after this long without a file


class ProtectCall(msgspec.Struct, frozen=True):
    """One protect_file call, as it crosses into a worker process."""

    path: Path
    dataset: str | None = None
    root: Path | None = None
    out_path: Path | None = None
    dry_run: bool = False
    force: bool = False
    spec: PatchSpec | None = None
    keep_location: bool | None = None
    subject_masks: Path | None = None  # a folder: the worker loads each file's mask itself


# ---- the worker process's side -------------------------------------------------------------------
_worker_ctx: AppContext | None = None


def ignore_interrupts() -> None:
    """Signals meant for the whole process group are the caller's to act on: a terminal's Ctrl-C,
    `timeout`'s or `kill -- -PGID`'s SIGTERM (a review: `timeout 20 ppd watch` and a group SIGTERM to
    `ppd poison` killed workers mid-file). The caller stops handing out files and lets the ones in
    progress finish (no traceback, nothing half-written). So a worker ignores SIGINT and leaves the
    group; a SIGTERM sent to it alone (the pool's own shutdown of a broken pool) still ends it. The
    caller blocked both while the worker started (poisoner.batch.interrupts_held): one that arrived
    meanwhile is dropped, not delivered at the unblock. systemd (KillMode=mixed) signals the caller;
    a worker whose caller is gone ends itself."""
    import contextlib
    import os
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # drops a pending group SIGTERM
    with contextlib.suppress(OSError):
        os.setpgid(0, 0)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM})


class WorkerFormatter(logging.Formatter):
    """A `ppd poison` worker's warnings in the CLI's one style: `ppd: warning: MESSAGE`."""

    def format(self, record: logging.LogRecord) -> str:
        return f"ppd: {record.levelname.lower()}: {record.getMessage()}"


def caller_formatter() -> logging.Formatter:
    """How this process's ppd handler writes records (the daemon's key=value formatter), for its
    workers to write theirs alike; the CLI's one-line style otherwise."""
    for handler in logging.getLogger().handlers:
        if getattr(handler, "_ppd", False) and handler.formatter is not None:
            return handler.formatter
    return WorkerFormatter()


def log_like_caller(formatter: logging.Formatter | None) -> None:
    """A worker's warnings on stderr, written as its caller writes them (never the bare message
    of logging's last-resort handler, which drops the file's name). Its per-file record is the
    caller's to write: a worker says only what went wrong. A library's Python warnings (Pillow's on
    a damaged EXIF tag) are not what went wrong: logged and dropped, as the caller drops them below
    -vv (daemon.cli.output.setup_logging; a review found them raw on stderr from workers)."""
    logging.captureWarnings(True)
    logging.getLogger("py.warnings").setLevel(logging.ERROR)
    if formatter is None:
        return
    handler = logging.StreamHandler()
    handler.setFormatter(formatter)
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(logging.WARNING)


def open_worker(
    paths: AppPaths, config: Config, lock_wait_s: float, parent: int | None = None,
    formatter: logging.Formatter | None = None, key_stamp: tuple[int, int, int] | None = None,
    stopped: Any = None, counts: tuple[Any, Any] | None = None,
) -> None:  # fmt: skip
    """A worker's AppContext: the caller's paths and config, the worker's own store connection.
    stopped: a shared byte its caller sets once asked to stop (Ctrl-C): a wait for another ppd
    process's file lock ends then (daemon.locks.WaitLeft), no file starts; a worker ignores the
    signal itself. counts: its files and waits in progress, shared with its caller
    (daemon.locks.share_counts), whose Ctrl-C says a file is finishing only when one is."""
    global _worker_ctx
    from daemon.locks import share_counts
    from verifier.supervise import die_with_parent  # the one helper for it (SfM children too)

    die_with_parent(parent)
    ignore_interrupts()
    keep_freed_memory()
    log_like_caller(formatter)
    if counts is not None:
        share_counts(*counts)
    from daemon.context import AppContext
    from daemon.store import Store
    from daemon.store.vault import Vault

    _worker_ctx = AppContext(
        paths=paths, config=config, store=Store(paths.db_path),
        vault=Vault(paths.vault_dir, config.vault.max_bytes, paths.config_file),
        lock_wait_s=lock_wait_s, key_stamp=key_stamp,  # the caller's key, never one made since
        give_up_waits=None if stopped is None else lambda: bool(stopped.value),
    )  # fmt: skip


def run_call(call: ProtectCall, ctx: AppContext | None = None) -> ProtectOutcome:
    """protect_file for one call, in this process (ctx: the worker's own when None); none once its
    caller stopped (a call the pool had queued where no cancel reaches: a stopped run starts no file)."""
    from daemon.locks import file_in_progress
    from daemon.protect.one_file import protect_file

    context = ctx or _worker_ctx
    assert context is not None, "open_worker was not run in this process"
    with file_in_progress():  # counted before the check: a stop meanwhile finds it in progress
        if context.give_up_waits is not None and context.give_up_waits():
            return not_started(call)
        return protect_file(
            call.path, context, call.dataset, root=call.root, out_path=call.out_path, dry_run=call.dry_run,
            force=call.force, spec=call.spec, keep_location=call.keep_location,
            subject_masks=call.subject_masks,
        )  # fmt: skip


def not_started(call: ProtectCall) -> ProtectOutcome:
    """A call its stopped caller counts with the files it never reached (ProtectOutcome.left)."""
    outcome = ProtectOutcome(
        path=Path(call.path).absolute(), dataset=call.dataset, state=Outcome.SKIPPED, reason="stopped"
    )
    outcome.left = True
    return outcome


def warm_up() -> None:
    """Load the stages and the poisoner, so a worker's first file does not wait for the imports."""
    import daemon.protect.one_file  # noqa: F401
    import poisoner.formats  # noqa: F401


def run_call_for_daemon(call: ProtectCall) -> ProtectOutcome:
    """run_call without the poisoner's report: unpickling it would load poisoner.formats (PIL,
    numpy) into the daemon, which reads only the outcome's state, reason and signature."""
    outcome = run_call(call)
    outcome.report = None
    return outcome


def died_outcome(call: ProtectCall, detail: str = "") -> ProtectOutcome:
    reason = f"{call.path.name}: {DIED}{detail}"
    return ProtectOutcome(
        path=Path(call.path).absolute(), dataset=call.dataset, state=Outcome.FAILED, reason=reason
    )


def _worker_args(
    ctx: AppContext, parent: int | None = None, stopped: Any = None, counts: tuple[Any, Any] | None = None
) -> tuple[object, ...]:
    formatter = caller_formatter()
    return (ctx.paths, ctx.config, ctx.lock_wait_s, parent, formatter, ctx.key_stamp, stopped, counts)


@contextlib.contextmanager
def _waits_left_on(ctx: AppContext, stop: Callable[[], bool] | None) -> Iterator[None]:
    """This process's waits for another's file lock end once stop() is true (open_worker's, here)."""
    before, ctx.give_up_waits = ctx.give_up_waits, stop
    try:
        yield
    finally:
        ctx.give_up_waits = before


# ---- a batch: ppd poison ----------------------------------------------------------------------------
def protect_many(
    ctx: AppContext,
    jobs: Sequence[tuple[Path, str, Path, Path | None]],
    *,
    workers: int | None = None,
    force: bool = False,
    dry_run: bool = False,
    spec: PatchSpec | Mapping[str, PatchSpec] | None = None,
    keep_location: bool | None = None,
    on_outcome: Callable[[ProtectOutcome], None] | None = None,
    subject_masks: Path | None = None,
    stop: Callable[[], bool] | None = None,
) -> list[ProtectOutcome]:
    """protect_file for every (file, dataset, root, out_path) job on a bounded pool of worker
    processes; the outcomes in the order of jobs, the same bytes written as serial runs.

    workers: None: the config's (`workers`); never more than the files; 1: in this process.
    spec: the spec new datasets get (or a dry run assumes), one for all or one per dataset name.
    subject_masks: a folder of subject masks for every job (default: each dataset's config).
    on_outcome: called in this process as each file finishes (a progress bar). Files whose worker
    died are run once more, one at a time, in this process: their attempt marker makes the
    poisoner run isolated in a child (a file that kills its process fails alone).
    stop: once it returns true (Ctrl-C, SIGTERM), no file starts any more and the files in
    progress finish: the outcomes are those of the files that ran, so fewer than the jobs."""
    from daemon.locks import counts_shared
    from poisoner.batch import bounded_map, pool_context

    def spec_for(dataset: str) -> PatchSpec | None:
        return spec.get(dataset) if isinstance(spec, Mapping) else spec

    calls = [
        ProtectCall(
            Path(f), d, Path(r), None if o is None else Path(o), dry_run, force, spec_for(d), keep_location,
            subject_masks,
        )
        for f, d, r, o in jobs
    ]  # fmt: skip
    n = max(1, min(ctx.config.workers if workers is None else workers, len(calls) or 1))
    stopped = stop or (lambda: False)
    if stopped():
        return []
    if n == 1:
        keep_freed_memory()  # this process does the pixel work (open_worker: each worker does)
        with _waits_left_on(ctx, stop):
            return _one_by_one(ctx, calls, stopped, on_outcome)
    retry = object()  # stands for a call whose worker died: re-run below
    results: dict[int, object] = {}

    def done(i: int, result: object) -> None:
        if isinstance(result, ProtectOutcome) and result.left:
            results.pop(i, None)  # never started: no outcome, as for the files not reached
            return
        results[i] = result
        if on_outcome is not None and result is not retry:
            on_outcome(cast(ProtectOutcome, result))

    def died(_i: int) -> object:
        return retry

    context = pool_context(("daemon.protect.one_file", "poisoner.formats"))
    told = context.RawValue("b", 0)  # set once stop() is true: the workers' waits for a lock end
    # the workers' files and waits in progress, for this process's Ctrl-C line (daemon.locks)
    counts = (context.RawArray("i", 2), context.Lock())

    def stopping() -> bool:
        if stopped():
            told.value = 1
            return True
        return False

    with counts_shared(*counts):
        bounded_map(
            cast(Callable[..., object], run_call), [(c,) for c in calls], n, died, on_done=done,
            mp_context=context, initializer=open_worker,
            initargs=_worker_args(ctx, stopped=told, counts=counts),
            stop=stopping if stop is not None else None,
            # [limits] max_memory_mb: the files in flight never need more memory than that together
            weights=[peak_estimate(c.path) for c in calls], budget=ctx.config.max_memory_bytes,
        )  # fmt: skip
    for i in sorted(results):
        if results[i] is retry and not stopped():
            log.warning("%s: %s; trying it once more", calls[i].path.name, DIED)
            with _waits_left_on(ctx, stop):
                done(i, run_call(calls[i], ctx))
    return [cast(ProtectOutcome, results[i]) for i in sorted(results) if results[i] is not retry]


def _one_by_one(
    ctx: AppContext, calls: list[ProtectCall], stopped: Callable[[], bool],
    on_outcome: Callable[[ProtectOutcome], None] | None,
) -> list[ProtectOutcome]:  # fmt: skip
    """protect_many in this process: until stopped(); a file left to another process ends it."""
    outcomes = []
    for call in calls:
        if stopped():
            break
        outcome = run_call(call, ctx)
        if outcome.left:  # stopped while another ppd process had it: nothing more starts
            break
        outcomes.append(outcome)
        if on_outcome is not None:
            on_outcome(outcome)
    return outcomes


# ---- the daemon's workers ---------------------------------------------------------------------------
VIDEO_PEAK_BYTES = 800_000_000  # poison_video at 3840x2160 peaks at 746 MB (bench_limits, docs/VIDEO.md)
UNKNOWN_PEAK_BYTES = 400_000_000  # an image whose header the daemon does not read itself


class ByteBudget:
    """Admission by memory: work runs only while the estimates of what runs fit in total bytes.
    A job estimated over the whole budget runs alone (its worker refuses it from the header,
    poisoner.limits.check_decode_budget); the budget never blocks the only job there is."""

    def __init__(self, total: int) -> None:
        self.total = max(1, int(total))
        self._used = 0
        self._running = 0
        self._cond = threading.Condition()

    def reserve(self, nbytes: int) -> int:
        """Wait until nbytes fit (or nothing else runs); what to release."""
        nbytes = max(0, int(nbytes))
        with self._cond:
            while self._running and self._used + nbytes > self.total:
                self._cond.wait()
            self._used += nbytes
            self._running += 1
        return nbytes

    def release(self, nbytes: int) -> None:
        with self._cond:
            self._used -= nbytes
            self._running -= 1
            self._cond.notify_all()

    @property
    def used(self) -> int:
        with self._cond:
            return self._used


def peak_estimate(path: Path) -> int:
    """What protecting path will take in memory, from its header (no decoder loaded here)."""
    from poisoner.limits import peak_bytes_estimate
    from poisoner.media import is_video

    if is_video(path):
        return VIDEO_PEAK_BYTES
    return peak_bytes_estimate(path, UNKNOWN_PEAK_BYTES)


class _Slot:
    """One worker process (started on demand) serving one of the daemon's worker threads."""

    def __init__(self, ctx: AppContext) -> None:
        self._ctx = ctx
        self._pool: ProcessPoolExecutor | None = None
        self.last_used = time.monotonic()

    def _started(self) -> ProcessPoolExecutor:
        if self._pool is None:
            import multiprocessing

            self._pool = ProcessPoolExecutor(  # typeshed ties initargs to a no-argument initializer
                1, mp_context=multiprocessing.get_context("spawn"), initializer=open_worker,  # type: ignore[arg-type]
                initargs=_worker_args(self._ctx, os.getpid()),  # type: ignore[arg-type]
            )  # fmt: skip
        return self._pool

    def _submit(self, fn: Callable[..., T], *args: object) -> Future[T]:
        from poisoner.batch import interrupts_held

        with interrupts_held():  # the worker process starts on a pool's first submit
            return self._started().submit(fn, *args)

    def warm(self) -> Future[None]:
        """Start the worker and its imports now."""
        self.last_used = time.monotonic()
        return self._submit(warm_up)

    def call(self, call: ProtectCall) -> ProtectOutcome:
        for attempt in (1, 2):
            try:
                return self._submit(run_call_for_daemon, call).result()
            except BrokenProcessPool:
                self.close()
                log.warning(
                    "%s: %s (attempt %d)", call.path.name, DIED, attempt, extra={"path": str(call.path)}
                )
            finally:
                self.last_used = time.monotonic()
        outcome = died_outcome(call, " twice; not retried")
        outcome.hopeless = True  # it took two processes down: the file is the cause
        return outcome

    @property
    def running(self) -> bool:
        return self._pool is not None

    def close(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


class ProtectWorkers:
    """protect_file for the daemon's worker threads, each in a worker process of its own, started on
    the first file and ended after idle_s without one (so an idle daemon holds no decoder memory)."""

    def __init__(
        self, ctx: AppContext, slots: int, idle_s: float = DEFAULT_IDLE_S, budget_bytes: int | None = None
    ) -> None:
        self.idle_s = idle_s
        self._lock = threading.Lock()
        self._free = [_Slot(ctx) for _ in range(max(1, slots))]
        self._all = list(self._free)
        self._busy = threading.Semaphore(len(self._free))
        # [limits] max_memory_mb: the workers together never hold more than this (estimated)
        self.budget = ByteBudget(budget_bytes or int(getattr(ctx.config, "max_memory_bytes", 1_024_000_000)))

    def protect(self, path: Path) -> ProtectOutcome:
        reserved = self.budget.reserve(peak_estimate(Path(path)))
        try:
            self._busy.acquire()
            with self._lock:
                slot = self._free.pop()
            try:
                return slot.call(ProtectCall(Path(path)))
            finally:
                with self._lock:
                    self._free.append(slot)
                self._busy.release()
        finally:
            self.budget.release(reserved)

    def warm(self, timeout: float = 60.0) -> None:
        """Start every worker now and wait (up to timeout) until they have loaded the stages and
        the poisoner: the daemon says it is ready once its first files need not wait for that.
        Unused, they exit after idle_s like any other."""
        with self._lock:
            started = [slot.warm() for slot in self._free]
        wait(started, timeout)

    def running(self) -> int:
        with self._lock:
            return sum(slot.running for slot in self._all)

    def end_idle(self, now: float | None = None) -> float | None:
        """End the worker processes idle for idle_s; seconds until the next idle one is due (None:
        none is waiting; one that finishes a file later wakes the daemon's loop through its pool)."""
        now = time.monotonic() if now is None else now
        idle: list[_Slot] = []
        with self._lock:  # each slot taken counts as busy, so protect() never finds the list empty
            for slot in [s for s in self._free if s.running and now - s.last_used >= self.idle_s]:
                if not self._busy.acquire(blocking=False):
                    break
                self._free.remove(slot)
                idle.append(slot)
        for slot in idle:
            slot.close()
        with self._lock:
            self._free.extend(idle)
        for _ in idle:
            self._busy.release()
        with self._lock:
            waits = [self.idle_s - (now - s.last_used) for s in self._free if s.running]
        if idle:  # quiet: the daemon's terminal says what it did to files, not to its workers
            log.debug("ended %d idle worker process(es)", len(idle))
        return max(0.0, min(waits)) if waits else None

    def close(self) -> None:
        with self._lock:
            slots = list(self._all)
        for slot in slots:
            slot.close()
