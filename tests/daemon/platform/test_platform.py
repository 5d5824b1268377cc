"""daemon.platform (Linux): an inotify queue overflow reaches ppd by the kernel's own IN_Q_OVERFLOW
event, never by watchdog's log text; and the /proc, mountinfo and FICLONE helpers on real files."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
from watchdog.observers.inotify_c import CallbackId, InotifyConstants, InotifyEvent, WatchDescriptor

from daemon.platform import fd_path, mounts_of_device, overflow_aware_inotify, reflink, writers_of

MAX_QUEUED = Path("/proc/sys/fs/inotify/max_queued_events")
REPO = Path(__file__).resolve().parents[3]


class _Quiet:
    """A watch callback that keeps the events it is given (the inotify reader's side)."""

    def __init__(self) -> None:
        self.events: list[InotifyEvent] = []
        self.overflows = 0

    def on_event(self, event: InotifyEvent) -> None:
        self.events.append(event)

    def on_watch_deleted(self, wd: WatchDescriptor) -> None:
        pass

    def on_queue_overflow(self) -> None:
        self.overflows += 1

    def on_events_lost(self) -> None:
        """watchdog 7.1's second overflow call (after every callback's on_queue_overflow; 7.0 has none)."""


def test_a_real_inotify_queue_overflow_calls_on_overflow(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The reader is not running (a consumer that is blocked): more events than the kernel queues
    are made, so the kernel drops the rest and queues IN_Q_OVERFLOW; reading the queue as the
    reader thread does calls on_overflow. No log record is consulted (logging is switched off)."""
    limit = int(MAX_QUEUED.read_text())
    if limit > 200_000:
        pytest.skip(f"max_queued_events is {limit}: too many files to make here")
    seen: list[bool] = []
    inotify = overflow_aware_inotify(lambda: seen.append(True))  # not started: nobody reads
    callback = _Quiet()
    mask = InotifyConstants.IN_CREATE | InotifyConstants.IN_DELETE
    inotify.add_callback(os.fsencode(tmp_path), mask, callback, CallbackId(1))
    try:
        for i in range(limit // 2 + 100):  # two events a file, distinct names: none coalesced
            name = tmp_path / f"f{i}"
            name.touch()
            name.unlink()
        logging.disable(logging.CRITICAL)  # the signal must not be a log message
        try:
            for _ in range(10_000):
                for event in inotify.read_events():
                    inotify.handle_event(event)
                if seen:
                    break
        finally:
            logging.disable(logging.NOTSET)
    finally:
        inotify.close()
    assert seen == [True]  # one overflow, reported once
    assert callback.overflows == 1  # watchdog's own handling still runs after ppd's
    assert len(callback.events) == limit  # the kernel queued exactly its limit, then the overflow
    assert not [r for r in caplog.records if "verflow" in r.getMessage()]


def test_only_the_overflow_event_calls_on_overflow() -> None:
    """An ordinary event is handed on untouched; only IN_Q_OVERFLOW is an overflow."""
    seen: list[bool] = []
    inotify = overflow_aware_inotify(lambda: seen.append(True))
    try:
        inotify.handle_event(InotifyEvent(1, InotifyConstants.IN_CREATE, 0, b"a.jpg"))
        assert seen == []
        inotify.handle_event(InotifyEvent(-1, InotifyConstants.IN_Q_OVERFLOW, 0, b""))
        assert seen == [True]
    finally:
        inotify.close()


def test_fd_path_reaches_the_opened_inode_after_a_rename(tmp_path: Path) -> None:
    first = tmp_path / "a.jpg"
    first.write_bytes(b"original")
    fd = os.open(first, os.O_RDONLY)
    try:
        first.rename(tmp_path / "b.jpg")
        first.write_bytes(b"swapped in")  # a new file under the old name
        assert fd_path(fd).read_bytes() == b"original"
    finally:
        os.close(fd)


def test_writers_of_sees_this_process_writing_and_not_reading(tmp_path: Path) -> None:
    photo = tmp_path / "a.jpg"
    photo.write_bytes(b"x")
    with photo.open("rb"):
        assert writers_of(photo.stat(), fresh=True) == []
    with photo.open("ab"):
        assert writers_of(photo.stat(), fresh=True) == [os.getpid()]


def test_mounts_of_device_finds_the_mount_holding_a_folder(tmp_path: Path) -> None:
    mounts = mounts_of_device(os.stat(tmp_path).st_dev)
    assert mounts, "/proc/self/mountinfo names no mount of the temporary folder's device"
    assert any(m == tmp_path or m in tmp_path.resolve().parents for m, _t, _s in mounts)
    lengths = [len(str(m)) for m, _t, _s in mounts]
    assert lengths == sorted(lengths, reverse=True)  # the longest (innermost) mount point first


def test_reflink_clones_or_refuses_leaving_the_copy_empty(tmp_path: Path) -> None:
    """FICLONE on whatever the temporary folder is: a clone holds the same bytes; a refusal is an
    OSError and leaves the destination empty (the vault then copies another way)."""
    src, dst = tmp_path / "src", tmp_path / "dst"
    src.write_bytes(b"kept original" * 1000)
    dst.touch()
    s, d = os.open(src, os.O_RDONLY), os.open(dst, os.O_WRONLY)
    try:
        try:
            reflink(d, s)
        except OSError:
            assert dst.read_bytes() == b""
        else:
            assert dst.read_bytes() == src.read_bytes()
    finally:
        os.close(s)
        os.close(d)


_WHERE_A_BLOCK_LIVES = """
import sys
import numpy as np
from daemon.platform import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
block = np.empty(30 << 20, np.uint8)  # 30 MiB: over glibc's default threshold, under the one set
at = block.ctypes.data
for line in open("/proc/self/maps"):
    lo, hi = (int(x, 16) for x in line.split()[0].split("-"))
    if lo <= at < hi:
        print("heap" if line.rstrip().endswith("[heap]") else "own mapping")
"""


@pytest.mark.skipif(not hasattr(os, "confstr") or not os.confstr("CS_GNU_LIBC_VERSION"), reason="not glibc")
def test_pixel_work_keeps_big_blocks_on_the_heap() -> None:
    """keep_freed_memory (issue 30): a 30 MiB array comes from malloc's heap, whose freed memory the
    next photo reuses, not from a mapping of its own that the kernel faults in and zeroes each time."""

    def where(mode: str) -> str:
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        proc = subprocess.run([sys.executable, "-c", _WHERE_A_BLOCK_LIVES, mode], capture_output=True,
                              text=True, timeout=60, cwd=REPO, env=env)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        return proc.stdout.strip()

    assert where("default") == "own mapping"
    assert where("keep") == "heap"
