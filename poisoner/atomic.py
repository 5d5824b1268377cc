"""Atomic file replacement: a crash at any instant leaves the old file or the complete new one.

The new content is written to a temporary file in the destination's own folder (so the final
rename never crosses a filesystem), flushed and fsynced, given the destination's permission
bits, then renamed over the destination; the folder is fsynced so the rename itself survives
a power cut. Temporary names start with TEMP_PREFIX: the watcher ignores them, and a
start-up scan may delete leftovers of a crash.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

TEMP_PREFIX = ".ppd-tmp-"


def fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_output(dst: Path, *, mode_like: Path | None = None) -> Iterator[Path]:
    """Yield a temporary path next to dst; on normal exit it atomically becomes dst.

    The caller writes the complete file to the yielded path (by any means: PIL, PyAV, ...).
    On an exception the temporary file is removed and dst is untouched. Permission bits are
    copied from mode_like (default: dst itself if it exists, else 0o644 minus the umask).
    """
    dst = Path(dst)
    folder = dst.parent
    fd, tmp_name = tempfile.mkstemp(prefix=TEMP_PREFIX, suffix=dst.suffix, dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            fh.flush()
            os.fsync(fh.fileno())
        source = mode_like if mode_like is not None else (dst if dst.exists() else None)
        if source is not None and source.exists():
            os.chmod(tmp, stat.S_IMODE(source.stat().st_mode))
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o644 & ~umask)
        os.replace(tmp, dst)
        fsync_dir(folder)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def atomic_write_bytes(dst: Path, data: bytes, *, mode_like: Path | None = None) -> None:
    with atomic_output(dst, mode_like=mode_like) as tmp:
        tmp.write_bytes(data)
