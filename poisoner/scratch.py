"""ppd's own folders in the temporary folder, and their removal after a process killed outright.

A folder made here (`owned_temp_dir`, `make_owned_temp_dir`, or one claimed with `claim`: the
forkserver's pymp-* folder) holds a lock file locked for as long as its ppd process lives; the kernel
releases the lock however the process ends, SIGKILL included. `sweep()`, run before a new such folder
is made, removes every folder of ppd's prefixes in the temporary folder whose lock is free: what a
killed process left (a half-written verification's COLMAP workspaces, the photos an automatic search
copied, a pool's socket folder). A folder without the lock file is never touched; a folder ppd keeps
for the user (a verification's report) gives its lock up (`release(..., keep=True)`).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

LOCK_NAME = ".ppd-owner.lock"
# The prefixes of ppd's folders in the temporary folder (multiprocessing's own for the forkserver).
PREFIXES = ("pymp-", "ppd-verify-", ".ppd-auto-", "ppd-preview-", "ppd-cover-")
_held: dict[str, int] = {}  # folder -> this process's open, locked descriptor of its lock file


def claim(folder: str | Path) -> bool:
    """Mark folder as this process's until it ends (or `release`); False where it cannot be (a
    filesystem without flock, say): the folder then works as before, unmarked, never swept."""
    key = os.fspath(folder)
    if key in _held:
        return True
    # Locked under a name of its own, then linked into place: a sweep never sees the lock file
    # unlocked, and a folder already marked (by another process) keeps its owner's lock.
    pending = os.path.join(key, f"{LOCK_NAME}.{os.getpid()}")
    try:
        fd = os.open(pending, os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # released by the kernel when this process ends, however it ends
        os.link(pending, os.path.join(key, LOCK_NAME))
    except OSError:  # no flock or no hard links here, or the folder is someone else's already
        os.close(fd)
        return False
    finally:
        with contextlib.suppress(OSError):
            os.unlink(pending)
    _held[key] = fd
    return True


def release(folder: str | Path, keep: bool = False) -> None:
    """Give folder's lock up; keep: the folder stays for the user, so its lock file goes first (a
    sweep must never take it for a dead process's)."""
    key = os.fspath(folder)
    if keep:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(os.path.join(key, LOCK_NAME))
    fd = _held.pop(key, None)
    if fd is not None:
        os.close(fd)


def make_owned_temp_dir(prefix: str) -> Path:
    """A new folder in the temporary folder, claimed; stale ones swept first. The caller removes it
    (`remove_owned`) or keeps it (`release(folder, keep=True)`)."""
    if not prefix.startswith(PREFIXES):
        raise ValueError(f"{prefix!r} is not one of ppd's temporary prefixes {PREFIXES}")
    sweep()
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    claim(folder)
    return folder


def remove_owned(folder: Path) -> None:
    shutil.rmtree(folder, ignore_errors=True)
    release(folder)


@contextlib.contextmanager
def owned_temp_dir(prefix: str) -> Iterator[Path]:
    """tempfile.TemporaryDirectory, and a killed process's copy is swept by the next ppd process."""
    folder = make_owned_temp_dir(prefix)
    try:
        yield folder
    finally:
        remove_owned(folder)


def remove_if_stale(folder: str | Path) -> bool:
    """Remove one of ppd's folders whose process has ended (its lock is free); True if removed. A
    folder without ppd's lock file, someone else's, or one whose process lives is left alone."""
    path = Path(folder)
    if not path.name.startswith(PREFIXES) or os.fspath(path) in _held:
        return False
    try:
        if path.lstat().st_uid != os.getuid() or not path.is_dir():
            return False
        fd = os.open(path / LOCK_NAME, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:  # gone, not ours, or no lock file: not a ppd process's folder
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        # Still the folder's lock file? A folder kept for the user unlinks it before its owner lets
        # the lock go: a lock won on the unlinked file says nothing about the folder.
        held, now = os.fstat(fd), os.stat(path / LOCK_NAME, follow_symlinks=False)
        if (held.st_dev, held.st_ino) != (now.st_dev, now.st_ino):
            return False
        shutil.rmtree(path, ignore_errors=True)
    except OSError:  # its process lives, or the lock file went meanwhile
        return False
    finally:
        os.close(fd)
    return not path.exists()


def sweep(root: str | Path | None = None) -> int:
    """Remove the folders that ended ppd processes left in root (the temporary folder); how many."""
    base = Path(root if root is not None else tempfile.gettempdir())
    try:
        candidates = [p for p in base.iterdir() if p.name.startswith(PREFIXES)]
    except OSError:
        return 0
    return sum(remove_if_stale(p) for p in candidates)
