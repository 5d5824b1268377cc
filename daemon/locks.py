"""One owner per outbox and per file, across processes (`ppd watch`, `ppd poison`, `ppd restore`).

Both are advisory fcntl.flock locks on small files in ppd's private data folder (never in the
user's folders): the kernel drops them when the holding process dies, so a crash never leaves a
lock behind. The holder writes its pid into the file, so a refusal can say who holds it.

- `outbox_lock`: one `ppd watch` per outbox; a second gets LockHeld at once.
- `file_lock`: one process (and one thread) at a time works on a given path; others wait up to
  a bound, then get LockHeld. flock locks belong to an open file description, so two threads of
  one process that each open the lock file exclude each other too.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from daemon.paths import make_private_dir
from poisoner.errors import ExitStatus, PpdError

DEFAULT_FILE_WAIT_S = 600.0  # a video can take minutes; the waiter then finds ppd's output ("unchanged")
_POLL_S = 0.05


class LockHeld(PpdError, RuntimeError):
    """Another process holds the lock (message: one line naming its pid)."""

    exit_status = ExitStatus.ENVIRONMENT


def lock_dir(data_dir: Path) -> Path:
    folder = Path(data_dir) / "locks"
    make_private_dir(folder)
    return folder


def _key(path: Path) -> str:
    return hashlib.sha256(os.fsencode(str(Path(path).absolute()))).hexdigest()[:32]


def _holder(fd: int) -> str:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        text = ""
    return f"pid {text}" if text.isdigit() else "another process"


def _write_pid(fd: int) -> None:
    """Best effort: on a full disk the lock still holds, only the refusal cannot name the pid."""
    with contextlib.suppress(OSError):
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)


@contextlib.contextmanager
def _flock(lock_file: Path, wait_s: float, refusal: Callable[[str], str]) -> Iterator[None]:
    """refusal(holder): the one-line message when the wait runs out."""
    fd = os.open(lock_file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
    try:
        deadline = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    raise LockHeld(refusal(_holder(fd))) from None
                time.sleep(_POLL_S)
        _write_pid(fd)
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _outbox_key(outbox: Path) -> str:
    """The outbox folder itself: its device and inode (a symlink or another spelling of the path
    is the same outbox); its path only while it does not exist yet."""
    try:
        st = os.stat(outbox)
    except OSError:
        return _key(outbox)
    return f"dev{st.st_dev:x}-ino{st.st_ino:x}"


@contextlib.contextmanager
def outbox_lock(data_dir: Path, outbox: Path) -> Iterator[None]:
    """Held for the life of `ppd watch` on outbox; LockHeld at once if another process has it."""
    lock_file = lock_dir(data_dir) / f"watch-{_outbox_key(outbox)}.lock"
    with _flock(lock_file, 0.0, lambda holder: f"another ppd watch ({holder}) is already watching {outbox}"):
        yield


def watching(data_dir: Path) -> list[str]:
    """Who holds a `ppd watch` lock of this data folder now ("pid N"): daemons using its store."""
    holders = []
    folder = Path(data_dir) / "locks"
    for lock_file in sorted(folder.glob("watch-*.lock")) if folder.is_dir() else []:
        try:
            fd = os.open(lock_file, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            fcntl.flock(fd, fcntl.LOCK_UN)
        except BlockingIOError:
            holders.append(_holder(fd))
        finally:
            os.close(fd)
    return holders


@contextlib.contextmanager
def file_lock(data_dir: Path, path: Path, wait_s: float = DEFAULT_FILE_WAIT_S) -> Iterator[None]:
    """Exclusive work on path; waits up to wait_s for another holder, then LockHeld."""
    folder = lock_dir(data_dir) / "files"
    make_private_dir(folder)
    name = Path(path).name

    def refusal(holder: str) -> str:
        return f"{name} is being worked on by another ppd process ({holder}); waited {wait_s:g} s, try later"

    with _flock(folder / f"{_key(path)}.lock", wait_s, refusal):
        yield
