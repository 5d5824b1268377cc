"""Protect many image files at once on several cores, writing exactly what one-by-one would.

`poison_many(pairs, spec, workers=...)` runs `poison_in_place` (src == dst) or `poison_file`
(src -> dst) for each pair in a bounded pool of worker processes: at most `workers` processes and
at most 2 x workers files in flight, so memory stays at workers x one file's peak. Each file is
independent and `poison_file` is deterministic, so the bytes written do not depend on the number
of workers or the order of completion (tests/poisoner/test_batch.py checks byte identity with serial runs).

Workers come from a "forkserver" (Linux): a fresh, single-threaded process that has imported the
poisoner once and forks a worker per pool slot, so a caller with threads (the daemon) never forks
itself and workers skip the import cost. Elsewhere, and under a temporary folder too long for its
socket, "spawn". workers=1 runs in the calling process.

Per file the result is a BatchResult with the PoisonReport or a one-line error; a worker that
dies (a codec crash) fails only the files it had, which are reported, never raised.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from poisoner.pool_exit import claim_temp_dir, exit_with_caller

if TYPE_CHECKING:  # types only: importing this module stays light
    from poisoner.formats import PoisonReport
    from poisoner.provenance import Marker
    from poisoner.spec import PatchSpec

MAX_DEFAULT_WORKERS = 8  # each worker holds one decoded file at a time
STOP_POLL_S = 0.2  # how soon bounded_map notices its stop() turned true
R = TypeVar("R")


@dataclass(frozen=True)
class BatchResult:
    src: Path
    dst: Path
    report: PoisonReport | None
    error: str | None = None  # one line when the file failed


def default_workers(count: int) -> int:
    """The CPUs this process may run on, capped, and never more than the files."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    return max(1, min(cpus, MAX_DEFAULT_WORKERS, count))


def _poison_one(
    src: Path, dst: Path, spec: PatchSpec, marker: Marker | None, keep_location: bool, max_pixels: int | None
) -> BatchResult:
    from poisoner.formats import ImageFormatError, poison_file, poison_in_place

    try:
        if Path(src) == Path(dst):
            report = poison_in_place(
                src, spec, marker=marker, keep_location=keep_location, max_pixels=max_pixels
            )
        else:
            report = poison_file(
                src, dst, spec, marker=marker, keep_location=keep_location, max_pixels=max_pixels
            )
    except ImageFormatError as exc:
        return BatchResult(src, dst, None, str(exc))
    except OSError as exc:  # e.g. the destination folder is not writable
        return BatchResult(src, dst, None, f"{Path(src).name}: {type(exc).__name__}: {exc}".splitlines()[0])
    return BatchResult(src, dst, report)


# The forkserver listens on an AF_UNIX socket in a folder multiprocessing makes under the temporary
# folder (about 32 characters more), and the kernel limits such socket paths to 107 bytes.
_SOCKET_PATH_MAX, _SOCKET_SUFFIX = 107, len("/pymp-xxxxxxxx/listener-xxxxxxxx")


def pool_context(preload: Sequence[str] = ("poisoner.formats",)) -> multiprocessing.context.BaseContext:
    """The start method for worker processes: a forkserver that imported preload once (Linux, a
    temporary folder short enough for its socket), else spawn."""
    short_tmp = len(os.fsencode(tempfile.gettempdir())) + _SOCKET_SUFFIX < _SOCKET_PATH_MAX
    if sys.platform.startswith("linux") and short_tmp:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(list(preload))
        return ctx
    return multiprocessing.get_context("spawn")


def start_worker(
    caller: int, temp_dir: str | None, initializer: Callable[..., None] | None, initargs: tuple[Any, ...]
) -> None:
    """A pool worker's start: it exits when its caller ends, then runs the caller's initializer."""
    exit_with_caller(caller, temp_dir)
    if initializer is not None:
        initializer(*initargs)


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Worker processes started inside never see a signal sent to the whole process group: SIGINT
    (a terminal's Ctrl-C) and SIGTERM (`timeout`, `kill -- -PGID`) are blocked in this thread while
    they start, and a child inherits the mask (a forkserver keeps it, and passes it on to the
    workers it forks; each worker then leaves the group: daemon.protect.pool.ignore_interrupts). A
    worker would otherwise die mid-file, or with a KeyboardInterrupt traceback; the caller decides
    when to stop. A signal for this process meanwhile is held, not lost: it arrives at the unblock."""
    if not hasattr(signal, "pthread_sigmask"):  # not POSIX
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def bounded_map(
    fn: Callable[..., R],
    calls: Sequence[tuple[Any, ...]],
    workers: int,
    died: Callable[[int], R],
    *,
    on_done: Callable[[int, R], None] | None = None,
    mp_context: multiprocessing.context.BaseContext | None = None,
    initializer: Callable[..., None] | None = None,
    initargs: tuple[Any, ...] = (),
    weights: Sequence[int] | None = None,
    budget: int | None = None,
    stop: Callable[[], bool] | None = None,
) -> list[R]:
    """fn(*call) for every call in a pool of `workers` processes with at most 2 x workers calls in
    flight; the results in the order of calls. died(i) stands for the result of call i when its
    worker process died (a dead worker breaks the pool: every call not finished by then gets
    died(i)). on_done(i, result) runs in this process as each call finishes (progress).
    weights/budget: the calls in flight never weigh more than budget together (bytes of memory,
    say), except one call alone that weighs more.
    stop(): checked as calls finish (and every STOP_POLL_S); once true, no call starts any more,
    the queued ones are cancelled and those running finish: the results are those that ran."""
    results: list[R | None] = [None] * len(calls)
    weight = list(weights) if weights is not None else [0] * len(calls)
    in_flight = [0]  # their total weight

    def finish(i: int, result: R) -> None:
        results[i] = result
        if on_done is not None:
            on_done(i, result)

    pending: dict[Future[R], int] = {}
    nxt = [0]  # the next call to submit (in order)
    context = mp_context or pool_context()
    # Workers end with this process even when it is killed outright (poisoner.pool_exit).
    temp_dir = claim_temp_dir() if context.get_start_method() == "forkserver" else None
    start = (os.getpid(), temp_dir, initializer, initargs)
    with ProcessPoolExecutor(workers, mp_context=context, initializer=start_worker, initargs=start) as pool:

        def submit_next() -> bool:
            i = nxt[0]
            if i >= len(calls) or len(pending) >= 2 * workers:
                return False
            if budget is not None and pending and in_flight[0] + weight[i] > budget:
                return False  # waits for memory to be released
            nxt[0] += 1
            in_flight[0] += weight[i]
            pending[pool.submit(fn, *calls[i])] = i
            return True

        with interrupts_held():  # the workers start on these first submits
            while submit_next():
                pass
        while pending:
            done, _ = wait(pending, timeout=STOP_POLL_S if stop else None, return_when=FIRST_COMPLETED)
            stopping = stop is not None and stop()
            if stopping:  # the calls not started yet never run; the running ones finish
                nxt[0] = len(calls)
                for fut in pending:
                    fut.cancel()
            for fut in done:
                i = pending.pop(fut)
                in_flight[0] -= weight[i]
                if fut.cancelled():
                    continue
                try:
                    finish(i, fut.result())
                except BrokenProcessPool:
                    if not stopping:  # stopping: a worker killed with its caller is not run again
                        finish(i, died(i))
            if stopping:  # cancelled futures never complete: drop them, wait only for running ones
                for fut in [f for f in pending if f.cancelled()]:
                    in_flight[0] -= weight[pending.pop(fut)]
            try:
                while submit_next():
                    pass
            except BrokenProcessPool:
                for j in range(nxt[0], len(calls)):  # the pool is gone: the rest are reported, not raised
                    finish(j, died(j))
                nxt[0] = len(calls)
    return [r for r in results if r is not None]


def poison_many(
    pairs: Iterable[tuple[Path, Path]],
    spec: PatchSpec,
    *,
    workers: int | None = None,
    markers: Mapping[Path, Marker] | None = None,
    keep_location: bool = False,
    max_pixels: int | None = None,
    on_done: Callable[[BatchResult], None] | None = None,
) -> list[BatchResult]:
    """Poison every (src, dst) pair (src == dst: in place, atomically). Returns one BatchResult
    per pair, in the order given; on_done is called in this process as each file finishes (for
    progress). markers maps a src path to its provenance marker."""
    jobs = [(Path(s), Path(d)) for s, d in pairs]
    markers = markers or {}
    n = default_workers(len(jobs)) if workers is None else max(1, min(workers, len(jobs) or 1))
    calls = [(src, dst, spec, markers.get(src), keep_location, max_pixels) for src, dst in jobs]
    if n == 1:
        results = []
        for call in calls:
            results.append(_poison_one(*call))
            if on_done is not None:
                on_done(results[-1])
        return results

    def died(i: int) -> BatchResult:
        src, dst = jobs[i]
        return BatchResult(src, dst, None, f"{src.name}: worker process died")

    return bounded_map(
        _poison_one, calls, n, died, on_done=(lambda _i, r: on_done(r)) if on_done is not None else None
    )
