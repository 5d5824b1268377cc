"""A path's lock file goes when its work is done (a black-box review: data/locks/files held one lock
file per path ever processed, 421 for 422 rows), and the lock still excludes: a waiter that opened
the file before its holder unlinked it must not take a lock on the unlinked file while a third
process locks the new file at the name."""

from __future__ import annotations

import contextlib
import os
import threading
import time
from pathlib import Path

import pytest

from daemon.locks import file_lock
from testkit.daemon_proc import wait_for
from testkit.photos import write_image
from tests.daemon.watch.test_watcher import running, wait_idle


def test_one_holder_at_a_time_while_lock_files_come_and_go(tmp_path: Path) -> None:
    inside: list[int] = []
    overlaps: list[tuple[int, ...]] = []
    guard = threading.Lock()

    def work(n: int) -> None:
        for _ in range(150):
            with file_lock(tmp_path, Path("/o/a.jpg"), wait_s=60):
                with guard:
                    inside.append(n)
                    if len(inside) > 1:
                        overlaps.append(tuple(inside))
                time.sleep(0.0005)
                with guard:
                    inside.remove(n)

    threads = [threading.Thread(target=work, args=(n,)) for n in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert overlaps == []
    assert list((tmp_path / "locks" / "files").iterdir()) == []


def test_the_daemon_leaves_no_lock_file_behind(ppd_env: dict[str, Path]) -> None:
    for i in range(4):
        write_image(ppd_env["outbox"] / "ds" / f"{i}.png", i)
    with running(ppd_env) as daemon:
        wait_for(lambda: daemon.counts.patched >= 4, 30, "4 patched")
        wait_idle(daemon)
        (ppd_env["outbox"] / "ds" / "0.png").unlink()
        wait_for(lambda: daemon.counts.removed >= 1, 30, "the removal")
        wait_idle(daemon)
        assert list((ppd_env["data"] / "locks" / "files").iterdir()) == []


def test_a_long_wait_for_another_process_is_said_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """`ppd poison` meeting a clip `ppd watch` was encoding waited in silence (a third black-box
    review): a wait past WAIT_NOTICE_S is said, once, naming the holder."""
    import logging

    from daemon.locks import WAIT_NOTICE_S

    held, release = threading.Event(), threading.Event()

    def hold() -> None:
        with file_lock(tmp_path, Path("/o/clip.mp4"), wait_s=60):
            held.set()
            release.wait(30)

    holder = threading.Thread(target=hold)
    holder.start()
    assert held.wait(10)
    threading.Timer(WAIT_NOTICE_S + 1.0, release.set).start()
    clip = Path("/o/clip.mp4")
    with caplog.at_level(logging.WARNING, logger="daemon.locks"), file_lock(tmp_path, clip, 60):
        pass
    holder.join()
    said = [r.getMessage() for r in caplog.records if "waiting for another ppd process" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("clip.mp4: waiting") and "pid" in said[0], said
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="daemon.locks"), file_lock(tmp_path, clip, 60):
        pass  # no wait: nothing said
    assert not caplog.records


def _watch_lock_files(data: Path) -> list[str]:
    return sorted(p.name for p in (data / "locks").glob("watch-*.lock"))


def test_a_clean_stop_of_ppd_watch_leaves_no_watch_lock_file(tmp_path: Path) -> None:
    """A third black-box review (S9): after each clean stop, DATA/locks kept one lock file per folder
    from the outbox up to /. A crash may leave them; the next run takes the same names, then removes
    them at its stop (none added). Real `ppd watch` processes, real signals."""
    import signal

    from testkit.reliability import DAEMON_ARGS, kill_daemon, start_daemon

    (tmp_path / "outbox").mkdir()
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)
    depth = len(Path(os.path.realpath(tmp_path / "outbox")).parents) + 1  # the outbox and every folder above
    assert len(_watch_lock_files(tmp_path / "data")) == depth  # held while it runs
    assert kill_daemon(daemon, signal.SIGTERM) == 0
    assert _watch_lock_files(tmp_path / "data") == []  # before: `depth` files, after every stop
    crashed = start_daemon(tmp_path, *DAEMON_ARGS)
    kill_daemon(crashed)  # SIGKILL: no clean-up
    left = _watch_lock_files(tmp_path / "data")
    assert len(left) == depth
    again = start_daemon(tmp_path, *DAEMON_ARGS)
    assert _watch_lock_files(tmp_path / "data") == left  # the same names, none added
    assert kill_daemon(again, signal.SIGTERM) == 0
    assert _watch_lock_files(tmp_path / "data") == []


def test_a_folder_lock_goes_with_its_last_holder_and_still_excludes_meanwhile(tmp_path: Path) -> None:
    """Two watches below one folder hold its lock file shared: the first to stop leaves it (the
    other still holds it, and a watch on the folder is still refused); the last removes it."""
    from daemon.locks import LockHeld, outbox_lock

    data, parent = tmp_path / "data", tmp_path / "photos"
    (parent / "a").mkdir(parents=True)
    (parent / "b").mkdir()
    with outbox_lock(data, parent / "b"):
        with outbox_lock(data, parent / "a"):
            pass
        assert len(_watch_lock_files(data)) == len(Path(os.path.realpath(parent / "b")).parents) + 1
        refused = pytest.raises(LockHeld, match=f"already watching {parent / 'b'}, inside {parent}")
        with refused, outbox_lock(data, parent):
            pass
    assert _watch_lock_files(data) == []
    with outbox_lock(data, parent):  # free again, and made again at the same names
        assert len(_watch_lock_files(data)) == len(Path(os.path.realpath(parent)).parents) + 1
    assert _watch_lock_files(data) == []


def test_watches_above_and_below_never_overlap_while_their_lock_files_come_and_go(tmp_path: Path) -> None:
    """Lock files removed by their last holder while others open them: a watch on a folder and one
    below it are never let in together, and nothing is left once all are done."""
    from daemon.locks import LockHeld, outbox_lock

    data, parent = tmp_path / "data", tmp_path / "photos"
    for sub in ("a", "b"):
        (parent / sub).mkdir(parents=True)
    inside: list[Path] = []
    overlaps: list[tuple[Path, ...]] = []
    guard = threading.Lock()

    def work(outbox: Path) -> None:
        for _ in range(150):
            with contextlib.suppress(LockHeld), outbox_lock(data, outbox):
                with guard:
                    inside.append(outbox)
                    if parent in inside and len(inside) > 1:
                        overlaps.append(tuple(inside))
                time.sleep(0.0005)
                with guard:
                    inside.remove(outbox)

    threads = [threading.Thread(target=work, args=(f,)) for f in (parent, parent / "a", parent / "b", parent)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert overlaps == []
    assert _watch_lock_files(data) == []
