"""A recorder that went on appending to a video ppd had patched: patched whole, its original kept.

A fragmented MP4 (OBS, ffmpeg `frag_keyframe`) written by a program that closes the file between
fragments is a complete, playable file at every fragment boundary, so ppd patches it; the writer's
next fragment then lands after ppd's output. The file became ppd's re-encoded video followed by the
recording's raw next fragment: no player reads it, ppd quarantined it, and no `ppd restore` could
give the recording back (black-box review 9, F1, HIGH).

Such a file (its first bytes exactly what ppd wrote, by size and sha256, more after them) is the
vault's original followed by what the writer added. Once it has been quiet for APPEND_QUIET_S (a
writer still at work: the daemon waits, as for any incomplete file), that whole recording is made in
ppd's private work folder, checked complete, kept in the vault as the new original, patched there,
and only the patched file replaces the one at the path (compare-and-swap): the clean recording never
stands where it is published (a diff review). One that is not complete so (a writer that resumes at
the size on disk, as `rsync --append` does, which ppd's output changed) is left to the usual checks.
Videos only: an image with bytes after its end is a re-save's or an editor's, judged as before.
Checked before anything else reaches the vault (check_complete).
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import stat
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from daemon.datasets.subject_masks import subject_masks_for
from daemon.fsops import copy_path_to_fd, write_all
from daemon.protect.job import (
    IncompleteFile,
    Job,
    Outcome,
    ProtectOutcome,
    no_space_in,
    still_the_version,
    tool_version,
)
from daemon.states import FileState
from poisoner.atomic import atomic_replace_at

log = logging.getLogger(__name__)

CHUNK = 1 << 20
APPEND_QUIET_S = 30.0  # a recorder closing the file between fragments writes the next within seconds


def patch_appended(job: Job) -> ProtectOutcome | None:
    """PATCHED once ppd's output with bytes appended is patched whole (see the module docstring);
    IncompleteFile while its writer may still be at work; None for any other file (one stat, no read)."""
    f, ctx, row = job.file, job.ctx, _appended_row(job)
    if f is None or row is None:
        return None
    written = int(row["size"])
    whole = hashlib.sha256()
    if _hash_range(f.fd, 0, written, whole) != row["poisoned_sha256"]:
        return None  # not ppd's output at its start: a new file, judged as any other
    _hash_range(f.fd, written, f.st.st_size - written, whole)
    appended = f.st.st_size - written
    if time.time() - f.st.st_mtime < APPEND_QUIET_S:
        raise IncompleteFile(
            f"{job.path.name} grew after ppd patched it ({appended} bytes appended by its writer): patched "
            f"whole once it has been quiet for {APPEND_QUIET_S:.0f} s"
        )
    with _work_folder(ctx) as folder:
        recording = folder / job.path.name
        fd = os.open(recording, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
        try:
            with no_space_in(ctx.vault.vault_dir):  # the work folder is in the vault
                copy_path_to_fd(ctx.vault.path_for(row["original_sha256"]), fd)
                _copy_range(f.fd, written, appended, fd)
        finally:
            os.close(fd)
        from poisoner.completeness import incomplete_reason

        if incomplete_reason(recording) is not None:
            return None  # not the recording continued: judged as it is, as before
        outcome = _patch_recording(job, row, recording, folder, whole.hexdigest())
    log.info(
        "%s grew after ppd patched it: patched whole, with the %d bytes its writer appended", job.path.name,
        appended, extra={"path": str(job.path), "dataset": row["dataset"], "appended_bytes": appended},
    )  # fmt: skip
    return outcome


def _appended_row(job: Job) -> dict[str, Any] | None:
    """The file's row when the file may be ppd's output with bytes appended: a video, larger than ppd
    wrote, neither a dry run, an `--out` copy nor a file whose bytes are the creator's (resaved)."""
    f, ctx = job.file, job.ctx
    if f is None or job.kind != "video" or job.out_path is not None or job.dry_run:
        return None
    row = ctx.store.file(job.record_path)
    # any state: an earlier look said its writer was at work (the daemon's "waiting" row, `ppd poison`'s
    # failed one); the figures of ppd's output stay in the row, and its first bytes must be exactly them
    if row is None or row["state"] == FileState.REMOVED or row.get("resaved") or not row.get("spec_id"):
        return None
    written = row.get("size")
    if not written or f.st.st_size <= written or not row.get("poisoned_sha256"):
        return None
    return row if ctx.vault.has(row["original_sha256"]) else None


def _patch_recording(
    job: Job, row: dict[str, Any], recording: Path, folder: Path, current_sha: str
) -> ProtectOutcome:
    """The whole recording kept in the vault, patched with the file's spec in the work folder, put at
    the path only if that still holds the file as hashed; its row recorded."""
    from daemon.protect.poisoning import poison_to, provenance_marker, seal_output
    from daemon.store.vault import sha256_file

    f, ctx = job.file, job.ctx
    assert f is not None
    spec = ctx.store.get_spec(row["spec_id"])
    with no_space_in(ctx.vault.vault_dir):
        original = ctx.vault.keep(recording)
        made = folder / f"patched-{job.path.name}"  # the same suffix: the poisoner goes by it
        report = poison_to(
            "video", recording, made, spec, subject_masks=subject_masks_for(ctx, row["dataset"]),
            marker=provenance_marker(ctx, spec.spec_id, original), keep_location=ctx.config.keep_location,
        )  # fmt: skip
        seal_output(ctx, made)
    patched = sha256_file(made)
    check = still_the_version(f, current_sha, job.path.name)
    with no_space_in(job.path.parent), atomic_replace_at(
        f.dir_fd, f.name, mode=stat.S_IMODE(f.st.st_mode), check=check
    ) as (fd, _tmp):
        copy_path_to_fd(made, fd)
        st = os.fstat(fd)
    ctx.store.record_file(
        job.path, row["dataset"], FileState.PATCHED, original_sha256=original, poisoned_sha256=patched,
        spec_id=spec.spec_id, tool_version=tool_version(), size=st.st_size, mtime_ns=st.st_mtime_ns,
        error=None, event="appended",
        detail={"appended_bytes": f.st.st_size - int(row["size"]), "earlier": row["original_sha256"]},
    )  # fmt: skip
    reason = "grew after ppd patched it: patched whole again, with what its writer appended"
    return job.outcome(Outcome.PATCHED, reason, original_sha256=original, poisoned_sha256=patched,
                       spec_id=spec.spec_id, output=job.path, report=report,
                       signature=(st.st_ino, st.st_size, st.st_mtime_ns))  # fmt: skip


@contextlib.contextmanager
def _work_folder(ctx: Any) -> Iterator[Path]:
    from daemon.protect.poisoning import work_folder

    with contextlib.ExitStack() as held:
        folder = work_folder(ctx, held)
        try:
            yield folder
        finally:
            shutil.rmtree(folder, ignore_errors=True)


def _hash_range(fd: int, start: int, length: int, h: Any = None) -> str:
    """The sha256 of length bytes from start (h: a running hash to go on with)."""
    h = h or hashlib.sha256()
    for chunk in _chunks(fd, start, length):
        h.update(chunk)
    return str(h.hexdigest())


def _copy_range(src_fd: int, start: int, length: int, dst_fd: int) -> None:
    for chunk in _chunks(src_fd, start, length):
        write_all(dst_fd, chunk)


def _chunks(fd: int, start: int, length: int) -> Iterator[bytes]:
    end = start + length
    while start < end:
        chunk = os.pread(fd, min(CHUNK, end - start), start)
        if not chunk:
            raise IncompleteFile("the file got shorter while it was read")
        start += len(chunk)
        yield chunk
