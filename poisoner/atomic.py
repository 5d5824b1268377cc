"""Atomic file replacement, the one helper every writer of a user-visible file goes through.

A crash at any instant leaves the old file or the complete new one. The new content is written
to a temporary file in the destination's own folder (so the final rename never crosses a
filesystem), fsynced, given its permission bits, then renamed over the destination; the folder
is fsynced so the rename itself survives a power cut.

Everything is relative to a directory file descriptor (`atomic_replace_at`): the temporary is
created with O_EXCL|O_NOFOLLOW in that folder and renamed with `src_dir_fd`/`dst_dir_fd`, so a
folder swapped for a symlink between the decision and the write cannot redirect it.
`atomic_output(path)` is the path-based form for folders ppd trusts (its own, or one the user
named on the command line).

Temporary names are of one exact form (is_temp_name: TEMP_PREFIX, a random token, the destination's
suffix), and a temporary is flock()ed by its writer for as long as it lives: `clear_stale_temps`
deletes only unlocked ones of that form and a minimum age, so it never removes another live
process's temporary and never anything that is not ppd's (a user's `.ppd-tmp-notes.txt` is not).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import re
import secrets
import stat
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

TEMP_PREFIX = ".ppd-tmp-"
STALE_TEMP_AGE_S = 10.0  # an unlocked temporary this old has no living writer (see clear_stale_temps)
BORN_LOCKED = "L"  # after TEMP_PREFIX: locked before it had a name (hex names never hold an "L")
TOKEN_HEX = 6  # bytes of the random token (secrets.token_hex): 12 lowercase hex digits
LONG_SUFFIXES = (".seal.key",)  # the suffixes of two parts create_temp_at is given (daemon.store.sealkey)
# create_temp_at's names exactly: the prefix, BORN_LOCKED or not, the token, then no suffix, one
# extension (atomic_replace_at's: os.path.splitext of the destination) or a LONG_SUFFIXES one. A sweep
# removes nothing else (a black-box review: `ppd status` deleted a user's `.ppd-tmp-todo.txt`).
_TEMP_NAME = re.compile(
    rf"{re.escape(TEMP_PREFIX)}{BORN_LOCKED}?[0-9a-f]{{{2 * TOKEN_HEX}}}"
    rf"(?:{'|'.join(re.escape(s) for s in LONG_SUFFIXES)}|\.[^.]*)?"
)
_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC


def is_temp_name(name: str) -> bool:
    """Whether name is of the form of ppd's own temporaries (create_temp_at), the only names swept."""
    return _TEMP_NAME.fullmatch(name) is not None


def fsync_dir(folder: Path) -> None:
    fd = os.open(folder, _DIR_FLAGS)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def default_mode() -> int:
    """0o644 minus the process's umask (what a new file would get)."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o644 & ~umask


def create_temp_at(dir_fd: int, suffix: str = "") -> tuple[str, int]:
    """A new, exclusively created and flock()ed temporary in the folder dir_fd: (name, write fd).

    Where the filesystem has O_TMPFILE, the file is locked before it gets a name (linked in
    through /proc/self/fd), so no other process ever sees it unlocked: its name carries
    BORN_LOCKED and `clear_stale_temps` may remove it as soon as it is unlocked, at any age."""
    try:
        fd = os.open(".", os.O_TMPFILE | os.O_RDWR | os.O_CLOEXEC, 0o600, dir_fd=dir_fd)
    except (AttributeError, OSError):
        fd = -1  # no O_TMPFILE here (or on this filesystem): create by name, lock right after
    if fd >= 0:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            for _ in range(100):
                name = f"{TEMP_PREFIX}{BORN_LOCKED}{secrets.token_hex(TOKEN_HEX)}{suffix}"
                try:
                    os.link(f"/proc/self/fd/{fd}", name, dst_dir_fd=dir_fd, follow_symlinks=True)
                    return name, fd
                except FileExistsError:
                    continue
        except OSError:
            pass  # no /proc, or linkat refused: fall back to a named temporary
        os.close(fd)
    for _ in range(100):
        name = f"{TEMP_PREFIX}{secrets.token_hex(TOKEN_HEX)}{suffix}"
        try:
            fd = os.open(name, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600,
                         dir_fd=dir_fd)  # fmt: skip
        except FileExistsError:
            continue
        fcntl.flock(fd, fcntl.LOCK_EX)  # "alive": clear_stale_temps leaves it alone
        return name, fd
    raise FileExistsError(errno.EEXIST, "no free temporary name")


@contextlib.contextmanager
def atomic_replace_at(
    dir_fd: int, name: str, *, mode: int | None = None, check: Callable[[], None] | None = None
) -> Iterator[tuple[int, str]]:
    """Yield (fd, temporary name) of a temporary in the folder dir_fd; on normal exit it becomes
    `name` in that folder atomically. The caller writes the complete content to fd (or to the
    temporary's name through dir_fd).

    check runs last, just before the rename, in the same critical section: it raises to abandon
    the replace (compare-and-swap on what is at `name` now). mode: the new file's permission
    bits (default 0o644 minus the umask). On any exception the temporary is removed and `name`
    is untouched."""
    tmp_name, fd = create_temp_at(dir_fd, os.path.splitext(name)[1])
    try:
        yield fd, tmp_name
        os.fchmod(fd, default_mode() if mode is None else mode)
        os.fsync(fd)
        if check is not None:
            check()
        os.rename(tmp_name, name, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
        os.fsync(dir_fd)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name, dir_fd=dir_fd)
        raise
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_output(
    dst: Path,
    *,
    mode_like: Path | None = None,
    mode: int | None = None,
    check: Callable[[], None] | None = None,
) -> Iterator[Path]:
    """Yield a temporary path next to dst; on normal exit it atomically becomes dst (check, when
    given, runs just before the rename and raises to abandon it: atomic_replace_at).

    For folders ppd trusts (the path is resolved once, when the folder is opened). The caller
    writes the complete file to the yielded path (by any means: PIL, PyAV, ...). Permission bits:
    mode when given, else copied from mode_like (default: dst itself if it exists, else 0o644
    minus the umask)."""
    dst = Path(dst)
    dir_fd = os.open(dst.parent, _DIR_FLAGS)
    try:
        if mode is None:
            mode = _mode_of(mode_like if mode_like is not None else dst)
        with atomic_replace_at(dir_fd, dst.name, mode=mode, check=check) as (_fd, tmp_name):
            yield dst.parent / tmp_name
    finally:
        os.close(dir_fd)


def _mode_of(path: Path) -> int | None:
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return None


def atomic_write_bytes(
    dst: Path, data: bytes, *, mode_like: Path | None = None, mode: int | None = None
) -> None:
    with atomic_output(dst, mode_like=mode_like, mode=mode) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(
    dst: Path, text: str, *, encoding: str = "utf-8", mode_like: Path | None = None, mode: int | None = None
) -> None:
    atomic_write_bytes(dst, text.encode(encoding), mode_like=mode_like, mode=mode)


def atomic_write_json(
    dst: Path,
    data: object,
    *,
    indent: int | None = None,
    default: Callable[[Any], Any] | None = None,
    mode_like: Path | None = None,
    mode: int | None = None,
) -> None:
    """data as JSON (json.dumps with indent and default). Encoded before dst's folder is touched,
    so data that cannot be encoded raises with dst unchanged and no temporary left."""
    text = json.dumps(data, indent=indent, default=default)
    atomic_write_text(dst, text, mode_like=mode_like, mode=mode)


def clear_stale_temps(
    dir_fd: int, *, min_age_s: float = STALE_TEMP_AGE_S, now: float | None = None
) -> list[str]:
    """Delete ppd's own leftover temporaries in the folder dir_fd: names of their form (is_temp_name),
    regular files, not locked by a living writer, and (unless born locked) at least min_age_s
    old (the age covers the instant between a named temporary's creation and its lock, and
    temporaries of older ppd versions). Returns the names removed."""
    now = time.time() if now is None else now
    return [n for n in os.listdir(dir_fd) if remove_if_stale(dir_fd, n, min_age_s=min_age_s, now=now)]


def remove_if_stale(
    dir_fd: int, name: str, *, min_age_s: float = STALE_TEMP_AGE_S, now: float | None = None
) -> bool:
    """Remove the temporary `name` in dir_fd if it is a stale one of ppd's (see clear_stale_temps)."""
    if not is_temp_name(name):
        return False
    born_locked = name.startswith(TEMP_PREFIX + BORN_LOCKED)
    return remove_if_unlocked(dir_fd, name, min_age_s=0.0 if born_locked else min_age_s, now=now)


def remove_if_unlocked(dir_fd: int, name: str, *, min_age_s: float, now: float | None = None) -> bool:
    """Remove the regular file `name` in dir_fd if no process holds its flock and it is min_age_s old
    (0: any age, for a file locked before it had a name). The lock test of remove_if_stale, for a
    caller that has its own names (daemon.store.sealkey's temporaries of an older ppd)."""
    now = time.time() if now is None else now
    try:
        fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, dir_fd=dir_fd)
    except OSError:
        return False  # gone, a symlink, or unreadable: not ours to judge
    try:
        st = os.fstat(fd)
        # (no age asked: not even a time in the future, a clock set back, keeps it)
        if not stat.S_ISREG(st.st_mode) or (min_age_s > 0 and now - st.st_mtime < min_age_s):
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False  # a living ppd process is writing it
        with contextlib.suppress(FileNotFoundError):
            same = os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
            if (same.st_ino, same.st_dev) == (st.st_ino, st.st_dev):
                os.unlink(name, dir_fd=dir_fd)
                return True
        return False
    finally:
        os.close(fd)


def remove_stale_temp(path: Path, *, min_age_s: float = STALE_TEMP_AGE_S, now: float | None = None) -> bool:
    """remove_if_stale for a temporary named by its path (its folder opened once): the start-up scan
    of the outbox and `ppd status`'s sweep of a dataset's folder."""
    dir_fd = os.open(path.parent, _DIR_FLAGS)
    try:
        return remove_if_stale(dir_fd, path.name, min_age_s=min_age_s, now=now)
    finally:
        os.close(dir_fd)
