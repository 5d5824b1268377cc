"""Everything ppd does that only Linux offers, in one place (daemon.platform is its interface).

- `fd_path(fd)`: a path that names an open descriptor's inode (/proc/self/fd/N): read again through
  the descriptor ppd opened, never through a name that may have been swapped since.
- `mounts_of_device(dev)`: the mounts of a device from /proc/self/mountinfo (for error messages).
- `writers_of(st)`: processes that hold a file open for writing (a scan of /proc/PID/fd).
- `lock_holders(st)`: processes that hold a flock on a file, and what each runs (/proc/locks).
- `reflink(dst_fd, src_fd)`: the FICLONE ioctl (a copy that shares extents on btrfs/XFS).
- `rename_noreplace(src_dir_fd, name, dst)`: rename that never replaces a file at dst
  (renameat2 RENAME_NOREPLACE), for moves into a folder that already holds files of the user's.
- `keep_freed_memory()`: glibc's malloc keeps freed memory for the next file instead of handing it
  back to the kernel at once (a worker's page faults: issue 30).
- `inotify_observer(on_overflow, on_moved_self=...)`: watchdog's inotify observer that also calls
  on_overflow when the kernel reports IN_Q_OVERFLOW (events were lost: the owner rescans), and
  on_moved_self when a watched folder is renamed (IN_MOVE_SELF). watchdog rebuilds its watches on an
  overflow but tells the application nothing; the event itself is read here, by its mask.

Standard library only at import (daemon.paths imports this module and `ppd status` imports that);
watchdog is imported by the one function that needs it.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from watchdog.observers.api import BaseObserver
    from watchdog.observers.inotify_c import InotifyFD

PROC = Path("/proc")
FICLONE = 0x40049409  # _IOW(0x94, 9, int), linux/fs.h


def fd_path(fd: int) -> Path:
    """The path that reaches fd's inode (what it was opened as, even if its name changed since)."""
    return PROC / "self" / "fd" / str(fd)


# ---- mounts ------------------------------------------------------------------------------------
def mounts_of_device(dev: int) -> list[tuple[Path, str, str]]:
    """(mount point, type, source) of every mount of device dev, longest mount point first; [] where
    /proc/self/mountinfo cannot be read."""
    wanted = f"{os.major(dev)}:{os.minor(dev)}"
    found = []
    try:
        lines = (PROC / "self" / "mountinfo").read_text().splitlines()
    except OSError:
        return []
    for line in lines:
        fields = line.split()
        if len(fields) < 10 or fields[2] != wanted or "-" not in fields[6:]:
            continue
        after = fields.index("-", 6)
        mount_point, source = Path(unescape_mount(fields[4])), unescape_mount(fields[after + 2])
        found.append((mount_point, fields[after + 1], source))
    return sorted(found, key=lambda m: len(str(m[0])), reverse=True)


def unescape_mount(text: str) -> str:
    """mountinfo writes space, tab, newline and backslash as octal escapes (\\040 ...)."""
    for code in ("040", "011", "012", "134"):
        text = text.replace(f"\\{code}", chr(int(code, 8)))
    return text


# ---- who writes a file -------------------------------------------------------------------------
WRITERS_TTL_S = 0.5  # one /proc scan serves a burst of files (a scan takes ~10-50 ms)
_writers_cache: tuple[float, dict[tuple[int, int], int]] = (-1.0, {})
_writers_lock = threading.Lock()


def writers_of(st: os.stat_result, proc: Path = PROC, *, fresh: bool = False) -> list[int]:
    """Pids of processes that hold the file (by device and inode) open for writing.

    Limits: Linux /proc only (elsewhere: []); only processes whose /proc/PID/fd this user may
    read (the user's own; root sees all); one scan is reused for WRITERS_TTL_S unless fresh; a writer that
    closed the file and will reopen it later is not seen (the format check,
    poisoner.completeness, catches most of those), nor one writing through a memory mapping
    after closing its descriptor."""
    global _writers_cache
    with _writers_lock:
        taken, table = _writers_cache
        if fresh or time.monotonic() - taken > WRITERS_TTL_S or proc != PROC:
            table = _scan_writers(proc)
            if proc == PROC:
                _writers_cache = (time.monotonic(), table)
    pid = table.get((st.st_dev, st.st_ino))
    return [] if pid is None else [pid]


def _scan_writers(proc: Path) -> dict[tuple[int, int], int]:
    """(device, inode) -> a pid holding it open for writing, over every readable process."""
    table: dict[tuple[int, int], int] = {}
    try:
        entries = os.listdir(proc)
    except OSError:
        return table
    for entry in entries:
        if not entry.isdigit():
            continue
        fd_dir = proc / entry / "fd"
        try:
            fds = os.listdir(fd_dir)
        except OSError:
            continue  # gone, or another user's process
        for fd in fds:
            try:
                target = os.stat(fd_dir / fd)
            except OSError:
                continue
            if stat.S_ISREG(target.st_mode) and _opened_for_writing(proc / entry / "fdinfo" / fd):
                table.setdefault((target.st_dev, target.st_ino), int(entry))
    return table


def _opened_for_writing(fdinfo: Path) -> bool:
    try:
        text = fdinfo.read_text()
    except OSError:
        return False
    for line in text.splitlines():
        if line.startswith("flags:"):
            return int(line.split()[1], 8) & os.O_ACCMODE in (os.O_WRONLY, os.O_RDWR)
    return False


# ---- copies that share extents -----------------------------------------------------------------
def lock_holders(st: os.stat_result, proc: Path = PROC) -> list[tuple[int, str]]:
    """(pid, its command line) of each process holding a flock on the file st describes, from
    /proc/locks ("1: FLOCK ADVISORY READ PID MAJ:MIN:INODE 0 EOF", the device in hex); [] when it
    cannot be read. A refusal names them: a shared lock otherwise tells nobody who holds it."""
    want = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = (proc / "locks").read_text().splitlines()
    except OSError:
        return []
    pids = sorted({int(f[4]) for f in (line.split() for line in lines)
                   if len(f) > 5 and f[1] == "FLOCK" and f[5] == want and f[4].isdigit()})  # fmt: skip
    held = []
    for pid in pids:
        try:
            argv = (proc / str(pid) / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        words = [a.decode("utf-8", "replace") for a in argv if a]
        held.append((pid, " ".join(" ".join(words).split())))  # one line, whatever its arguments hold
    return held


def parent_pid(pid: int, proc: Path = PROC) -> int | None:
    """The parent of process pid (/proc/PID/stat's fourth field), None when it is gone or unreadable."""
    try:
        stat_line = (proc / str(pid) / "stat").read_text()
    except OSError:
        return None
    try:  # the command name, second, is in parentheses and may hold spaces: the fields after it count
        return int(stat_line.rsplit(")", 1)[1].split()[1])
    except (IndexError, ValueError):
        return None


def reflink(dst_fd: int, src_fd: int) -> None:
    """Make the empty file dst_fd a clone of src_fd (FICLONE); OSError where the filesystem cannot
    (then dst is left empty)."""
    fcntl.ioctl(dst_fd, FICLONE, src_fd)


# ---- memory ------------------------------------------------------------------------------------
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # mallopt's parameters, malloc.h
HEAP_BLOCKS_UP_TO = 32 << 20  # glibc's largest mmap threshold on 64-bit: bigger blocks still map
KEEP_FREED = 64 << 20  # freed memory kept at the heap's top, at most, per process


RENAME_NOREPLACE = 1  # linux/fs.h
AT_FDCWD = -100


def rename_noreplace(src_dir_fd: int, name: str, dst: Path) -> None:
    """Rename `name` of the folder src_dir_fd to dst, atomically, or FileExistsError when dst exists
    (a file or a link, even a dangling one). Where the kernel or filesystem has no RENAME_NOREPLACE
    (ENOSYS, EINVAL: vfat before Linux 6.x, some FUSE), a check then rename(): a window of a few
    microseconds in which a file put at dst by another process would be replaced."""
    import ctypes

    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2  # glibc 2.28+
    except AttributeError:
        renameat2 = None
    if renameat2 is not None:
        if renameat2(src_dir_fd, os.fsencode(name), AT_FDCWD, os.fsencode(dst), RENAME_NOREPLACE) == 0:
            return
        err = ctypes.get_errno()
        if err not in (errno.ENOSYS, errno.EINVAL):
            raise OSError(err, os.strerror(err), str(dst))
    if os.path.lexists(dst):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(dst))
    os.rename(name, dst, src_dir_fd=src_dir_fd)


def keep_freed_memory() -> bool:
    """Tell glibc's malloc to serve blocks up to HEAP_BLOCKS_UP_TO from its heap and keep up to
    KEEP_FREED of freed memory for the next allocation. Why: by default every numpy array over a
    few MiB is a fresh mapping, and its pages are faulted in and zeroed by the kernel again for each
    photo; `ppd poison` of 24 PNGs of 800 px took 118k page faults and 0.47 s of system CPU, 16k
    and 0.2 s with this, the same peak memory (bench/results/batch.md, round 9). A process that
    does pixel work (a `ppd poison` run, a worker) calls it; the daemon itself does not. False where
    the C library is not glibc (nothing changed)."""
    try:
        if not os.confstr("CS_GNU_LIBC_VERSION"):
            return False
    except (ValueError, OSError):
        return False
    import ctypes

    mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    return bool(mallopt(M_MMAP_THRESHOLD, HEAP_BLOCKS_UP_TO)) and bool(mallopt(M_TRIM_THRESHOLD, KEEP_FREED))


# ---- inotify ----------------------------------------------------------------------------------
def overflow_aware_inotify(
    on_overflow: Callable[[], None], on_moved_self: Callable[[], None] | None = None
) -> InotifyFD:
    """watchdog's inotify reader (not started) that calls on_overflow for each IN_Q_OVERFLOW it reads,
    before watchdog's own handling (which rebuilds its recursive watches), and on_moved_self for each
    IN_MOVE_SELF (a watched folder renamed: watchdog reports nothing, and goes on watching it at its
    new place under its old name)."""
    from watchdog.observers.inotify_c import InotifyEvent
    from watchdog.observers.inotify_c import InotifyFD as _InotifyFD

    class _OverflowAwareFD(_InotifyFD):
        def handle_event(self, event: InotifyEvent) -> None:
            if event.is_queue_overflow:
                on_overflow()
            elif event.is_move_self and on_moved_self is not None:
                on_moved_self()
            super().handle_event(event)

    return _OverflowAwareFD()


def inotify_observer(
    on_overflow: Callable[[], None],
    *,
    full_events: bool = True,
    on_moved_self: Callable[[], None] | None = None,
) -> BaseObserver:
    """watchdog's InotifyObserver reading through overflow_aware_inotify. full_events: a rename from
    outside the watched folder arrives as a move (InotifyFullEmitter), as
    InotifyObserver(generate_full_events=True) gives. on_moved_self: called when a watched folder is
    renamed (its watches ask for IN_MOVE_SELF, which watchdog itself never does): the owner checks
    whether the folder it watches is still the one at its path."""
    from watchdog.observers.api import DEFAULT_OBSERVER_TIMEOUT
    from watchdog.observers.inotify import InotifyEmitter, InotifyFullEmitter, InotifyObserver
    from watchdog.observers.inotify_c import InotifyConstants

    base = InotifyFullEmitter if full_events else InotifyEmitter

    class _Emitter(base):  # type: ignore[misc,valid-type]
        def get_event_mask_from_filter(self) -> Any:
            mask = super().get_event_mask_from_filter()
            return mask | InotifyConstants.IN_MOVE_SELF if on_moved_self is not None else mask

    class _Observer(InotifyObserver):
        def __init__(self) -> None:  # InotifyObserver.__init__ with ppd's reader
            self._inotify_fd = overflow_aware_inotify(on_overflow, on_moved_self)
            self._inotify_fd.start()
            super(InotifyObserver, self).__init__(
                _Emitter, timeout=DEFAULT_OBSERVER_TIMEOUT, inotify_fd=self._inotify_fd
            )

    return _Observer()
