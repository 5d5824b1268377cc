"""A writer that went on appending to a file ppd had patched: its original comes back with those bytes.

A fragmented MP4 (OBS, ffmpeg `frag_keyframe`) written by a program that closes the file between
fragments (a resumable download, `rsync --append`) is a complete, playable file at every fragment
boundary, so ppd patches it; the writer's next append then lands on ppd's output. The file became
ppd's re-encoded video followed by the recording's raw next fragment: no player reads it, ppd
quarantined it, and no `ppd restore` could give the recording back (black-box review 9, F1, HIGH).

Here such a file (its first bytes exactly what ppd wrote, by size and sha256, more after them) is put
back as the writer meant it: the vault's original followed by the appended bytes, through the same
compare-and-swap replace as a patch. The stages then start over on it as on any new version: it is
kept in the vault as a new original, patched whole, and restorable. Checked before anything reaches
the vault (check_complete), so the mixed file is never kept as an original.
"""

from __future__ import annotations

import hashlib
import logging
import os
import stat
from collections.abc import Iterator
from typing import Any

from daemon.fsops import copy_path_to_fd, write_all
from daemon.protect.job import Job, SourceChanged, no_space_in, still_the_version
from daemon.states import FileState
from poisoner.atomic import atomic_replace_at

log = logging.getLogger(__name__)

CHUNK = 1 << 20


def put_back_appended(job: Job) -> None:
    """Raises SourceChanged once the original with the appended bytes is at the path; returns when
    the file is not ppd's output with bytes appended (the usual case: one stat, no read)."""
    f, ctx = job.file, job.ctx
    if f is None or job.out_path is not None or job.dry_run:
        return
    row = ctx.store.file(job.record_path)
    if row is None or row["state"] != FileState.PATCHED or not row.get("poisoned_sha256"):
        return
    written = row.get("size")
    if not written or f.st.st_size <= written or not ctx.vault.has(row["original_sha256"]):
        return
    whole = hashlib.sha256()
    if _hash_range(f.fd, 0, written, whole) != row["poisoned_sha256"]:
        return  # not ppd's output at its start: a new file, judged as any other
    _hash_range(f.fd, written, f.st.st_size - written, whole)
    original = ctx.vault.path_for(row["original_sha256"])
    check = still_the_version(f, whole.hexdigest(), job.path.name)
    with no_space_in(job.path.parent), atomic_replace_at(
        f.dir_fd, f.name, mode=stat.S_IMODE(f.st.st_mode), check=check
    ) as (fd, _tmp):
        copy_path_to_fd(original, fd)
        _copy_range(f.fd, written, f.st.st_size - written, fd)
    appended = f.st.st_size - written
    log.info(
        "%s grew after ppd patched it: its original put back with the %d bytes its writer appended",
        job.path.name, appended,
        extra={"path": str(job.path), "dataset": row["dataset"], "appended_bytes": appended},
    )  # fmt: skip
    raise SourceChanged(
        f"{job.path.name} grew after ppd patched it ({appended} bytes appended by its writer): its original "
        "with those bytes put back, to be patched whole"
    )


def extends_original(job: Job, earlier: str) -> bool:
    """Whether the file begins with the whole of the vault original `earlier` and goes on after it: a
    version put back here (its writer's continuation), not a photo saved over ppd's mark, which is
    what resaved.saved_over takes a new original of a patched row for (restore then said "if it was an
    edit of that photo, it still carries ppd's mark" of the recording put back)."""
    f = job.file
    try:
        size = job.ctx.vault.path_for(earlier).stat().st_size
    except OSError:
        return False
    return f is not None and f.st.st_size > size and _hash_range(f.fd, 0, size) == earlier


def _hash_range(fd: int, start: int, length: int, h: Any = None) -> str:
    """The sha256 of length bytes from start (h: a running hash to go on with)."""
    h = h or hashlib.sha256()
    for chunk in _chunks(fd, start, length):
        h.update(chunk)
    return h.hexdigest()


def _copy_range(src_fd: int, start: int, length: int, dst_fd: int) -> None:
    for chunk in _chunks(src_fd, start, length):
        write_all(dst_fd, chunk)


def _chunks(fd: int, start: int, length: int) -> Iterator[bytes]:
    end = start + length
    while start < end:
        chunk = os.pread(fd, min(CHUNK, end - start), start)
        if not chunk:
            raise SourceChanged("the file got shorter while it was read")
        start += len(chunk)
        yield chunk
