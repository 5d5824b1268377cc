"""poisoner.scratch: which of ppd's temporary folders are removed (only a ppd process's, once it has
ended; never one kept for the user); poisoner.pool_exit: a worker that watches its caller exits when
the caller does."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from poisoner import scratch
from poisoner.scratch import LOCK_NAME, remove_if_stale
from testkit.kill_loops import REPO

HOLDER = (
    "import fcntl, os, sys, time\n"
    "fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o600)\n"
    "fcntl.flock(fd, fcntl.LOCK_EX)\n"
    "print('held', flush=True)\n"
    "time.sleep(600)\n"
)


def _held(lock: Path) -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(lock)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_only_an_ended_ppd_processs_folder_is_removed(tmp_path: Path) -> None:
    live, dead, foreign = (tmp_path / name for name in ("pymp-live", "ppd-verify-dead", ".ppd-auto-foreign"))
    named_otherwise = tmp_path / "other-dead"
    for folder in (live, dead, foreign, named_otherwise):
        folder.mkdir()
        (folder / "work").mkdir()
        (folder / "work" / "listener-x").write_bytes(b"")
    (dead / LOCK_NAME).write_bytes(b"")  # its process ended: nobody holds the lock
    (named_otherwise / LOCK_NAME).write_bytes(b"")  # not multiprocessing's: not ours to judge
    holder = _held(live / LOCK_NAME)
    try:
        inode = (live / LOCK_NAME).stat().st_ino
        assert not scratch.claim(live)  # marked by another process: its lock stays its own
        assert (live / LOCK_NAME).stat().st_ino == inode and sorted(os.listdir(live)) == [LOCK_NAME, "work"]
        assert scratch.sweep(tmp_path) == 1
        assert not dead.exists()
        assert live.is_dir() and foreign.is_dir() and named_otherwise.is_dir()
    finally:
        holder.kill()
        holder.wait()
    assert remove_if_stale(live)  # its holder has ended now
    assert not live.exists() and foreign.is_dir()


WATCHED = (
    "import os, sys, time\n"
    "from poisoner.pool_exit import exit_with_caller\n"
    "def no_pidfd(pid): raise OSError(38, 'pidfd_open blocked')\n"
    "if sys.argv[3] == 'poll': os.pidfd_open = no_pidfd\n"
    "exit_with_caller(int(sys.argv[1]), sys.argv[2])\n"
    "print('watching', flush=True)\n"
    "time.sleep(600)\n"
)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="the poll reads /proc")
@pytest.mark.parametrize("how", ["pidfd", "poll"])
def test_a_worker_exits_when_the_caller_it_watches_is_killed_and_removes_its_folder(
    tmp_path: Path, how: str
) -> None:
    if how == "pidfd" and not hasattr(os, "pidfd_open"):
        pytest.skip("no pidfd_open here")
    folder = tmp_path / "pymp-caller"
    folder.mkdir()
    caller = _held(folder / LOCK_NAME)  # stands for ppd: holds the folder's lock while it lives
    worker = subprocess.Popen([sys.executable, "-c", WATCHED, str(caller.pid), str(folder), how], cwd=REPO,
                              stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert worker.stdout is not None and worker.stdout.readline().strip() == "watching"
        time.sleep(0.3)
        assert worker.poll() is None and folder.is_dir()  # the caller lives: the worker goes on
        os.kill(caller.pid, signal.SIGKILL)  # not reaped until the worker has gone: a zombie has ended
        assert worker.wait(30) == 1
        assert not folder.exists()
    finally:
        for proc in (caller, worker):
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def test_an_owned_folder_goes_at_the_end_or_stays_for_the_user_and_is_never_swept_then(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with scratch.owned_temp_dir(".ppd-auto-") as used:
        assert used.parent == tmp_path and (used / LOCK_NAME).is_file()
        assert scratch.sweep() == 0 and used.is_dir()  # its process (this one) lives
    assert not used.exists()
    kept = scratch.make_owned_temp_dir("ppd-verify-")
    (kept / "report.json").write_text("{}")
    scratch.release(kept, keep=True)
    assert scratch.sweep() == 0 and (kept / "report.json").is_file() and not (kept / LOCK_NAME).exists()
    with pytest.raises(ValueError):
        scratch.make_owned_temp_dir("not-ppd-")


def test_a_folder_kept_for_the_user_while_a_sweep_looks_at_it_stays(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The owner gives a kept folder's lock up (unlinks the lock file, then closes it) between the
    sweep's open and its flock: the lock the sweep wins is no longer the folder's."""
    import fcntl

    kept = tmp_path / "ppd-verify-kept"
    kept.mkdir()
    (kept / "report.json").write_text("{}")
    owner = os.open(kept / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o600)
    fcntl.flock(owner, fcntl.LOCK_EX)
    real_flock = fcntl.flock

    def owner_lets_go_first(fd: int, op: int) -> None:
        if op & fcntl.LOCK_NB:  # the sweep's attempt: the owner's release(keep=True) lands just before
            os.unlink(kept / LOCK_NAME)
            os.close(owner)
        real_flock(fd, op)

    monkeypatch.setattr(scratch.fcntl, "flock", owner_lets_go_first)
    assert not remove_if_stale(kept)
    assert (kept / "report.json").is_file()
