"""The platform ppd needs, behind one small interface: what only the operating system answers
(an open descriptor's path, mounts, who writes a file, reflinks, malloc's retention, inotify with
its overflow). Linux is the one implementation (linux.py); a port implements these names."""

from daemon.platform.linux import (
    fd_path,
    inotify_observer,
    keep_freed_memory,
    lock_holders,
    mounts_of_device,
    overflow_aware_inotify,
    parent_pid,
    reflink,
    rename_noreplace,
    writers_of,
)

__all__ = [
    "fd_path",
    "inotify_observer",
    "keep_freed_memory",
    "lock_holders",
    "mounts_of_device",
    "overflow_aware_inotify",
    "parent_pid",
    "reflink",
    "rename_noreplace",
    "writers_of",
]
