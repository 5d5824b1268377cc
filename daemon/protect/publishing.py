"""The last stage: a dataset with a publish folder gets its patched file moved there (daemon.fsops.move_out).

A move that fails (a publish folder the service may not write: ProtectSystem=strict without it in
ReadWritePaths, a read-only or full disk) leaves the patched file where it is: the row stays patched
(its bytes are ppd's output) and keeps the reason in `error` (NOT_MOVED...), the outcome is 'failed'
with that reason, and `ppd status` counts the file (daemon.cli.status_queries). It was logged as
"unchanged ... already patched ([Errno 30] Read-only file system ...)" at info, and nothing counted
it (a black-box review). The next run on the file (the daemon's catch-up at start, `ppd poison`)
moves it then (retry_publish)."""

from __future__ import annotations

import os
from pathlib import Path

from daemon.fsops import move_out
from daemon.protect.job import Job, Outcome, ProtectOutcome, publish_dir
from daemon.states import NOT_MOVED_PREFIX, PATCHED_VALUES, FileState


def publish(job: Job) -> ProtectOutcome | None:
    """6. A dataset with a publish folder gets its patched file moved there."""
    target_dir = publish_dir(job.ctx, job.dataset) if job.out_path is None else None
    if target_dir is None:
        return None
    assert job.file is not None
    rel = job.path.relative_to(job.root) if job.path.is_relative_to(job.root) else Path(job.path.name)
    try:
        job.final = move_out(job.file.dir_fd, job.file.name, target_dir / rel)
    except OSError as exc:
        why = (exc.strerror or str(exc)).lower()
        # where the file is: an in-place dataset's folder is no outbox (a diff review, F9)
        reason = f"{NOT_MOVED_PREFIX} {target_dir}: {why}; left in {job.path.parent}, moved at the next run"
        if isinstance(exc, FileExistsError):  # never over it: a photo published earlier was lost so
            reason = (f"{NOT_MOVED_PREFIX} {target_dir}: another file is there under this name "
                      f"({target_dir / rel}); left in {job.path.parent}: rename this one or move that one "
                      "away, and the next run moves it")  # fmt: skip
        job.ctx.store.record_file(
            job.record_path, job.dataset, FileState.PATCHED, error=reason, event="publish_failed",
            detail={"to": str(target_dir / rel), "error": why},
        )  # fmt: skip
        return job.outcome(  # the signature of what ppd wrote: the watcher takes it for its own echo
            Outcome.FAILED, reason, poisoned_sha256=job.poisoned_sha, output=job.path,
            **({"signature": job.written} if job.written is not None else {}),
        )  # fmt: skip
    job.ctx.store.record_file(
        job.record_path, job.dataset, FileState.PATCHED, published_path=str(job.final), error=None,
        event="published", detail={"to": str(job.final)},
    )  # fmt: skip
    return None


def published_there(row: dict[str, object] | None) -> Path | None:
    """The file a patched row was published as, where it still is: its name in the dataset's folder is
    free for another photo, whose row must not take this one's place (a diff review)."""
    if row is None or row.get("state") not in PATCHED_VALUES or not row.get("published_path"):
        return None
    published = Path(str(row["published_path"]))
    return published if os.path.lexists(published) else None


def not_moved(row: dict[str, object] | None) -> bool:
    """Whether a patched row is a file the publish stage could not move out of the outbox."""
    return row is not None and str(row.get("error") or "").startswith(NOT_MOVED_PREFIX)


def retry_publish(job: Job) -> ProtectOutcome | None:
    """An earlier run patched the file but could not move it: move it now (None when there is nothing
    to retry; the caller then says 'already patched')."""
    if job.dry_run or job.out_path is not None or not not_moved(job.row):
        return None
    job.poisoned_sha = job.sha
    return publish(job) or job.outcome(
        Outcome.UNCHANGED, f"already patched; moved to {job.final}", poisoned_sha256=job.sha, output=job.final
    )
