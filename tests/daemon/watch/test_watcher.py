"""The watch daemon with the real inotify observer on real temporary folders.

Most tests run WatchDaemon in a thread of the test process (same code `ppd watch` runs, minus
signal handling); the SIGTERM and sys.modules tests run `ppd watch` as a real subprocess.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from daemon.paths import AppPaths
from daemon.protect.one_file import AppContext
from daemon.states import FileState
from daemon.store import Store
from daemon.watch.notify import SystemdNotifier, notify_socket_address, watchdog_interval
from daemon.watch.outbox import WatchOptions, ignore_reason, is_candidate, scan_outbox
from daemon.watch.watcher import DaemonOptions, WatchDaemon
from daemon.watch.workers import PoolOptions, WorkerPool
from poisoner.atomic import TEMP_PREFIX
from poisoner.media import MEDIA_SUFFIXES
from testkit.daemon_proc import wait_for
from testkit.photos import write_image

REPO = Path(__file__).resolve().parents[3]

# Fast settings for tests: the defaults (2 s debounce) are for real writers.
FAST = DaemonOptions(
    watch=WatchOptions(settle_s=0.3, moved_settle_s=0.05, unclosed_settle_s=3.0),
    workers=2,
    queue_size=16,  # small: the 200-file tests overflow into the pending set
    tmp_grace_s=1.0,
    verify=False,
    incomplete_wait_s=2.0,  # an incomplete file is waited for this long (unchanged) before quarantine
)


# ---- helpers ----------------------------------------------------------------------------------
def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def wait_idle(daemon: WatchDaemon, quiet: float = 0.6, timeout: float = 60.0) -> None:
    """Nothing settling, queued or running, for `quiet` seconds in a row."""
    deadline = time.monotonic() + timeout
    quiet_since = None
    while time.monotonic() < deadline:
        stats = daemon.pool.stats()
        busy = daemon.watcher.armed_count or stats.queued or stats.pending or stats.in_flight
        if busy:
            quiet_since = None
        elif quiet_since is None:
            quiet_since = time.monotonic()
        elif time.monotonic() - quiet_since >= quiet:
            return
        time.sleep(0.05)
    raise AssertionError("daemon never went idle")


def store_of(env: dict[str, Path]) -> Store:
    return Store(env["data"] / "ppd.sqlite3")


def rows_by_path(store: Store) -> dict[str, dict]:
    return {r["path"]: r for ds in store.datasets() for r in store.files(ds["name"])}


def protected_event_counts(store: Store) -> dict[str, int]:
    counts: dict[str, int] = {}
    for ev in store.events(limit=100_000):
        if ev["kind"] == "patched":
            counts[ev["path"]] = counts.get(ev["path"], 0) + 1
    return counts


def assert_protected_once(env: dict[str, Path], files: list[Path], originals: dict[Path, str]) -> None:
    """Each file: one patched row and event, disk = poisoned sha, vault = original."""
    store = store_of(env)
    rows = rows_by_path(store)
    events = protected_event_counts(store)
    vault = env["data"] / "vault"
    for f in files:
        row = rows.get(str(f))
        assert row is not None, f"no row for {f.name}"
        assert row["state"] == FileState.PATCHED, (f.name, row["state"], row["error"])
        assert events.get(str(f)) == 1, (f.name, events.get(str(f)))
        assert row["original_sha256"] == originals[f], f.name
        assert sha(f) == row["poisoned_sha256"] != originals[f]
        blob = vault / row["original_sha256"][:2] / row["original_sha256"]
        assert sha(blob) == originals[f]
    store.close()


@contextmanager
def running(env: dict[str, Path], options: DaemonOptions = FAST) -> Iterator[WatchDaemon]:
    ctx = AppContext.open(AppPaths.from_env())
    daemon = WatchDaemon(ctx, options)
    thread = threading.Thread(target=daemon.run, name="test-daemon")
    thread.start()
    try:
        assert daemon.ready.wait(30), "daemon did not become ready"
        yield daemon
    finally:
        daemon.request_stop()
        thread.join(60)
        ctx.close()
    assert not thread.is_alive()


def staged(tmp_path: Path, n: int, prefix: str = "img") -> tuple[list[Path], dict[str, str]]:
    """n images written outside the outbox, with their sha256 by name."""
    stage = tmp_path / f"stage-{prefix}"
    files = [write_image(stage / f"{prefix}{i:03d}.png", seed=i) for i in range(n)]
    return files, {f.name: sha(f) for f in files}


# ---- names ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name, ignored",
    [
        ("photo.png", False),
        ("IMG_0001.JPG", False),
        ("photo.png.crdownload", True),
        ("photo.jpg.part", True),
        ("photo.png~", True),
        (".photo.png.swp", True),
        ("photo.png.swp", True),
        ("photo.tmp", True),
        (".hidden.png", True),
        (f"{TEMP_PREFIX}abc.png", True),
        ("~$IMG_1.jpg", True),
        ("#IMG_1.jpg#", True),  # Emacs's auto-save
        ("#IMG_1.jpg", False),  # a photo (a black-box review, F4: left by the daemon, patched by poison)
    ],
)
def test_ignore_reason(name: str, ignored: bool) -> None:
    assert (ignore_reason(name) is not None) is ignored


def test_is_candidate_needs_media_suffix_and_no_dot_folder(tmp_path: Path) -> None:
    suffixes = MEDIA_SUFFIXES
    assert is_candidate(tmp_path, tmp_path / "ds" / "a.jpg", suffixes)
    assert is_candidate(tmp_path, tmp_path / "ds" / "clip.mp4", suffixes)
    assert not is_candidate(tmp_path, tmp_path / "ds" / "notes.txt", suffixes)
    assert not is_candidate(tmp_path, tmp_path / ".Trash-1000" / "a.jpg", suffixes)
    assert not is_candidate(tmp_path, tmp_path.parent / "elsewhere.jpg", suffixes)


def test_media_table_loads_no_codec() -> None:
    # The event layer reads the suffix table on every event; it must not pull PyAV, numpy or PIL in.
    code = "import sys, poisoner.media; print(sorted({'av', 'numpy', 'PIL'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.strip() == "[]"


def test_scan_removes_only_old_ppd_temporaries(tmp_path: Path) -> None:
    old = tmp_path / "ds" / f"{TEMP_PREFIX}000000000001.png"
    young = tmp_path / "ds" / f"{TEMP_PREFIX}000000000002.png"
    keep = write_image(tmp_path / "ds" / "a.png", 1)
    for p in (old, young):
        p.write_bytes(b"partial")
    os.utime(old, (time.time() - 3600, time.time() - 3600))
    result = scan_outbox(tmp_path, MEDIA_SUFFIXES, tmp_grace_s=60)
    assert result.files == [keep]
    assert result.stale_temps_removed == [old] and not old.exists()
    assert result.young_temps == [young] and young.exists()


# ---- worker pool ------------------------------------------------------------------------------
def test_pool_never_blocks_dedups_and_runs_each_path_once() -> None:
    gate = threading.Event()
    seen: list[Path] = []
    lock = threading.Lock()

    def handle(path: Path) -> None:
        gate.wait()
        with lock:
            seen.append(path)

    pool = WorkerPool(handle, PoolOptions(workers=2, queue_size=8))
    pool.start()
    paths = [Path(f"/x/{i}.png") for i in range(10_000)]
    accepted = [pool.submit(p) for p in paths]  # workers are stuck: this must still return
    duplicates = [pool.submit(p) for p in paths[100:200]]
    stats = pool.stats()
    assert all(accepted) and not any(duplicates)
    assert stats.queued <= 8 and stats.queued + stats.pending + stats.in_flight == 10_000
    gate.set()
    assert pool.wait_idle(60)
    pool.stop()
    assert sorted(seen) == sorted(paths)


def test_pool_reruns_a_path_submitted_while_in_flight() -> None:
    started, release = threading.Event(), threading.Event()
    calls: list[Path] = []

    def handle(path: Path) -> None:
        calls.append(path)
        started.set()
        release.wait()

    pool = WorkerPool(handle, PoolOptions(workers=1, queue_size=4))
    pool.start()
    pool.submit(Path("/a"))
    assert started.wait(5)
    pool.submit(Path("/a"))  # content may have changed under the worker
    pool.submit(Path("/a"))  # ... but twice is still once more
    release.set()
    assert pool.wait_idle(5)
    pool.stop()
    assert calls == [Path("/a"), Path("/a")]


def test_pool_overflow_asks_for_a_rescan_once_drained() -> None:
    gate = threading.Event()
    pool = WorkerPool(lambda p: gate.wait(), PoolOptions(workers=1, queue_size=2, max_pending=3))
    pool.start()
    results = [pool.submit(Path(f"/{i}")) for i in range(10)]
    assert results.count(False) > 0 and pool.stats().overflowed
    assert not pool.take_overflow()  # not drained yet
    gate.set()
    assert pool.wait_idle(5)
    assert pool.take_overflow() and not pool.take_overflow()
    pool.stop()


def test_pool_stop_finishes_in_flight_and_returns_the_rest() -> None:
    started, release = threading.Event(), threading.Event()
    finished: list[Path] = []

    def handle(path: Path) -> None:
        started.set()
        release.wait(30)  # held until stop() has dropped the queue, however slow this machine
        finished.append(path)

    pool = WorkerPool(handle, PoolOptions(workers=1, queue_size=4))
    pool.start()
    for i in range(5):
        pool.submit(Path(f"/{i}"))
    assert started.wait(5)

    def release_once_stopping() -> None:
        wait_for(lambda: pool.stats().queued + pool.stats().pending == 0, 30, "stop() to drop the queue")
        release.set()

    releaser = threading.Thread(target=release_once_stopping)
    releaser.start()
    dropped = pool.stop()
    releaser.join(30)
    assert finished == [Path("/0")]  # the one in flight completed before stop returned
    assert sorted(dropped) == [Path(f"/{i}") for i in range(1, 5)]
    assert not pool.submit(Path("/late"))


# ---- sd_notify --------------------------------------------------------------------------------
@pytest.mark.parametrize("abstract", [False, True])
def test_notify_sends_datagrams(tmp_path: Path, abstract: bool) -> None:
    name = f"@ppd-test-{os.getpid()}-{time.monotonic_ns()}" if abstract else str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name[1:] if abstract else name)
    sock.settimeout(5)
    try:
        notifier = SystemdNotifier({"NOTIFY_SOCKET": name})
        assert notifier.ready("protected 0")
        assert notifier.watchdog() and notifier.stopping()
        got = [sock.recv(4096).decode() for _ in range(3)]
    finally:
        sock.close()
    assert got == ["READY=1\nSTATUS=protected 0", "WATCHDOG=1", "STOPPING=1"]


def test_notify_never_blocks_on_a_receiver_that_stopped_reading(tmp_path: Path) -> None:
    path = tmp_path / "full.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    notifier = SystemdNotifier({"NOTIFY_SOCKET": str(path)})
    results: list[bool] = []
    # More than the kernel queues (net.unix.max_dgram_qlen: 10 here, 512 where systemd sets it)
    qlen = Path("/proc/sys/net/unix/max_dgram_qlen")
    count = max(2000, int(qlen.read_text()) + 100) if qlen.exists() else 2000
    sender = threading.Thread(target=lambda: results.extend(notifier.status(str(i)) for i in range(count)))
    sender.start()
    sender.join(30)  # a blocking send would hang here forever
    sock.close()
    assert not sender.is_alive() and len(results) == count
    assert results[0] and not all(results)  # the first got through; the overflow was dropped


def test_ready_and_stopping_wait_for_room_in_a_full_queue(tmp_path: Path) -> None:
    """systemd fails a start whose READY=1 never arrives: these two wait for a slow reader."""
    path = tmp_path / "slow.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    notifier = SystemdNotifier({"NOTIFY_SOCKET": str(path)})
    queued = 0
    while notifier.status(str(queued)):  # fill the receiver's queue
        queued += 1
    assert not notifier.status("dropped")

    def read_late() -> None:
        time.sleep(0.3)
        for _ in range(queued):
            sock.recv(4096)

    reader = threading.Thread(target=read_late)
    reader.start()
    assert notifier.stopping("bye")  # waited for the reader instead of being dropped
    reader.join(10)
    sock.settimeout(5)
    assert sock.recv(4096) == b"STOPPING=1\nSTATUS=bye"
    sock.close()


def test_notify_is_a_no_op_outside_systemd() -> None:
    assert notify_socket_address({}) is None
    assert not SystemdNotifier({}).ready()


def test_watchdog_interval_is_half_and_only_for_the_named_pid() -> None:
    assert watchdog_interval({"WATCHDOG_USEC": "30000000"}) == 15.0
    assert watchdog_interval({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": str(os.getpid())}) == 15.0
    assert watchdog_interval({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": "1"}) is None
    assert watchdog_interval({}) is None


# ---- the daemon, live -------------------------------------------------------------------------
def test_200_files_dropped_by_copy_are_each_protected_once(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    sources, originals = staged(tmp_path, 200)
    dest = ppd_env["outbox"] / "copied"
    dest.mkdir()
    with running(ppd_env) as daemon:
        targets = [Path(shutil.copyfile(src, dest / src.name)) for src in sources]
        wait_for(lambda: daemon.counts.patched >= 200, 90, "200 protected")
        wait_idle(daemon)
        assert daemon.counts.failed == 0 and daemon.counts.patched == 200
    assert_protected_once(ppd_env, targets, {t: originals[t.name] for t in targets})


def test_200_files_renamed_in_are_each_protected_once(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    sources, originals = staged(tmp_path, 200, prefix="mv")
    dest = ppd_env["outbox"] / "moved"
    dest.mkdir()
    with running(ppd_env) as daemon:
        targets = []
        for src in sources:
            os.rename(src, dest / src.name)  # same filesystem: a moved-in event
            targets.append(dest / src.name)
        wait_for(lambda: daemon.counts.patched >= 200, 90, "200 protected")
        wait_idle(daemon)
        assert daemon.counts.patched == 200
    assert_protected_once(ppd_env, targets, {t: originals[t.name] for t in targets})


def _slow_write(data: bytes, target: Path, seconds: float, chunks: int, reopen: bool) -> None:
    """Write data in chunks over `seconds`; reopen=True closes after every chunk (a writer
    that closes early and appends later)."""
    pause = seconds / chunks
    step = -(-len(data) // chunks)
    pieces = [data[i * step : (i + 1) * step] for i in range(chunks)]
    if reopen:
        for i, piece in enumerate(pieces):
            with open(target, "ab" if i else "wb") as fh:
                fh.write(piece)
            time.sleep(pause)
        return
    with open(target, "wb") as fh:
        for piece in pieces:
            fh.write(piece)
            fh.flush()
            time.sleep(pause)


@pytest.mark.parametrize("reopen", [False, True])
def test_slow_writer_is_protected_once_when_complete(
    ppd_env: dict[str, Path], tmp_path: Path, reopen: bool
) -> None:
    src = write_image(tmp_path / "big.png", seed=7, size=512)
    data = src.read_bytes()
    target = ppd_env["outbox"] / "slow" / "big.png"
    target.parent.mkdir()
    # Pauses (0.25 s) shorter than the debounce (0.5 s) for the writer that closes early.
    options = DaemonOptions(watch=WatchOptions(settle_s=0.5, moved_settle_s=0.05), verify=False)
    with running(ppd_env, options) as daemon:
        _slow_write(data, target, seconds=3.0, chunks=12, reopen=reopen)
        wait_for(lambda: daemon.counts.patched >= 1, 30, "slow file protected")
        wait_idle(daemon)
        assert daemon.counts.failed == 0, "processed before it was complete"
    assert_protected_once(ppd_env, [target], {target: hashlib.sha256(data).hexdigest()})


@pytest.mark.slow
@pytest.mark.parametrize("n", [20])
def test_many_slow_writers_at_once(ppd_env: dict[str, Path], tmp_path: Path, n: int) -> None:
    datas = [write_image(tmp_path / f"s{i}.png", seed=100 + i, size=384).read_bytes() for i in range(n)]
    targets = [ppd_env["outbox"] / "slow" / f"s{i}.png" for i in range(n)]
    targets[0].parent.mkdir()
    options = DaemonOptions(watch=WatchOptions(settle_s=0.8, moved_settle_s=0.05), verify=False)
    with running(ppd_env, options) as daemon:
        writers = [
            threading.Thread(target=_slow_write, args=(d, t, 3.0, 10, i % 2 == 0))
            for i, (d, t) in enumerate(zip(datas, targets, strict=True))
        ]
        for w in writers:
            w.start()
        for w in writers:
            w.join()
        wait_for(lambda: daemon.counts.patched >= n, 60, f"{n} protected")
        wait_idle(daemon)
        assert daemon.counts.failed == 0
    assert_protected_once(
        ppd_env, targets, {t: hashlib.sha256(d).hexdigest() for t, d in zip(targets, datas, strict=True)}
    )


@pytest.mark.slow
def test_flood_of_10k_files(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    stage = tmp_path / "flood"
    seed_img = write_image(tmp_path / "one.png", 1, size=128).read_bytes()
    stage.mkdir()
    n = 10_000
    for i in range(n):  # distinct content: each file's last bytes differ (PNG ignores trailing data)
        (stage / f"f{i:05d}.png").write_bytes(seed_img + i.to_bytes(4, "big"))
    options = DaemonOptions(
        watch=WatchOptions(settle_s=0.3, moved_settle_s=0.05), queue_size=64, verify=False
    )
    with running(ppd_env, options) as daemon:
        os.rename(stage, ppd_env["outbox"] / "flood")  # one folder moved in: 10k complete files
        wait_for(lambda: daemon.counts.patched + daemon.counts.failed >= n, 600, "10k processed")
        wait_idle(daemon)
    rows = rows_by_path(store_of(ppd_env))
    assert sum(r["state"] == FileState.PATCHED for r in rows.values()) == n


def test_ignored_names_until_renamed(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    ds = ppd_env["outbox"] / "dl"
    ds.mkdir()
    with running(ppd_env) as daemon:
        ignored = [
            write_image(ds / "photo.png.crdownload", 1),
            write_image(ds / "b.jpg.part", 2),
            write_image(ds / ".hidden.png", 3),
            write_image(ds / "c.png~", 4),
            write_image(ds / "d.png.swp", 5),
            write_image(ds / "e.tmp", 6),
            write_image(ds / f"{TEMP_PREFIX}x.png", 7),
        ]
        before = {p: sha(p) for p in ignored}
        time.sleep(FAST.watch.settle_s + 0.3)
        wait_idle(daemon)
        assert daemon.counts.patched == 0 and rows_by_path(store_of(ppd_env)) == {}
        final = ds / "photo.png"
        original = before[ignored[0]]
        os.rename(ignored[0], final)  # the browser finishes the download
        wait_for(lambda: daemon.counts.patched >= 1, 20, "renamed download protected")
        wait_idle(daemon)
        assert daemon.counts.patched == 1
    assert_protected_once(ppd_env, [final], {final: original})
    for p in ignored[1:]:
        assert sha(p) == before[p]


def test_replaced_file_is_protected_again_and_own_writes_never_retrigger(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    target = ppd_env["outbox"] / "edit" / "a.png"
    with running(ppd_env) as daemon:
        write_image(target, 1)
        wait_for(lambda: daemon.counts.patched >= 1, 20, "first version")
        wait_idle(daemon, quiet=1.0)
        assert daemon.counts.patched == 1 and daemon.counts.unchanged == 0  # no echo of its own rename
        # New content replaced by rename (editors), then overwritten in place (cp over it).
        write_image(tmp_path / "v2.png", 2)
        os.replace(tmp_path / "v2.png", target)
        wait_for(lambda: daemon.counts.patched >= 2, 20, "second version")
        v3 = write_image(tmp_path / "v3.png", 3)
        shutil.copyfile(v3, target)  # truncate + write + close on the same inode
        wait_for(lambda: daemon.counts.patched >= 3, 20, "third version")
        wait_idle(daemon, quiet=1.0)
        assert daemon.counts.patched == 3
    store = store_of(ppd_env)
    row = store.file(target)
    assert row["state"] == FileState.PATCHED and row["original_sha256"] == sha(v3)
    assert protected_event_counts(store)[str(target)] == 3
    assert sha(target) == row["poisoned_sha256"]


def test_restart_catch_up(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    ds = ppd_env["outbox"] / "shoot"
    keep, change, delete = (
        write_image(ds / f"{n}.png", i) for i, n in enumerate(("keep", "change", "delete"))
    )
    with running(ppd_env) as daemon:
        wait_for(lambda: daemon.counts.patched >= 3, 30, "initial scan protects 3")
        wait_idle(daemon)
    keep_sha = sha(keep)
    # While the daemon is down: one added, one changed, one removed, a crash leftover.
    added = write_image(ds / "added.png", 10)
    write_image(change, 11)
    changed_original = sha(change)
    delete.unlink()
    leftover = ds / f"{TEMP_PREFIX}00000000c0de.png"
    leftover.write_bytes(b"half a png")
    os.utime(leftover, (time.time() - 60, time.time() - 60))
    with running(ppd_env) as daemon:
        wait_for(lambda: daemon.counts.patched >= 2 and daemon.counts.removed >= 1, 30, "catch-up")
        wait_idle(daemon)
        assert daemon.counts.patched == 2 and daemon.counts.removed == 1
    store = store_of(ppd_env)
    events = protected_event_counts(store)
    assert events[str(keep)] == 1 and sha(keep) == keep_sha  # untouched: not processed again
    assert events[str(added)] == 1 and store.file(added)["state"] == FileState.PATCHED
    assert events[str(change)] == 2 and store.file(change)["original_sha256"] == changed_original
    assert store.file(delete)["state"] == "removed"
    assert any(e["kind"] == "removed" and e["path"] == str(delete) for e in store.events(limit=1000))
    assert not leftover.exists()


def test_live_removal_and_folder_rename_are_recorded(ppd_env: dict[str, Path]) -> None:
    ds = ppd_env["outbox"] / "trip"
    files = [write_image(ds / f"{i}.png", i) for i in range(3)]
    with running(ppd_env) as daemon:
        wait_for(lambda: daemon.counts.patched >= 3, 30, "3 protected")
        wait_idle(daemon)
        files[0].unlink()
        wait_for(lambda: daemon.counts.removed >= 1, 20, "deletion recorded")
        poisoned = {f.name: sha(f) for f in files[1:]}
        os.rename(ds, ppd_env["outbox"] / "trip-renamed")
        wait_for(lambda: daemon.counts.removed >= 3, 20, "renamed folder's old paths recorded")
        wait_idle(daemon)
        assert daemon.counts.patched == 3  # ppd's own output is never poisoned twice
    store = store_of(ppd_env)
    assert all(store.file(f)["state"] == "removed" for f in files)
    for name, digest in poisoned.items():
        assert sha(ppd_env["outbox"] / "trip-renamed" / name) == digest
    # `ppd status`: the old name, its folder gone and its files all elsewhere, leaves the table (it
    # stayed there as "3 files, nothing patched" for ever: a black-box review) and is named once
    from typer.testing import CliRunner

    from daemon.cli import app

    output = CliRunner().invoke(app, ["status"]).output
    rows = [line.split("│")[1].strip() for line in output.splitlines() if line.startswith("│")]
    assert "trip-renamed" in rows and "trip" not in rows, output
    said = " ".join(output.split())
    assert "not shown: 1 dataset(s) whose folder is gone, moved or deleted (trip)" in said


def test_bad_files_fail_cleanly_and_the_daemon_keeps_going(ppd_env: dict[str, Path]) -> None:
    ds = ppd_env["outbox"] / "bad"
    ds.mkdir()
    with running(ppd_env) as daemon:
        fake = ds / "fake.png"
        fake.write_text("this is not a PNG")
        empty = ds / "empty.jpg"
        empty.write_bytes(b"")
        wait_for(lambda: daemon.counts.quarantined >= 2, 20, "two files quarantined")
        assert daemon.counts.failed == 0  # one count per file: quarantined, not failed as well
        good = write_image(ds / "good.png", 1)
        staged = write_image(ppd_env["outbox"].parent / "staging" / "readonly.png", 2)
        staged.chmod(0o444)  # before it arrives: a chmod during the patch would race its replace
        readonly = ds / "readonly.png"
        os.rename(staged, readonly)
        wait_for(lambda: daemon.counts.patched >= 2, 20, "good files after bad ones")
        wait_idle(daemon)
        assert daemon.watcher.is_alive()
    store = store_of(ppd_env)
    quarantine = ppd_env["outbox"].parent / "ppd-quarantine" / "bad"
    for bad in (fake, empty):  # failed, then moved out of the outbox whole
        row = store.file(bad)
        assert row["state"] == FileState.QUARANTINED and row["error"] and "\n" not in row["error"]
        assert not bad.exists()
    assert (quarantine / "fake.png").read_text() == "this is not a PNG"
    assert (quarantine / "empty.jpg").read_bytes() == b""
    # `ppd status bad --failed` says where each went (a black-box review: only the watch log did)
    from daemon.cli.status_cmd import failed_lines
    from daemon.cli.status_queries import dataset_status, failed_files

    ctx = AppContext.open(AppPaths.from_env())
    try:
        d = dataset_status(ctx, "bad") | {"failed_files": failed_files(ctx, "bad")}
    finally:
        ctx.close()
    said = " ".join(failed_lines(d))
    assert f"(quarantined: moved to {quarantine / 'fake.png'})" in said, said
    assert store.file(good)["state"] == FileState.PATCHED
    assert store.file(readonly)["state"] == FileState.PATCHED
    assert readonly.stat().st_mode & 0o777 == 0o444  # permission bits kept by the atomic replace


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads files whatever their permission bits")
def test_unreadable_file_fails_with_a_reason(ppd_env: dict[str, Path]) -> None:
    secret = write_image(ppd_env["outbox"] / "locked" / "secret.png", 1)
    secret.chmod(0o000)
    with running(ppd_env) as daemon:
        wait_for(lambda: daemon.counts.failed >= 1, 20, "failure recorded")
    row = store_of(ppd_env).file(secret)
    assert row["state"] == "failed" and "ermission" in row["error"]


def test_outbox_deleted_under_the_daemon_is_recreated_and_watched(ppd_env: dict[str, Path]) -> None:
    with running(ppd_env) as daemon:
        write_image(ppd_env["outbox"] / "a" / "one.png", 1)
        wait_for(lambda: daemon.counts.patched >= 1, 20, "first file")
        shutil.rmtree(ppd_env["outbox"])
        wait_for(lambda: ppd_env["outbox"].is_dir() and daemon.watcher.is_alive(), 20, "outbox recreated")
        wait_idle(daemon)
        later = write_image(ppd_env["outbox"] / "b" / "two.png", 2)
        wait_for(lambda: daemon.counts.patched >= 2, 20, "file in the recreated outbox")
        assert daemon.counts.removed >= 1  # one.png went with the old outbox
    assert store_of(ppd_env).file(later)["state"] == FileState.PATCHED


# ---- `ppd watch` as a real process ------------------------------------------------------------
def _ppd_command() -> list[str]:
    exe = Path(sys.executable).parent / "ppd"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "daemon.cli"]


def _listen(sock: socket.socket) -> tuple[list[str], threading.Event, threading.Thread]:
    """Read sd_notify messages all along, as systemd does (the socket queues only ~10 datagrams),
    until STOPPING=1 or the socket closes: (messages, stopping, the started reader)."""
    messages: list[str] = []
    stopping = threading.Event()

    def listen() -> None:
        with contextlib.suppress(OSError):
            while not stopping.is_set():
                messages.append(sock.recv(4096).decode())
                stopping.set() if messages[-1].startswith("STOPPING=1") else None

    listener = threading.Thread(target=listen, daemon=True)
    listener.start()
    return messages, stopping, listener


def _count_protected_else_original(
    env: dict[str, Path], store: Store, dest: Path, originals: dict[str, str]
) -> int:
    """Each file is its original (no row, or pending/failed) or protected (row, vault copy); how
    many are protected."""
    rows = rows_by_path(store)
    done = 0
    for name, original in originals.items():
        path = dest / name
        row = rows.get(str(path))
        digest = sha(path)
        if digest == original:
            assert row is None or row["state"] in ("pending", "failed"), (name, row)
            continue
        done += 1
        assert row is not None and row["state"] == FileState.PATCHED, name
        assert row["poisoned_sha256"] == digest, name
        blob = env["data"] / "vault" / original[:2] / original
        assert sha(blob) == original
    return done


def test_sigterm_mid_batch_leaves_every_file_original_or_protected(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    n = 40
    stage = tmp_path / "stage"
    sources = [write_image(stage / f"p{i:02d}.png", seed=i, size=640) for i in range(n)]
    originals = {s.name: sha(s) for s in sources}
    notify_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(notify_path))
    sock.settimeout(30)
    env = {
        **os.environ,
        "NOTIFY_SOCKET": str(notify_path),
        "WATCHDOG_USEC": "1000000",
        "PYTHONUNBUFFERED": "1",
    }
    proc = subprocess.Popen(
        [*_ppd_command(), "watch", "--no-verify", "--debounce", "0.1", "-j", "2"],
        env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    messages, stopping, listener = _listen(sock)
    try:
        wait_for(lambda: bool(messages), 30, "READY=1")
        assert messages[0].startswith("READY=1"), messages
        # The first ping comes half a WATCHDOG_USEC after READY; waited for here, because a fast
        # machine protects two files and gets SIGTERM before the main loop's first wake.
        wait_for(lambda: "WATCHDOG=1" in messages, 30, "a WATCHDOG=1 ping")
        dest = ppd_env["outbox"] / "batch"
        dest.mkdir()
        for s in sources:
            shutil.copyfile(s, dest / s.name)
        store = store_of(ppd_env)

        def protected() -> int:
            return sum(r["state"] == FileState.PATCHED for r in rows_by_path(store).values())

        wait_for(lambda: protected() >= 2, 60, "first files protected")
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
        stopping.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
        stopping.set()
        sock.close()
        listener.join(30)
    assert proc.returncode == 0, out
    assert messages[-1].startswith("STOPPING=1"), messages
    done = _count_protected_else_original(ppd_env, store, dest, originals)
    assert 0 < done < n, f"SIGTERM did not land mid-batch ({done}/{n} protected)"
    assert not list(dest.glob(f"{TEMP_PREFIX}*")), "temporary files left behind"
    assert "stopped:" in out


def test_daemon_process_stays_light(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The daemon never imports torch, pycolmap or scikit-image (idle RSS goal, crash safety)."""
    write_image(ppd_env["outbox"] / "ds" / "a.png", 1)
    script = """
import json, sys, threading
from daemon.cli import app  # what `ppd` imports
from daemon.paths import AppPaths
from daemon.protect.one_file import AppContext
from daemon.watch.watcher import DaemonOptions, WatchDaemon, WatchOptions
ctx = AppContext.open(AppPaths.from_env())
d = WatchDaemon(ctx, DaemonOptions(watch=WatchOptions(settle_s=0.1), verify=True))
t = threading.Thread(target=d.run); t.start()
d.ready.wait(30)
d.pool.wait_idle(60)
d.request_stop(); t.join(60)
print(json.dumps({"protected": d.counts.patched, "modules": sorted(sys.modules)}))
"""
    proc = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["protected"] == 1
    heavy = [m for m in report["modules"] if m.split(".")[0] in ("torch", "pycolmap", "skimage")]
    assert heavy == [], heavy
    # files are protected in worker processes (daemon.protect.pool): no decoder in the daemon's memory
    decoders = [m for m in report["modules"] if m.split(".")[0] in ("PIL", "av")]
    assert decoders == [], decoders
    # numpy only as sqlite_utils's own import (daemon.store), never for the poisoner
    assert "numpy" not in report["modules"] or "sqlite_utils" in report["modules"]
    assert "poisoner.formats" not in report["modules"] and "poisoner.blend" not in report["modules"]


def test_bad_config_is_one_line_and_exit_status_2(ppd_env: dict[str, Path]) -> None:
    """Bad input, 2 as in every command (it was 1): the unit's RestartPreventExitStatus does not
    restart a daemon every 5 s on a config only the user can fix."""
    (ppd_env["config"] / "config.toml").write_text("workers = 0\n")
    proc = subprocess.run(
        [*_ppd_command(), "watch"], cwd=REPO, capture_output=True, text=True, timeout=60, env=dict(os.environ)
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "workers" in lines[0] and "Traceback" not in proc.stderr


# ---- per-file worker processes (daemon.protect.pool) -------------------------------------------------
def _worker_pids() -> set[int]:
    """This process's child processes (the daemon's protect workers run under the test's process)."""
    pids: set[int] = set()
    for task in Path("/proc/self/task").iterdir():
        with contextlib.suppress(FileNotFoundError):
            pids |= {int(p) for p in (task / "children").read_text().split()}
    return pids


def test_worker_processes_exit_after_their_idle_period(ppd_env: dict[str, Path]) -> None:
    before = _worker_pids()
    options = dataclasses.replace(FAST, worker_idle_s=3.0)  # long enough to see it there first
    with running(ppd_env, options) as daemon:
        photo = write_image(ppd_env["outbox"] / "ds" / "a.png", 1)
        original = sha(photo)
        wait_for(lambda: daemon.counts.patched == 1, 60, "the photo protected")
        assert daemon.protectors.running() >= 1  # the worker that did it is still there
        assert _worker_pids() - before
        wait_for(lambda: daemon.protectors.running() == 0, 30, "idle workers to exit")
        # a later file starts a worker again
        second = write_image(ppd_env["outbox"] / "ds" / "b.png", 2)
        wait_for(lambda: daemon.counts.patched == 2, 60, "the second photo protected")
    assert_protected_once(ppd_env, [photo], {photo: original})
    assert sha(second) != sha(photo)


def test_a_worker_killed_mid_file_is_retried_once_isolated(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    big = write_image(tmp_path / "big.png", 7, size=2400)  # seconds of work: time to kill its worker
    original = sha(big)
    attempts = ppd_env["data"] / "attempts"
    killed: list[int] = []
    with running(ppd_env) as daemon:
        dest = ppd_env["outbox"] / "ds" / "big.png"
        dest.parent.mkdir()
        os.rename(big, dest)

        def kill_the_worker() -> bool:  # the attempt marker names the process doing the heavy work
            for marker in attempts.glob("*.json") if attempts.is_dir() else ():
                with contextlib.suppress(OSError, ValueError):
                    pid = json.loads(marker.read_text())["pid"]
                    if pid != os.getpid() and not killed:
                        os.kill(pid, signal.SIGKILL)
                        killed.append(pid)
            return bool(killed)

        wait_for(kill_the_worker, 60, "the worker to start on the file")
        wait_for(lambda: daemon.counts.patched + daemon.counts.failed >= 1, 120, "the retry")
        assert daemon.counts.patched == 1 and daemon.counts.quarantined == 0
    assert killed and killed[0] not in _worker_pids()
    assert_protected_once(ppd_env, [dest], {dest: original})
    assert not list(dest.parent.glob(f"{TEMP_PREFIX}*")), "temporary files left behind"


def test_a_file_waited_for_is_not_listed_as_failed(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """Found by a black-box review: while the daemon waited for an incomplete file's writer, its row
    said failed (`ppd status --failed` listed it) and the daemon's count said failed 0. The row now
    says it is waited for; the completed file is then patched once."""
    from daemon.cli.status_queries import dataset_status, failed_files
    from daemon.cli.status_steps import next_step_lines

    src = write_image(tmp_path / "big.png", seed=8, size=256)
    data = src.read_bytes()
    target = ppd_env["outbox"] / "trip" / "cut.png"
    target.parent.mkdir()
    options = dataclasses.replace(FAST, incomplete_wait_s=60.0)
    with running(ppd_env, options) as daemon:
        target.write_bytes(data[: len(data) // 2])  # a writer that paused half way
        wait_for(lambda: daemon.counts.skipped >= 1, 30, "the half file waited for")
        row = store_of(ppd_env).file(target)
        assert row is not None and row["state"] == FileState.SKIPPED, row
        assert "waiting for its writer" in (row["error"] or "")
        ctx = AppContext.open(AppPaths.from_env())
        try:
            assert failed_files(ctx, "trip") == []
            # and `ppd status` says it is still being written, not "skipped" (the ratio's word)
            status = dataset_status(ctx, "trip")
            assert status["counts"]["waiting"] == 1 and status["counts"]["skipped"] == 0
            lines = " ".join(next_step_lines(status))
            assert "trip: 1 still being written (incomplete), NOT protected yet" in lines
        finally:
            ctx.close()
        with open(target, "ab") as fh:  # the writer goes on
            fh.write(data[len(data) // 2 :])
        wait_for(lambda: daemon.counts.patched >= 1, 60, "the completed file patched")
        wait_idle(daemon)
        assert daemon.counts.failed == 0
    assert_protected_once(ppd_env, [target], {target: hashlib.sha256(data).hexdigest()})


def test_a_photo_named_symlink_leaves_the_outbox_its_target_untouched(ppd_env: dict[str, Path]) -> None:
    """DAEMON.md: a symlink is quarantined. It was left in place (logged at info on every start) and
    `ppd status` counted nothing: published with `cp -L` or by a web server it ships the unprotected
    file it points to (a black-box review, 2026-12-07). The link moves; its target is never touched."""
    outside = write_image(ppd_env["outbox"].parent / "elsewhere" / "real.png", 4)
    before, mode = sha(outside), outside.stat().st_mode
    ds = ppd_env["outbox"] / "shoot"
    ds.mkdir()
    with running(ppd_env) as daemon:
        (ds / "link.png").symlink_to(outside)
        wait_for(lambda: daemon.counts.quarantined >= 1, 20, "the link quarantined")
        wait_idle(daemon)
    assert not (ds / "link.png").is_symlink() and not (ds / "link.png").exists()
    moved = ppd_env["outbox"].parent / "ppd-quarantine" / "shoot" / "link.png"
    assert moved.is_symlink() and moved.resolve() == outside.resolve()
    assert sha(outside) == before and outside.stat().st_mode == mode
    row = store_of(ppd_env).file(ds / "link.png")
    assert row["state"] == FileState.QUARANTINED and "symlink" in row["error"]


def test_a_symlink_with_no_suffix_to_a_photo_is_quarantined_too(ppd_env: dict[str, Path]) -> None:
    """A diff review: `latest -> ~/Pictures/IMG_1.jpg` (no suffix) was only logged "not a regular file,
    left alone", while a `.png` link is quarantined: both publish the photo they reach. A link with no
    suffix to a note is left alone."""
    outside = write_image(ppd_env["outbox"].parent / "elsewhere" / "real.png", 5)
    note = ppd_env["outbox"].parent / "elsewhere" / "notes"
    note.write_text("not a photo\n")
    ds = ppd_env["outbox"] / "shoot"
    ds.mkdir()
    with running(ppd_env) as daemon:
        (ds / "notes").symlink_to(note)
        (ds / "latest").symlink_to(outside)
        wait_for(lambda: daemon.counts.quarantined >= 1, 20, "the link quarantined")
        wait_idle(daemon)
        assert daemon.counts.quarantined == 1
    assert not (ds / "latest").is_symlink() and (ds / "notes").is_symlink()
    assert (ppd_env["outbox"].parent / "ppd-quarantine" / "shoot" / "latest").is_symlink()


def test_a_restored_file_is_left_alone_at_start_until_it_changes(ppd_env: dict[str, Path]) -> None:
    """Every daemon start judged each restored file again, one "unchanged ... restored by the user"
    line each (58 at one start in a black-box review). Restore now records the file's size and time,
    and the catch-up scan leaves it alone while they hold; a new version written over it is patched."""
    from daemon.protect.one_file import protect_file, restore_file

    photo = write_image(ppd_env["outbox"] / "kept" / "a.png", seed=3)
    ctx = AppContext.open(AppPaths.from_env())
    try:
        assert protect_file(photo, ctx).state == "patched"
        assert restore_file(ctx, photo).state == "restored"
    finally:
        ctx.close()
    with running(ppd_env) as daemon:
        wait_idle(daemon)
        assert daemon.counts.unchanged == 0 and daemon.counts.patched == 0  # not judged again
        staged = write_image(ppd_env["outbox"].parent / "stage" / "a.png", seed=4)
        os.replace(staged, photo)  # a new version over the restored file
        wait_for(lambda: daemon.counts.patched >= 1, 30, "the new version patched")
