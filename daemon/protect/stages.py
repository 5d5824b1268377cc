"""One file patched end to end, as a list of named stages over one small state object (`Job`).

    STAGES = check_name → open_contained_file → check_complete → hash_original → recognise →
             decide → keep_in_vault → mark_pending → poison → replace_atomically →
             record_provenance → publish

Each stage is a small function `stage(job) -> ProtectOutcome | None`: None hands the job to the next
stage, an outcome ends the run there; an exception ends it 'failed' (one_file.protect_file records it).

The crash-safety argument is the order of the last six (docs/STORE.md, with the fsyncs each file
costs and why each is needed):
1. keep_in_vault: an independent copy of the original's bytes (Vault.keep_bytes: the bytes
   hash_original read through the file's descriptor and hashed, never a link; Vault.keep_fd for a
   file over IN_MEMORY_MAX) is in the vault, fsynced with its folder, before anything else (with
   the spec that patches it: Vault.keep_spec, so a rebuilt store knows it);
2. mark_pending: a 'pending' row naming the original's sha256 is committed (not fsynced: after a
   power cut the patched file's seal names the original, durable in the vault, and the next run
   writes the row back; a killed process loses nothing of it);
3. poison: the complete patched file (with its provenance marker) is made: in memory for an image
   up to IN_MEMORY_MAX (nothing is written until replace_atomically), else in ppd's private work
   folder (and in a child process when the last attempt on this file died with its process);
4. replace_atomically: it is copied to a flock()ed temporary in the file's own folder (through
   that folder's descriptor), fsynced, and renamed over the file only if the file at that name is
   still the one that was hashed (compare-and-swap on device, inode, size, mtime and sha256, just
   before the rename); otherwise the new version is left in place and the run starts over;
5. record_provenance: the patched row with the patched sha256; 6. publish: to the publish folder, if any.
A crash between any two steps leaves the original or the complete patched file at the path, and
the original in the vault whenever the path may hold the patched one.

Beside it: job.py (the Job, its outcome), poisoning.py (poisoner, seal, work folders), recovery.py.

Containment (daemon.fsops): the file is opened once, relative to a descriptor of its folder reached
from the anchor (the outbox, or the folder given to `ppd poison`) without following a symlink; every
later read and write goes through those descriptors, never through the path.
"""

from __future__ import annotations

import hashlib
import logging
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import cast

from daemon.datasets.dataset import ensure_dataset, ensure_dataset_row
from daemon.datasets.subject_masks import (
    SubjectMaskError,
    mask_folder_holding,
    remember_masks,
    sibling_images,
    subject_masks_for,
)
from daemon.datasets.unpatched_names import unpatched_name_reason
from daemon.fsops import (
    ContainedFile,
    NotContained,
    clear_stale_temps_once,
    copy_fd_to_path,
    copy_path_to_fd,
    open_contained,
    open_dir,
    read_fd,
    write_all,
)
from daemon.platform import fd_path, writers_of
from daemon.protect.appended import patch_appended
from daemon.protect.edited import recognise_edited_output
from daemon.protect.job import (
    FileSignature,
    IncompleteFile,
    Job,
    Outcome,
    ProtectOutcome,
    ProtectRefused,
    SourceChanged,
    is_ignored_name,
    no_space_in,
    place_note,
    report_detail,
    shown_name,
    still_the_version,
    storable,
    tool_version,
)
from daemon.protect.poisoning import (
    link_or_copy,
    poison_image_bytes,
    poison_isolated,
    poison_to,
    provenance_marker,
    seal_in_memory,
    seal_output,
    work_copy_name,
    work_folder,
)
from daemon.protect.publishing import publish, retry_publish
from daemon.protect.quarantine import attempt, forget_attempt
from daemon.protect.recovery import copy_patched_as_it_is, recover_pending
from daemon.protect.remark import finish_remark, take_in
from daemon.protect.resaved import recognise_resaved_output, saved_over
from daemon.states import LINKED_FOLDER_PREFIX, STILL_OPEN_PREFIX, UNPROTECTED_PREFIX, FileState
from daemon.store.vault import VaultContentChanged, sha256_file
from poisoner.atomic import atomic_replace_at
from poisoner.errors import ExitStatus, PpdError
from poisoner.media import SNIFF_BYTES, UNPROTECTED, media_class, unpatched_name
from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

PATCHED_PREFIX = "patched-"  # the poison stage's output in the private work folder


# ---- the stages ------------------------------------------------------------------------------
def check_name(job: Job) -> ProtectOutcome | None:
    """Hidden files and ppd's temporaries are never touched; a subject mask is refused (not the
    file's fault: never quarantined); a name the store cannot hold is refused."""
    if is_ignored_name(job.path):
        return job.outcome(Outcome.SKIPPED, "hidden or temporary file")
    if (key := mask_folder_holding(job.ctx.config, job.path)) is not None:
        raise SubjectMaskError(
            f"{shown_name(job.path)} is a subject mask ({key}): masks are never patched; "
            "move the mask folder out of the outbox"
        )
    if not storable(job.path):
        raise ProtectRefused(
            f"{shown_name(job.path)}: the file name is not valid UTF-8; rename it to protect it "
            "(ppd records names as UTF-8)"
        )
    return None


def open_contained_file(job: Job) -> ProtectOutcome | None:
    """Open the file once, without following a symlink anywhere below the anchor (daemon.fsops)."""

    try:
        job.file = open_contained(job.anchor, job.path)
    except NotContained as exc:
        if job.path.is_symlink() and job.path.is_dir():  # never followed; `ppd poison` names its photos
            return job.outcome(Outcome.SKIPPED, f"{LINKED_FOLDER_PREFIX}: the photos in it are not protected")
        raise ProtectRefused(str(exc)) from None
    # ppd's own temporaries a killed run left in this folder (a re-protect's too), even when every
    # file in it turns out to be done already: once a folder, a process
    clear_stale_temps_once(job.file.dir_fd)
    opened = job.file  # a suffix of no format: the file's first bytes, read through its descriptor
    if unpatched_name(job.path.name) is not None:  # the daemon's rule: a backup, a partial download
        said = unpatched_name_reason(job.path.name, False, os.pread(opened.fd, SNIFF_BYTES, 0))
        return job.outcome(Outcome.SKIPPED, said or "not a supported image or video")  # a photo: said so
    kind = media_class(job.path, lambda: os.pread(opened.fd, SNIFF_BYTES, 0))
    if kind == UNPROTECTED:  # a photo ppd does not write (GIF, raw): the run's summary names it
        return job.outcome(Outcome.SKIPPED, f"{UNPROTECTED_PREFIX}: a format ppd cannot patch")
    if kind is None:  # not ours to judge (sidecars, notes): left alone, no row
        return job.outcome(Outcome.SKIPPED, "not a supported image or video")
    job.kind = kind
    return None  # an empty file is judged by check_complete (a writer may be about to fill it)


class UnrecognisedFile(PpdError, ValueError):
    """The file does not begin like any image or video ppd reads (nor can appending make it one)."""

    exit_status = ExitStatus.FAILED


def check_complete(job: Job) -> ProtectOutcome | None:
    """Only complete files go on: one still open for writing by another process is skipped (its
    close re-arms the watcher); one whose structure is incomplete, whose header declares more
    pixels than the decode budget, or that no writer takes, is refused here, before anything
    reaches the vault."""
    from poisoner.completeness import incomplete_reason, starts_like_media

    assert job.file is not None
    through_fd = fd_path(job.file.fd)  # the opened inode, never the path again
    pids = writers_of(job.file.st)
    if pids:  # the shared scan may predate the writer's close (e.g. ppd's own temporary, renamed here)
        pids = writers_of(job.file.st, fresh=True)
    reason = None if pids else incomplete_reason(through_fd)
    if reason is not None:
        pids = writers_of(job.file.st, fresh=True)  # the shared scan may predate this writer
    if pids:
        # the fact only: the daemon says it patches it once closed (its close re-arms the watcher),
        # `ppd poison`, which does not, says to run it again (a black-box review read a promise there)
        why = f"{STILL_OPEN_PREFIX} by pid {pids[0]}"
        return job.outcome(Outcome.SKIPPED, why, signature=None)
    if (whole := patch_appended(job)) is not None:  # ppd's output its writer appended to: patched whole
        return whole
    if starts_like_media(os.pread(job.file.fd, 16, 0)) is False:
        # before the vault: a tail fragment (a writer's next append) is never kept as an original
        raise UnrecognisedFile(
            f"{job.path.name} is not a recognised image or video (its first bytes match no format ppd reads)"
        )
    if reason is not None:
        raise IncompleteFile(f"{job.path.name} is incomplete ({reason}); not patched")
    if job.kind == "image":
        from poisoner.image.read import check_writable_image
        from poisoner.limits import check_decode_budget

        config = job.ctx.config
        check_decode_budget(
            through_fd, config.max_pixels, name=job.path.name, max_bytes=config.max_memory_bytes
        )
        # what no writer takes (CMYK JPEG, 16-bit colour TIFF, ...): failed here, not after the
        # vault, and a dry run does not call it "would patch"
        job.shown_size = check_writable_image(through_fd, job.path.name, config.max_pixels)
    return None


# An image up to this size is read into memory once, for its hash and its vault copy (and its
# patched output once, for its hash and its replace); larger files and videos stream as before.
IN_MEMORY_MAX = 64 << 20


def hash_original(job: Job) -> ProtectOutcome | None:
    """The original's sha256, read through its descriptor. An image up to IN_MEMORY_MAX is read into
    memory once: its vault copy (keep_in_vault) is written from these very bytes, never read
    or hashed a second time."""
    assert job.file is not None
    if job.kind == "image" and job.file.st.st_size <= IN_MEMORY_MAX:
        job.data = read_fd(job.file.fd)
        job.sha = hashlib.sha256(job.data).hexdigest()
    else:
        job.sha = job.file.sha256()
    job.row = job.ctx.store.file(job.record_path)
    return None


def recognise(job: Job) -> ProtectOutcome | None:
    """What is never patched again: ppd's own output (by its row, its sha256 anywhere in the
    store, or its provenance marker), a run of this path that was interrupted (finished here), a
    file the user restored (unless force)."""
    ctx, row, sha, out_path = job.ctx, job.row, job.sha, job.out_path
    assert sha is not None  # hash_original ran first
    # Never poison twice: ppd's own output (here or anywhere) is left alone.
    if out_path is None and row is not None and row["poisoned_sha256"] == sha:
        forget_attempt(ctx.paths.data_dir, job.path)  # killed after its row, before letting go
        st = job.file.st if job.file is not None else None
        if (
            st is not None
            and not job.dry_run
            and (row.get("size"), row.get("mtime_ns")) != (st.st_size, st.st_mtime_ns)
        ):
            # the same bytes under a new time (touched, copied with a new mtime): `ppd status`, which
            # compares the time, would call it changed since patched
            ctx.store.record_file(
                job.path, row["dataset"], FileState.PATCHED, size=st.st_size, mtime_ns=st.st_mtime_ns
            )
        if (published := retry_publish(job)) is not None:  # patched; its move to the publish folder failed
            return published
        if (finished := finish_remark(job, row)) is not None:  # another spec's mark: a re-mark stopped
            return finished
        return job.outcome(Outcome.UNCHANGED, "already patched", poisoned_sha256=sha, output=job.path)
    # An interrupted run of this very path first: its output may equal another file's (the same
    # photo in two datasets), which the look-up below would take as "someone else's output".
    interrupted = (
        out_path is None and row is not None and row["state"] == FileState.PENDING and not job.dry_run
    )
    opened = job.file
    if interrupted and row is not None and opened is not None:
        # the bytes that were hashed: read through the descriptor, checked unchanged afterwards
        hashed, unchanged = fd_path(opened.fd), (lambda: not opened.changed())
        if recover_pending(ctx, row, job.path, sha, job.kind, hashed, unchanged):
            forget_attempt(ctx.paths.data_dir, job.path)
            return job.outcome(Outcome.UNCHANGED, "recovered after an interrupted run", poisoned_sha256=sha)
    earlier = ctx.store.find_poisoned(sha, moved_first=out_path is None, near=job.path)
    if earlier is not None and out_path is not None:  # --out of a file patched already (in place)
        if not job.dry_run:
            copy_patched_as_it_is(job, earlier, _write_out)
        said = "would be copied as it is" if job.dry_run else "copied as it is"
        return job.outcome(Outcome.UNCHANGED, f"already ppd output: {said}", poisoned_sha256=sha,
                           output=job.record_path)  # fmt: skip
    if earlier is not None:  # moved or copied here: recorded, with this dataset's spec (remark)
        return take_in(job, earlier, _record_recognised)
    if (recognised := _recognise_by_marker(job) or recognise_resaved_output(job)) is not None:
        return recognised
    if (
        row is not None
        and row["state"] == FileState.RESTORED
        and row["original_sha256"] == sha
        and not job.force
    ):
        return job.outcome(Outcome.UNCHANGED, "restored by the user; use --force to protect it again")
    return None


def decide(job: Job) -> ProtectOutcome | None:
    """The dataset's spec, then what ends the run before the vault: an up-to-date `--out` copy, a
    file the spec's ratio does not select (recorded 'skipped'), a dry run."""
    ctx, row, sha, out_path = job.ctx, job.row, job.sha, job.out_path
    spec = job.spec = _dataset_spec(job)
    record_path = job.record_path
    if (
        out_path is not None
        and row is not None
        and row["state"] == FileState.PATCHED
        and row["original_sha256"] == sha
        and row["spec_id"] == spec.spec_id
        and record_path.is_file()
        and sha256_file(record_path) == row["poisoned_sha256"]
    ):
        return job.outcome(Outcome.UNCHANGED, "patched copy is up to date", output=record_path)

    rel = job.path.relative_to(job.root).as_posix() if job.path.is_relative_to(job.root) else job.path.name
    # a voice memo saved as .mp4 is left as it is, like a .m4a (it failed, and the daemon quarantined it)
    sound_only = False
    if job.kind == "video":  # PyAV only for a video: a photo's `ppd poison` never loads it
        from poisoner.video.demux import audio_only

        sound_only = audio_only(fd_path(cast(ContainedFile, job.file).fd))
    if sound_only or not spec.selects(rel):
        why = (
            "sound only, no picture: nothing to protect"
            if sound_only else "not selected by the spec's ratio"
        )
        same = row is not None and row["state"] == FileState.SKIPPED and row["original_sha256"] == sha
        if same and row is not None and row["spec_id"] == spec.spec_id:
            return job.outcome(Outcome.UNCHANGED, why)
        if not job.dry_run:
            if out_path is not None:  # the copy is published as it is
                job.work = work_folder(ctx, job.held)
                copy = job.work / job.path.name
                opened = cast(ContainedFile, job.file)  # by open_contained_file, an earlier stage
                if copy_fd_to_path(opened.fd, copy) != sha:
                    raise SourceChanged(f"{job.path.name} changed while being patched; left as it is now")
                _write_out(job, copy)
            ctx.store.record_file(
                record_path, job.dataset, FileState.SKIPPED, original_sha256=sha, spec_id=spec.spec_id,
                poisoned_sha256=None, error=why if sound_only else None, event="skipped",
                detail={"reason": "sound only" if sound_only else "ratio"},
            )  # fmt: skip
        return job.outcome(Outcome.SKIPPED, why, spec_id=spec.spec_id)
    if job.shown_size is not None and (small := spec.too_small(*job.shown_size)) is not None:
        raise ProtectRefused(f"{shown_name(job.path)}: {small}; not patched")  # the dry run says it too
    if job.dry_run:
        return job.outcome(Outcome.PATCHED, "would patch", original_sha256=sha, spec_id=spec.spec_id)
    return None


def _dataset_spec(job: Job) -> PatchSpec:
    """The dataset's subject masks (checked), then its spec: a new dataset's is set now, its corner
    judged on this file and its neighbours (daemon.datasets.dataset.ensure_dataset)."""

    ctx = job.ctx
    job.mask_dir = subject_masks_for(ctx, job.dataset, job.subject_masks)
    if job.dry_run:
        spec = job.wanted_spec or ctx.store.dataset_spec(job.dataset) or ctx.config.spec_for(job.dataset)
        ctx.store.check_file_spec(job.dataset, spec)  # refused as the real run's ensure_dataset would
        return spec
    spec = ensure_dataset(
        ctx, job.dataset, job.root, job.wanted_spec, sample=lambda: _corner_sample(job), mask_dir=job.mask_dir
    )
    if job.subject_masks is not None:  # issue 25: kept with the dataset for later runs and the daemon
        remember_masks(ctx, job.dataset, job.mask_dir)
    return spec


def _corner_sample(job: Job) -> list[Path]:
    """The files a new dataset's corner is judged on: this one, copied through its descriptor under its
    own name (masks are found by name), and the image files next to it
    (daemon.datasets.subject_masks.sibling_images)."""

    assert job.file is not None
    if job.kind != "image":  # a video is never judged (nor copied for it): its neighbours are
        return sibling_images(job.path)
    job.work = job.work or work_folder(job.ctx, job.held)
    folder = job.work / "corner"
    folder.mkdir(exist_ok=True)
    copy = folder / job.path.name
    copy_fd_to_path(job.file.fd, copy)
    return [copy, *sibling_images(job.path)]


def _recognise_by_marker(job: Job) -> ProtectOutcome | None:
    """ppd's own output without a row (a lost store): its seal verifies under this installation's
    key over exactly these bytes (poisoner.provenance). A copied, forged, cropped or edited file
    does not verify and goes on as a new photo. When the vault holds the original the seal names,
    the row is written back (so status and restore see it)."""
    from poisoner.provenance import scan_seals

    assert job.file is not None and job.sha is not None
    ctx = job.ctx
    scan = scan_seals(fd_path(job.file.fd), ctx.seal_key())  # one scan of the file
    seal, claim = scan.seal, scan.claim
    if scan.other_key and not job.force:  # marked again, and its marked bytes vaulted as the original
        raise ProtectRefused(  # (a black-box review, after a lost store and `ppd key new`)
            f"{shown_name(job.path)} is sealed with another key than this installation's: ppd's output made "
            "with another key (`ppd key import` that key), or a photo whose metadata was copied from such a "
            "file (`--force` patches it, its bytes kept as the original); not patched"
        )  # "already ppd's output" misled where only the metadata was copied (a privacy review, F5)
    if seal is None:  # a token that opens but no longer verifies: ppd's output, edited since?
        return recognise_edited_output(job, claim) if claim is not None else None
    if job.out_path is None and not job.dry_run and ctx.vault.has(seal.original_sha256):
        _record_recognised(job, seal.original_sha256, job.sha, seal.spec_id, None, "provenance seal")
    return job.outcome(
        Outcome.UNCHANGED, "already ppd output (its provenance seal says so)", poisoned_sha256=job.sha
    )


def _record_recognised(
    job: Job, original: str, sha: str, spec_id: str | None, version: str | None, source: str,
    when: int | None = None,  # the original's modification time, when a row knows it
) -> None:  # fmt: skip
    """ppd's output recognised in this dataset's folder (by its seal, or as a copy of a stored
    output: source says which): a patched file of the dataset, its original the vault's copy."""
    assert job.file is not None
    ensure_dataset_row(job.ctx, job.dataset, job.root, job.wanted_spec)
    job.ctx.store.record_file(
        job.path, job.dataset, FileState.PATCHED, original_sha256=original, poisoned_sha256=sha,
        spec_id=spec_id, tool_version=version, size=job.file.st.st_size, mtime_ns=job.file.st.st_mtime_ns,
        error=None, event="recognised", detail={"from": source}, original_mtime_ns=when,
    )  # fmt: skip


def keep_in_vault(job: Job) -> ProtectOutcome | None:
    """1. An independent copy of the original (read through its descriptor) goes to the vault, and the
    spec that is to patch it: a seal names only the spec's id, so a store rebuilt from the vault gives
    the dataset its spec back from there (a black-box review: a dataset made with --patch-size came
    back spec-less, and its next photo got the default mark)."""
    assert job.file is not None and job.sha is not None and job.spec is not None
    job.ctx.vault.keep_spec(job.spec)  # once per spec id (Vault.keep_spec)
    data = job.data  # held on: the poisoner's input (poison)
    try:
        if data is not None:  # the bytes that were hashed: written as they are, not read again
            job.ctx.vault.keep_bytes(data, job.sha, times=(job.file.st.st_atime_ns, job.file.st.st_mtime_ns))
        else:
            job.ctx.vault.keep_fd(job.file.fd, expected_sha256=job.sha)
    except VaultContentChanged:
        raise SourceChanged(f"{job.path.name} was written to while being kept; left as it is now") from None
    if job.file.changed():
        raise SourceChanged(f"{job.path.name} was written to while being kept; left as it is now")
    job.work = job.work or work_folder(job.ctx, job.held)
    job.original = job.work / job.path.name  # poisoners pick the format by suffix
    link_or_copy(job.ctx.vault.path_for(job.sha), job.original)  # ppd's own bytes, read only
    return None


def mark_pending(job: Job) -> ProtectOutcome | None:
    """2. A pending row: after a crash we know this path's original is in the vault. An attempt
    marker is held from here until the run ends: if the heavy work kills the process, the daemon
    quarantines the file at its next start instead of retrying it (daemon.protect.quarantine)."""

    assert job.spec is not None
    job.died_before = job.held.enter_context(attempt(job.ctx.paths.data_dir, job.path, job.dataset))
    job.ctx.store.record_file(
        job.record_path, job.dataset, FileState.PENDING, original_sha256=job.sha, spec_id=job.spec.spec_id,
        original_mtime_ns=job.file.st.st_mtime_ns if job.file is not None else None, poisoned_sha256=None,
        error=None, tool_version=tool_version(), event="pending",
        detail={"kind": job.kind}, durable=False,  # no fsync: see the order at the top
    )  # fmt: skip
    return None


def poison(job: Job) -> ProtectOutcome | None:
    """3. The complete patched file, sealed and hashed: made in memory from the bytes hash_original
    read (an image up to IN_MEMORY_MAX, in this process), else written in the private work folder."""
    assert job.work is not None and job.original is not None and job.spec is not None and job.kind
    data, job.data = job.data, None
    marker = provenance_marker(job.ctx, job.spec.spec_id, job.sha)
    limits = {"max_pixels": job.ctx.config.max_pixels} if job.kind == "image" else {}
    if data is not None and not job.died_before:  # an image in memory: patched, sealed, hashed there
        out, job.report = poison_image_bytes(
            job.original, data, job.spec, job.mask_dir, marker=marker, keep_location=job.keep_location,
            **limits,
        )  # fmt: skip
        del data
        patched = bytearray(out)  # sealed in place; the unsealed copy dropped at once (peak: two copies)
        del out
        seal_in_memory(job.ctx, patched, job.path.name)
        job.poisoned_data = patched
        job.poisoned_sha = hashlib.sha256(patched).hexdigest()
        return None
    del data
    job.poisoned = job.work / work_copy_name(PATCHED_PREFIX, job.path.name)
    with no_space_in(job.ctx.vault.vault_dir):  # the work folder is in the vault
        if job.died_before:  # the last attempt took its process down: this one cannot
            job.report = poison_isolated(
                job.kind, job.original, job.poisoned, job.spec, marker, job.keep_location, job.mask_dir,
                **limits,
            )  # fmt: skip
        else:
            job.report = poison_to(
                job.kind, job.original, job.poisoned, job.spec, job.progress, job.mask_dir, marker=marker,
                keep_location=job.keep_location, **limits,
            )  # fmt: skip
        seal_output(job.ctx, job.poisoned)
    if job.kind == "image" and job.poisoned.stat().st_size <= IN_MEMORY_MAX:  # hashed here, written later
        job.poisoned_data = job.poisoned.read_bytes()
        job.poisoned_sha = hashlib.sha256(job.poisoned_data).hexdigest()
    else:
        job.poisoned_sha = sha256_file(job.poisoned)
    return None


def replace_atomically(job: Job) -> ProtectOutcome | None:
    """4. The patched file replaces the original at its name, through the folder's descriptor, only
    if the name still holds the version that was hashed (else SourceChanged: the newer version
    stays). With --out, the copy is written into the output folder instead."""
    assert job.file is not None and (job.poisoned is not None or job.poisoned_data is not None)
    if job.out_path is not None:
        _write_out(job, _patched(job))
        return None
    f = job.file
    assert job.sha is not None
    clear_stale_temps_once(f.dir_fd)
    with no_space_in(job.path.parent), atomic_replace_at(
        f.dir_fd, f.name, mode=stat.S_IMODE(f.st.st_mode), check=still_the_version(f, job.sha, job.path.name)
    ) as (fd, _tmp):
        _write_content(fd, _patched(job))
        st = os.fstat(fd)
    job.poisoned_data = None
    job.written = (st.st_ino, st.st_size, st.st_mtime_ns)
    job.final = job.path
    return None


def record_provenance(job: Job) -> ProtectOutcome | None:
    """5. The patched row: what the original was, which spec, what ppd wrote."""
    assert job.spec is not None
    record_path = job.record_path
    st = os.stat(record_path, follow_symlinks=False) if job.out_path is not None else None
    written = cast(FileSignature, job.written)  # set by replace_atomically, the stage before
    size, mtime = (st.st_size, st.st_mtime_ns) if st else (written[1], written[2])
    job.ctx.store.record_file(
        record_path, job.dataset, FileState.PATCHED, original_sha256=job.sha,
        poisoned_sha256=job.poisoned_sha, spec_id=job.spec.spec_id, tool_version=tool_version(),
        size=size, mtime_ns=mtime, error=None, published_path=None, event="patched",
        detail={**report_detail(job.report), **_copy_of(job)}, saved_over=saved_over(job),
    )  # fmt: skip
    job.final = record_path
    return None


def _copy_of(job: Job) -> dict[str, str]:
    """An `--out` copy's source, kept with its row: what `ppd restore` removes as a copy (restoring)."""
    return {"copy_of": str(job.path)} if job.out_path is not None else {}


STAGES: tuple[Callable[[Job], ProtectOutcome | None], ...] = (
    check_name,
    open_contained_file,
    check_complete,
    hash_original,
    recognise,
    decide,
    keep_in_vault,  # crash-safe order from here: vault → pending → poison → replace → row → publish
    mark_pending,
    poison,
    replace_atomically,
    record_provenance,
    publish,
)


def run_stages(
    job: Job, stages: tuple[Callable[[Job], ProtectOutcome | None], ...] = STAGES
) -> ProtectOutcome:
    """Run the stages in order until one returns an outcome; the job's descriptors and work
    folder are released whatever happens."""
    try:
        for stage in stages:
            outcome = stage(job)
            if outcome is not None:
                return outcome
        return job.outcome(
            Outcome.PATCHED, place_note(job.report), original_sha256=job.sha,
            poisoned_sha256=job.poisoned_sha,
            spec_id=job.spec.spec_id if job.spec else None, output=job.final, report=job.report,
            signature=job.written,
        )  # fmt: skip
    finally:
        job.close()


# ---- writing outside the file's folder ---------------------------------------------------------
def _patched(job: Job) -> Path | bytes | bytearray:
    """The patched file poison() hashed: its bytes in memory, or its work file."""
    content = job.poisoned_data if job.poisoned_data is not None else job.poisoned
    assert content is not None
    return content


def _write_content(fd: int, content: Path | bytes | bytearray) -> None:
    if not isinstance(content, Path):
        write_all(fd, content)
    else:
        copy_path_to_fd(content, fd)


def _write_out(job: Job, content: Path | bytes | bytearray) -> None:
    """`--out`: the copy goes into the output folder the user named (trusted, created if needed)."""
    out = job.record_path
    out.parent.mkdir(parents=True, exist_ok=True)
    dir_fd = open_dir(out.parent)
    try:
        clear_stale_temps_once(dir_fd)
        mode = stat.S_IMODE(job.file.st.st_mode) if job.file is not None else None
        with no_space_in(out.parent), atomic_replace_at(dir_fd, out.name, mode=mode) as (fd, _tmp):
            _write_content(fd, content)
    finally:
        os.close(dir_fd)
