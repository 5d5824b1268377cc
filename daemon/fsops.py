"""Descriptor-relative file operations: containment that a swapped folder or file cannot escape.

A file inside a dataset is opened once, component by component from a trusted anchor folder
(the outbox, or the folder named on the command line): every folder below the anchor with
O_NOFOLLOW|O_DIRECTORY relative to its parent's descriptor, the file with O_NOFOLLOW relative to
its folder's. Every later read goes through the file's descriptor and every write and rename
through the folder's descriptor (poisoner.atomic.atomic_replace_at), never through the path
again: a folder or file swapped for a symlink after the open is not followed, and what is
written lands in the folder that was opened, which is inside the anchor.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import logging
import os
import stat
import threading
from dataclasses import dataclass
from pathlib import Path

from daemon.platform import rename_noreplace
from poisoner.atomic import atomic_replace_at, clear_stale_temps, fsync_dir
from poisoner.errors import ExitStatus, PpdError

log = logging.getLogger(__name__)

CHUNK = 1 << 20
_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
_FILE_FLAGS = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC  # NONBLOCK: a FIFO must not hang


class NotContained(PpdError):
    """The path is not a regular file reachable inside its anchor without following a symlink."""

    exit_status = ExitStatus.FAILED


Identity = tuple[int, int, int, int]  # (device, inode, size, mtime_ns)


def identity(st: os.stat_result) -> Identity:
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


@dataclass
class ContainedFile:
    """An open regular file and its folder, both reached without following a symlink."""

    path: Path  # as asked (for messages and the store); never used for I/O
    dir_fd: int
    name: str
    fd: int
    st: os.stat_result  # at open
    anchor: Path
    dir_parts: tuple[str, ...]  # the folders from anchor to the file

    def close(self) -> None:
        for fd in (self.fd, self.dir_fd):
            with contextlib.suppress(OSError):
                os.close(fd)

    def sha256(self) -> str:
        return sha256_fd(self.fd)

    def changed(self) -> bool:
        """Whether the open file's size or mtime moved since it was opened (written to)."""
        return identity(os.fstat(self.fd)) != identity(self.st)

    def folder_in_place(self) -> bool:
        """Whether the opened folder is still the one reached from the anchor by its path without
        a symlink (a folder moved out of the anchor, or swapped for a link, is not)."""
        try:
            anchor_fd = open_dir(self.anchor)
        except OSError:
            return False
        try:
            fd = open_dir_below(anchor_fd, self.dir_parts, self.path)
        except (NotContained, OSError):
            return False
        finally:
            os.close(anchor_fd)
        try:
            now, opened = os.fstat(fd), os.fstat(self.dir_fd)
        finally:
            os.close(fd)
        return (now.st_dev, now.st_ino) == (opened.st_dev, opened.st_ino)

    def current_identity(self) -> Identity | None:
        """What is at the name in the opened folder now (None: nothing, or not a regular file)."""
        try:
            st = os.stat(self.name, dir_fd=self.dir_fd, follow_symlinks=False)
        except FileNotFoundError:
            return None
        return identity(st) if stat.S_ISREG(st.st_mode) else None


def open_dir(path: Path) -> int:
    """A trusted folder (anchor) as a descriptor; the path itself may pass through symlinks."""
    return os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)


def open_dir_below(anchor_fd: int, parts: tuple[str, ...], shown: Path) -> int:
    """Walk parts below anchor_fd, never following a symlink; a new descriptor of the last folder."""
    fd = os.dup(anchor_fd)
    try:
        for part in parts:
            if part in ("", ".", "..") or "/" in part:
                raise NotContained(f"{shown}: refusing the path component {part!r}")
            try:
                nxt = os.open(part, _DIR_FLAGS, dir_fd=fd)
            except OSError as exc:
                if exc.errno in (errno.ELOOP, errno.ENOTDIR):
                    raise NotContained(
                        f"{shown}: the folder {part!r} is a symlink or not a folder; refusing it "
                        "(ppd never follows a symlink inside a dataset)"
                    ) from None
                raise
            os.close(fd)
            fd = nxt
        return fd
    except BaseException:
        os.close(fd)
        raise


def open_contained(anchor: Path, path: Path) -> ContainedFile:
    """Open path (inside anchor, compared without resolving) as described in the module docstring."""
    anchor, path = Path(anchor).absolute(), Path(path).absolute()
    try:
        rel = path.relative_to(anchor)
    except ValueError:
        raise NotContained(f"{path} is not inside {anchor}") from None
    if not rel.parts:
        raise NotContained(f"{path} is a folder, not a file")
    anchor_fd = open_dir(anchor)
    try:
        dir_fd = open_dir_below(anchor_fd, rel.parts[:-1], path)
    finally:
        os.close(anchor_fd)
    name = rel.parts[-1]
    try:
        try:
            fd = os.open(name, _FILE_FLAGS, dir_fd=dir_fd)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise NotContained(
                    f"refusing symlink {path.name} (ppd only protects regular files)"
                ) from None
            raise
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            os.close(fd)
            raise NotContained(f"{path.name} is not a regular file")
        os.set_blocking(fd, True)
    except BaseException:
        os.close(dir_fd)
        raise
    return ContainedFile(
        path=path, dir_fd=dir_fd, name=name, fd=fd, st=st, anchor=anchor, dir_parts=rel.parts[:-1]
    )


def sha256_fd(fd: int) -> str:
    digest = hashlib.sha256()
    offset = 0
    while chunk := os.pread(fd, CHUNK, offset):
        digest.update(chunk)
        offset += len(chunk)
    return digest.hexdigest()


def read_fd(fd: int) -> bytes:
    """The open file's whole content, read from offset 0 (the fd's own offset is not moved)."""
    size = os.fstat(fd).st_size
    data = os.pread(fd, size, 0) if size else b""
    if len(data) < size:  # a short read (a file cut meanwhile) or a pipe-like file: read on
        chunks = [data]
        offset = len(data)
        while chunk := os.pread(fd, CHUNK, offset):
            chunks.append(chunk)
            offset += len(chunk)
        data = b"".join(chunks)
    elif size:  # a file grown meanwhile: its new tail too (what is hashed is what is read)
        tail = []
        offset = size
        while chunk := os.pread(fd, CHUNK, offset):
            tail.append(chunk)
            offset += len(chunk)
        data = b"".join([data, *tail]) if tail else data
    return data


def write_all(fd: int, data: bytes | bytearray) -> None:
    """os.write until every byte is written (a nearly full disk takes a short write first)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def copy_fd_to_path(fd: int, dst: Path) -> str:
    """Copy the open file's bytes to a new private file dst (fsynced); the sha256 of what was copied."""
    out = os.open(dst, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    try:
        return copy_fd_to_fd(fd, out)
    finally:
        os.close(out)


def copy_fd_to_fd(fd: int, out: int) -> str:
    """Copy the open file's bytes (from offset 0) into out, an empty file, and fsync it; the sha256 of
    what was copied."""
    digest = hashlib.sha256()
    offset = 0
    while chunk := os.pread(fd, CHUNK, offset):
        digest.update(chunk)
        write_all(out, chunk)
        offset += len(chunk)
    os.fsync(out)
    return digest.hexdigest()


def copy_path_to_fd(src: Path, fd: int) -> None:
    """Write src's bytes into fd from offset 0 (the temporary of an atomic replace)."""
    with open(src, "rb") as fin:
        while chunk := fin.read(CHUNK):
            write_all(fd, chunk)


# Folders whose stale `.ppd-tmp-*` files this process has already cleared (by (dev, inode)).
_cleared: set[tuple[int, int]] = set()
_cleared_lock = threading.Lock()


def clear_stale_temps_once(dir_fd: int) -> list[str]:
    """The first time this process writes in a folder, remove ppd's stale temporaries there (said in
    the log: a file removed from a user's folder is never removed in silence)."""
    st = os.fstat(dir_fd)
    key = (st.st_dev, st.st_ino)
    with _cleared_lock:
        if key in _cleared:
            return []
        _cleared.add(key)
    try:
        removed = clear_stale_temps(dir_fd)
    except OSError:
        return []
    if removed:
        folder = _folder_of(dir_fd)
        log.info("removed %d temporary file(s) a killed ppd left in %s: %s", len(removed), folder,
                 ", ".join(removed), extra={"path": folder})  # fmt: skip
    return removed


def _folder_of(dir_fd: int) -> str:
    """The open folder's path, for a log line ("?" where /proc cannot say)."""
    try:
        return os.readlink(f"/proc/self/fd/{dir_fd}")
    except OSError:
        return "?"


def move_out(src_dir_fd: int, name: str, dst: Path) -> Path:
    """Move the file `name` of the folder src_dir_fd to dst (a trusted folder) atomically, never over a
    file there (FileExistsError): a rename on one filesystem, else a complete copy, then unlink. It
    replaced one: a photo published under the same name was lost (a diff review)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        rename_noreplace(src_dir_fd, name, dst)
        fsync_dir(dst.parent)
        os.fsync(src_dir_fd)
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise
        src_fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=src_dir_fd)
        try:
            dst_fd = open_dir(dst.parent)
            try:
                mode = stat.S_IMODE(os.fstat(src_fd).st_mode)
                with atomic_replace_at(dst_fd, dst.name, mode=mode, check=lambda: _free(dst)) as (fd, _t):
                    offset = 0
                    while chunk := os.pread(src_fd, 1 << 20, offset):
                        write_all(fd, chunk)
                        offset += len(chunk)
            finally:
                os.close(dst_fd)
        finally:
            os.close(src_fd)
        os.unlink(name, dir_fd=src_dir_fd)
        os.fsync(src_dir_fd)
    return dst


def _free(dst: Path) -> None:
    """FileExistsError when dst is taken (checked just before the copy's rename)."""
    if os.path.lexists(dst):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(dst))
