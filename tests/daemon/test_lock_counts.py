"""The counts behind `ppd poison`'s Ctrl-C line (daemon.locks.file_in_progress, shared with a pool's
workers): a worker killed while it held their shared lock must not hang the others' files, as the counts
only shape a message. A real child process holding a real multiprocessing lock, killed."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time

from daemon import locks


def _hold(lock, ready) -> None:  # type: ignore[no-untyped-def]
    lock.acquire()
    ready.set()
    time.sleep(60)


def test_a_worker_killed_holding_the_shared_lock_leaves_the_others_going() -> None:
    context = multiprocessing.get_context("spawn")
    counts, lock, ready = context.RawArray("i", 2), context.Lock(), context.Event()
    holder = context.Process(target=_hold, args=(lock, ready))
    holder.start()
    try:
        assert ready.wait(60)
        os.kill(holder.pid, signal.SIGKILL)  # dies with the lock held
        holder.join(10)
        started = time.monotonic()
        with locks.counts_shared(counts, lock), locks.file_in_progress():
            took = time.monotonic() - started
        assert took < locks.COUNT_LOCK_S + 1.0, took  # before: blocked for good
        assert list(counts) == [0, 0]  # not counted, and the message stays as it was
    finally:
        if holder.is_alive():
            holder.kill()
    with locks.file_in_progress():  # this process's own counts again, its own lock free
        assert not locks.waiting_to_leave()
