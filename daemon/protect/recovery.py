"""Runs that stopped half-way and files that moved: a 'pending' row completed when the file is
ppd's own output (recover_pending), a patched file's row carried to its new path (carry_moved_row),
ppd's output copied to `--out` as it is (copy_patched_as_it_is).
See the crash-safe order in daemon.protect.stages."""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.datasets.dataset import ensure_dataset
from daemon.datasets.moved import adopt_moved
from daemon.datasets.subject_masks import masks_or_none
from daemon.platform import fd_path
from daemon.protect.job import Job, one_line, shown_name
from daemon.protect.poisoning import named_vault_copy, poison_to, provenance_marker, seal_output
from daemon.states import FileState
from daemon.store.vault import sha256_file
from poisoner.provenance import sealed_for

if TYPE_CHECKING:
    from daemon.context import AppContext

log = logging.getLogger(__name__)


# What a row says of a file's original, carried to another row of the same output (a moved file, an
# `--out` copy): its date too, which restore gives back.
ORIGINAL_FIELDS = ("original_sha256", "original_mtime_ns", "spec_id", "tool_version")


def carry_moved_row(ctx: AppContext, earlier: dict[str, Any], path: Path, dataset: str, root: Path) -> bool:
    """A patched file that was moved or renamed (a dataset folder renamed in the outbox, say)
    keeps its provenance: its row follows it to the new path instead of dropping out of the
    store, so status, restore and verification still see it. Copies (the old path still there)
    are left as they are. At the same place in root as in its dataset's gone folder, the whole folder
    moved (the outbox did): the dataset follows it first (daemon.datasets.moved), else the row carried
    outside the dataset's folder read as an `--out` copy, which `ppd restore` deleted (a review, F1)."""
    old = Path(earlier["path"])
    if old == path or old.exists() or earlier["state"] not in (FileState.PATCHED, FileState.REMOVED):
        return False
    if earlier["dataset"] == dataset:
        adopt_moved(ctx, dataset, root, proof=(path, old))
    # resaved / saved_over go with the file: a re-saved one moved must not be written over by restore
    moved_fields = (*ORIGINAL_FIELDS, "poisoned_sha256", "resaved", "saved_over")
    fields: dict[str, Any] = {k: earlier.get(k) for k in moved_fields}
    # A dataset first seen through moved files (a renamed folder) inherits their patch spec.
    ensure_dataset(ctx, dataset, root, ctx.store.get_spec(earlier["spec_id"]))
    st = path.stat()
    ctx.store.record_file(
        path, dataset, FileState.PATCHED, event="moved", detail={"from": str(old)},
        size=st.st_size, mtime_ns=st.st_mtime_ns, **fields,
    )  # fmt: skip
    if ctx.store.file(old) is not None:  # not moved with its folder's rows (adopt_moved)
        ctx.store.record_file(
            old, earlier["dataset"], FileState.REMOVED, event="moved_away", detail={"to": str(path)}
        )
    return True


def copy_patched_as_it_is(job: Job, earlier: dict[str, Any], write: Callable[[Job, Any], None]) -> None:
    """`--out` of ppd's own output (patched in place, then `--out`): the copy is that output byte for
    byte, recorded as the dataset's patched copy with the earlier row's original (a black-box review:
    nothing was written, "unchanged", exit 0). write: stages' `--out` writer."""
    assert job.file is not None and job.sha is not None
    out = job.record_path
    if not (out.is_file() and sha256_file(out) == job.sha):
        write(job, job.data if job.data is not None else fd_path(job.file.fd))
    st = os.stat(out, follow_symlinks=False)
    ensure_dataset(job.ctx, job.dataset, job.root, job.wanted_spec)
    kept: dict[str, Any] = {k: earlier.get(k) for k in ORIGINAL_FIELDS}
    job.ctx.store.record_file(
        out, job.dataset, FileState.PATCHED, poisoned_sha256=job.sha, size=st.st_size,
        mtime_ns=st.st_mtime_ns, error=None, event="copied", detail={"from": str(job.path)}, **kept,
    )  # fmt: skip


def _redone_is(ctx: AppContext, row: dict[str, Any], path: Path, sha: str, kind: str) -> bool:
    """Whether poisoning row's vault original again under its spec gives exactly sha."""
    original_sha = row["original_sha256"]
    spec = ctx.store.get_spec(row["spec_id"])
    with named_vault_copy(ctx, original_sha, path.name) as original:
        scratch = original.with_name(f"redo{path.suffix}")
        try:
            poison_to(
                kind, original, scratch, spec, subject_masks=masks_or_none(ctx, row["dataset"]),
                marker=provenance_marker(ctx, spec.spec_id, original_sha),
                keep_location=ctx.config.keep_location,
            )  # fmt: skip
            seal_output(ctx, scratch)
        except Exception as exc:  # any poisoner failure: cannot redo it, the file is treated as new content
            log.warning(
                "%s: the run that stopped half-way cannot be redone (%s); treated as new content",
                shown_name(path), one_line(exc), extra={"path": str(path)},
            )  # fmt: skip
            return False
        return sha256_file(scratch) == sha


def recover_pending(
    ctx: AppContext, row: dict[str, Any], path: Path, sha: str, kind: str | None, content: Path | None = None,
    unchanged: Callable[[], bool] = lambda: True,
) -> bool:  # fmt: skip
    """A 'pending' row means a run stopped between keeping the original and recording the
    result. If the file now differs from the original, it may be our complete output (the
    rename happened, the final row did not). It is when its provenance seal verifies over exactly
    these bytes and names this row's original and spec (content: where to read the bytes that
    were hashed, the opened file's descriptor path; default path; unchanged: whether the file is
    still the version that was hashed, asked after the seal is read); else poison the vault original
    again and compare (poisoning is deterministic). True (and the row completed) when it is ours."""
    original_sha = row["original_sha256"]
    if not kind or not original_sha or sha == original_sha or not ctx.vault.verify(original_sha):
        return False
    sealed = (  # the seal read must be of the bytes that were hashed
        sealed_for(content or path, ctx.seal_key(), original_sha, row["spec_id"]) and unchanged()
    )
    if not sealed and not _redone_is(ctx, row, path, sha, kind):
        return False
    st = path.stat()
    ctx.store.record_file(
        path, row["dataset"], FileState.PATCHED, poisoned_sha256=sha, size=st.st_size,
        mtime_ns=st.st_mtime_ns, error=None, event="recovered", detail={"from": "pending"},
    )  # fmt: skip
    return True
