"""ppd's output whose bytes changed after patching but not its pixels: a photo tagger wrote keywords
or a rating, an editor saved the metadata. Its seal no longer verifies (it covers every byte), so it
looked like a new photo: the marked file went into the vault as an "original", got a second mark,
and `ppd restore` could only give back the once-marked file (a black-box review, 2026-12-07).

A token made with this installation's key names the original and the spec (poisoner.provenance
read_seal_and_claim). That is a claim: a token can be copied onto another photo. So it is trusted only when
the file codes exactly the picture ppd writes from that original with that spec, patched again in
memory and compared as coded (JPEG and PNG; no decode, a patch's memory): then the file is ppd's
output, recorded as such, and never patched twice. Its bytes are the creator's (the rating, the
keywords): the row says so (files.resaved), and `ppd restore` refuses to write the original over
them without --force, which keeps them in DATA/displaced (a black-box review, F2: restore wrote the
original over the rated file, no copy kept)."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from daemon.datasets.dataset import ensure_dataset
from daemon.fsops import read_fd
from daemon.protect.job import Job, Outcome, ProtectOutcome
from daemon.states import FileState

if TYPE_CHECKING:
    from poisoner.provenance import Seal

log = logging.getLogger(__name__)


def recognise_edited_output(job: Job, claim: Seal) -> ProtectOutcome | None:
    """UNCHANGED, its row recorded as ppd's output of the original its token names (claim:
    poisoner.provenance.read_seal_and_claim's), when the image's pixels are ppd's output of that
    original; None for anything else (it goes on as a new photo)."""
    assert job.file is not None and job.sha is not None
    ctx = job.ctx
    if job.kind != "image" or not ctx.vault.has(claim.original_sha256):
        return None
    current = job.data if job.data is not None else read_fd(job.file.fd)
    if not _pixels_are_ppds_output(job, claim, current):
        return None
    if not job.dry_run and job.out_path is None:  # --out: left as ppd's sealed output is (no copy, no row)
        ensure_dataset(ctx, job.dataset, job.root, job.wanted_spec)  # a folder ppd has not seen yet
        ctx.store.record_file(
            job.path, job.dataset, FileState.PATCHED, original_sha256=claim.original_sha256,
            poisoned_sha256=job.sha, spec_id=claim.spec_id, tool_version=None,
            size=job.file.st.st_size, mtime_ns=job.file.st.st_mtime_ns, error=None, event="recognised",
            resaved=1,  # the bytes are the creator's: `ppd restore` keeps them (--force sets them aside)
            detail={"from": "provenance token; bytes changed after patching, pixels unchanged"},
        )  # fmt: skip
    return job.outcome(
        Outcome.UNCHANGED, "already ppd output (changed after patching, its pixels unchanged)",
        poisoned_sha256=job.sha,
    )  # fmt: skip


def _pixels_are_ppds_output(job: Job, claim: Seal, current: bytes) -> bool:
    """Whether current codes exactly the picture ppd writes from the claimed original with the
    claimed spec (under this name and the dataset's subject masks, as the poison stage would),
    compared as coded, without a decode (poisoner.image.coded: JPEG and PNG; any other format is
    not recognised and is patched as a new photo, as before)."""
    from daemon.datasets.subject_masks import subject_masks_for
    from daemon.protect.poisoning import poison_image_bytes
    from poisoner.errors import PpdError
    from poisoner.image.coded import comparable, same_coded_picture

    ctx = job.ctx
    if not comparable(current):  # a format it cannot compare: not worth a patch
        return False
    try:
        spec = ctx.store.get_spec(claim.spec_id)
        original = ctx.vault.path_for(claim.original_sha256).read_bytes()
        masks = subject_masks_for(ctx, job.dataset, job.subject_masks)
        expected, _ = poison_image_bytes(job.path, original, spec, masks, max_pixels=ctx.config.max_pixels)
    except (PpdError, OSError, ValueError) as exc:  # no spec, unreadable: not recognised, patched as new
        log.info("ppd token: output not checked", extra={"path": str(job.path), "error": str(exc)})
        return False
    return same_coded_picture(expected, current) is True
