"""A patched file saved again in place by another program, its seal gone: a PNG re-saved (the same
pixels, the seal chunk dropped), a JPEG saved again at quality 90. It looked like a new photo: the
marked picture went into the vault as an "original", got a second mark, and `ppd restore` handed it
back as "restored" (a black-box review, 2026-12-07, F1).

Only a file whose row is patched and whose bytes changed is looked at (rare; never a new photo): ppd's
output of the row's original is made again in memory (placement is deterministic from the original and
the spec) and the three pictures compared (poisoner.image.resaved). ppd's output saved again is
recorded patched with its clean original and no second mark, its bytes the creator's (files.resaved:
`ppd restore` refuses to write over them without --force, which keeps them in DATA/displaced). Anything
else (an edit, a crop) goes on as a new photo, as before."""

from __future__ import annotations

import logging
from typing import cast

from daemon.datasets.subject_masks import subject_masks_for
from daemon.protect.job import Job, Outcome, ProtectOutcome
from daemon.states import FileState
from poisoner.errors import PpdError

log = logging.getLogger(__name__)

RESAVED_REASON = "already ppd output (saved again by another program: its picture is ppd's patched one)"


def recognise_resaved_output(job: Job) -> ProtectOutcome | None:
    """UNCHANGED, the row kept on its clean original and recorded with these bytes, when the file in
    place is ppd's output of its row's original saved again; None for anything else."""
    row, ctx = job.row, job.ctx
    assert job.file is not None and job.sha is not None
    # no bytes in memory (a file over stages.IN_MEMORY_MAX): not judged, patched as new, as before
    if (
        job.kind != "image" or job.out_path is not None or row is None or row["state"] != FileState.PATCHED
        or not row["original_sha256"] or job.sha == row["original_sha256"] or not row["spec_id"]
        or job.data is None or not ctx.vault.has(row["original_sha256"])
    ):  # fmt: skip
        return None
    if not _is_resaved(job, row["original_sha256"], row["spec_id"]):
        return None
    if not job.dry_run:
        ctx.store.record_file(
            job.path, row["dataset"], FileState.PATCHED, poisoned_sha256=job.sha,
            size=job.file.st.st_size, mtime_ns=job.file.st.st_mtime_ns, error=None, resaved=1,
            event="recognised", detail={"from": "saved again by another program, its seal gone",
                                        "was": row["poisoned_sha256"]},
        )  # fmt: skip
    return job.outcome(Outcome.UNCHANGED, RESAVED_REASON, poisoned_sha256=job.sha)


def saved_over(job: Job) -> str | None:
    """The files.saved_over of the row the job records, its original now job.sha: the clean photo from
    before, when that was saved over ppd's patched photo in place (its row patched with another original)
    and is patched as new. An `--out` copy's source was never patched: nothing."""
    row, sha = job.row, job.sha
    if row is None or not row["original_sha256"] or job.out_path is not None:
        return None
    if row["original_sha256"] == sha:  # the same original patched again (a re-protect, --force)
        return cast(str | None, row.get("saved_over"))
    if row["state"] == FileState.PATCHED:  # the first one saved over is the clean one
        return cast(str | None, row.get("saved_over") or row["original_sha256"])
    return None  # a restored file replaced, a new photo: nothing of ppd's in it


def _is_resaved(job: Job, original_sha: str, spec_id: str) -> bool:
    """ppd's output of the original made again (this name, the dataset's subject masks, as the poison
    stage would) and compared, decoded, with the file (poisoner.image.resaved)."""
    from daemon.protect.poisoning import poison_image_bytes
    from poisoner.image.resaved import is_resaved_output

    ctx = job.ctx
    assert job.data is not None
    try:
        spec = ctx.store.get_spec(spec_id)
        original = ctx.vault.path_for(original_sha).read_bytes()
        masks = subject_masks_for(ctx, job.dataset, job.subject_masks)
        max_pixels = ctx.config.max_pixels
        expected, _ = poison_image_bytes(job.path, original, spec, masks, max_pixels=max_pixels)
        return is_resaved_output(job.path.name, original, expected, job.data)
    except (PpdError, OSError, ValueError) as exc:  # a subject-mask error is a PpdError
        log.info("saved again? not checked", extra={"path": str(job.path), "error": str(exc)})
        return False
