"""The application's entry points for one file: protect_file, restore_file (daemon.protect.restoring),
reprotect_dataset.

protect_file runs daemon.protect.stages's named stages (the crash-safe order is listed there, once)
under a per-file lock shared by every ppd process (daemon.locks), and turns any exception into a
'failed' outcome with a one-line reason. Shared by `ppd poison` and the daemon's workers.
"""

from __future__ import annotations

import functools
import logging
import os
import sqlite3
import stat
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from daemon.context import AppContext
from daemon.datasets.dataset import (
    DatasetConflict,
    DatasetNameError,
    OutsideOutboxError,
    attribute,
    dataset_of,
    ensure_dataset_row,
)
from daemon.datasets.subject_masks import (
    MaskFolderMissing,
    masks_or_none,
    sibling_images,
)
from daemon.fsops import sha256_fd
from daemon.locks import LockHeld, WaitLeft
from daemon.protect.job import (
    IncompleteFile,
    Job,
    Outcome,
    Progress,
    ProtectOutcome,
    ProtectRefused,
    SourceChanged,
    anchor_for,
    is_ignored_name,
    media_kind,
    name_the_disk,
    one_line,
    shown_name,
    storable,
    tool_version,
)
from daemon.protect.poisoning import file_is_the_cause, poison_to
from daemon.protect.remark import note_not_reprotected, reprotect_row
from daemon.protect.restoring import FROM_PUBLISH_FOLDER, restore_file
from daemon.protect.stages import STAGES, run_stages
from daemon.states import FileState
from poisoner.errors import PpdError
from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

__all__ = [
    "FROM_PUBLISH_FOLDER", "STAGES", "AppContext", "Outcome", "ProtectOutcome", "ProtectRefused",
    "SourceChanged", "dataset_pairs", "is_ignored_name", "media_kind", "poison_to", "protect_file",
    "reprotect_dataset", "restore_file", "shown_name", "storable", "tool_version",
]  # fmt: skip
OUTCOME_STATES = (Outcome.PATCHED, Outcome.SKIPPED, Outcome.FAILED, Outcome.UNCHANGED)  # protect_file
RESTORE_STATES = (Outcome.RESTORED, Outcome.UNCHANGED, Outcome.FAILED)  # restore_file
SOURCE_CHANGE_TRIES = 3  # a file replaced while being patched is started over this many times


def failure_message(exc: BaseException, path: Path) -> str:
    """The one-line reason for a failure; a name with a newline is escaped first, so the line
    is not cut in the middle of the file's name."""
    text = str(exc)
    if path.name and shown_name(path) != path.name:
        text = text.replace(path.name, shown_name(path))
    lines = text.strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def _resolve_dataset(ctx: AppContext, path: Path, dataset: str | None, root: Path | None) -> tuple[str, Path]:
    """The caller's (dataset, root) when both are given (`ppd poison` planned them), else
    daemon.datasets.dataset.attribute's, the one rule; a root given alone is kept. Named by neither, the
    file must be in the outbox (OutsideOutboxError): a file from elsewhere comes with its dataset."""
    if dataset is not None and root is not None:
        return dataset, root
    if dataset is None and root is None:
        dataset_of(ctx.paths.outbox, path)  # raises outside the outbox
    # adopt: a dataset whose folder moved here (the outbox moved) follows it, before its files are judged
    name, found = attribute(ctx, path, dataset, folder=False, adopt=True)
    return name, root or found


def protect_file(
    path: Path,
    ctx: AppContext,
    dataset: str | None = None,
    *,
    root: Path | None = None,
    out_path: Path | None = None,
    dry_run: bool = False,
    force: bool = False,
    progress: Progress | None = None,
    spec: PatchSpec | None = None,
    keep_location: bool | None = None,
    subject_masks: Path | None = None,
) -> ProtectOutcome:
    """Patch one file: daemon.protect.stages.STAGES, under the file's lock (daemon.locks).

    dataset/root: default from the outbox layout (daemon.datasets.dataset); `ppd poison FOLDER` passes
    the folder's name and the folder. out_path: write the patched copy there and leave path
    as it is. force: re-patch a file the user restored. spec: the spec a dataset without one
    gets (default: the config's), and the one a dry run assumes. subject_masks: the folder of
    subject masks (`--subject-masks`; default: the dataset's [datasets.NAME] subject_masks). A
    version that replaces the file while it is being patched is left in place and patched next (up
    to SOURCE_CHANGE_TRIES runs; then the outcome asks for a requeue). Never raises for a bad file:
    the outcome says 'failed' with a one-line reason, and nothing is lost.
    """
    started = time.monotonic()
    path = Path(path).absolute()
    try:
        dataset, root = _resolve_dataset(ctx, path, dataset, root)
    except (OutsideOutboxError, DatasetConflict, DatasetNameError) as exc:
        return ProtectOutcome(path=path, dataset=None, state=Outcome.FAILED, reason=one_line(exc))
    root = Path(root).absolute()
    keep = ctx.config.keep_location if keep_location is None else keep_location
    new_job = functools.partial(
        Job, path=path, ctx=ctx, dataset=dataset, root=root, anchor=anchor_for(ctx, path, root),
        out_path=out_path, dry_run=dry_run, force=force, progress=progress, wanted_spec=spec,
        keep_location=keep, subject_masks=subject_masks,
    )  # fmt: skip
    try:
        with ctx.path_lock(out_path or path):
            outcome = _run_until_settled(new_job)
    except WaitLeft as exc:  # stopped while another process had it: not started, so not failed either
        log.warning("%s: %s; not patched by this run", path.name, exc)
        outcome = ProtectOutcome(path=path, dataset=dataset, state=Outcome.SKIPPED, reason=str(exc))
        outcome.left = True
    except LockHeld as exc:  # another process is on it; its own row says what happened
        outcome = ProtectOutcome(path=path, dataset=dataset, state=Outcome.FAILED, reason=one_line(exc))
    except OSError as exc:  # the lock file itself (a full disk): nothing was done
        outcome = _record_failure(ctx, path, dataset, root, out_path, exc, dry_run, spec)
    outcome.seconds = time.monotonic() - started
    log.log(
        logging.INFO if outcome.state in (Outcome.PATCHED, Outcome.FAILED) else logging.DEBUG,
        "protect %s: %s",
        outcome.state,
        path.name,
        extra={"path": str(path), "dataset": dataset, "state": outcome.state, "reason": outcome.reason,
               "seconds": round(outcome.seconds, 3)},
    )  # fmt: skip
    return outcome


def _run_until_settled(new_job: Callable[[], Job]) -> ProtectOutcome:
    """The stages on a fresh Job, again while the source changes under them (SOURCE_CHANGE_TRIES
    runs, then an outcome asking for a requeue); any other exception is recorded as 'failed'."""
    for _ in range(SOURCE_CHANGE_TRIES):
        job = new_job()
        try:
            return run_stages(job)
        except SourceChanged as exc:
            outcome = job.outcome(Outcome.SKIPPED, one_line(exc), requeue=True, signature=None)
            log.info("%s: %s", shown_name(job.path), outcome.reason, extra={"path": str(job.path)})
        except Exception as exc:  # one bad file must not stop the others; record and go on
            return _record_failure(
                job.ctx, job.path, job.dataset, job.root, job.out_path, exc, job.dry_run, job.wanted_spec
            )
    return outcome


def _record_failure(
    ctx: AppContext,
    path: Path,
    dataset: str,
    root: Path,
    out_path: Path | None,
    exc: Exception,
    dry_run: bool,
    spec: PatchSpec | None,
) -> ProtectOutcome:
    message = failure_message(name_the_disk(exc, [(out_path or path).parent, ctx.paths.data_dir]), path)
    if not isinstance(exc, ProtectRefused | SourceChanged):
        log.debug("protect failed", exc_info=exc)
    if out_path is None and not dry_run and _holds_ppd_output(ctx, path):
        # Another run (or process) patched it meanwhile: a patched row is never made 'failed'.
        return ProtectOutcome(
            path=path, dataset=dataset, state=Outcome.UNCHANGED, reason=f"already patched ({message})"
        )
    waits_for = exc.folder if isinstance(exc, MaskFolderMissing) else None
    if not storable(out_path or path):  # no row can name it; the log line says why
        log.info("not recorded: %s: %s", shown_name(path), message, extra={"path": repr(str(path))})
    elif waits_for is not None and ctx.store.dataset_spec(dataset) is None:
        pass  # a new dataset's spec (its corner) is never set without its masks; status names the folder
    elif not dry_run:
        try:  # a new dataset's corner is judged on the files next to this one (it could not be read)
            ensure_dataset_row(
                ctx, dataset, root, spec, sample=lambda: sibling_images(path),
                mask_dir=masks_or_none(ctx, dataset),
            )  # fmt: skip
            ctx.store.record_file(
                out_path or path, dataset, FileState.FAILED, error=message, event="failed",
                # --out: the row is the copy's, never written; the file to fix is the source
                detail={"error": message, "exception": type(exc).__name__,
                        **({"source": str(path)} if out_path is not None else {})},
            )  # fmt: skip
        except Exception as store_exc:  # the store itself failing (disk full) must not hide the first error
            log.error(
                "could not record failure of %s: %s", shown_name(path), one_line(store_exc),
                extra={"path": str(path), "error": message},
            )  # fmt: skip
    return ProtectOutcome(
        path=path, dataset=dataset, state=Outcome.FAILED, reason=message, hopeless=file_is_the_cause(exc),
        incomplete=isinstance(exc, IncompleteFile), waits_for=waits_for,
    )  # fmt: skip


def _holds_ppd_output(ctx: AppContext, path: Path) -> bool:
    """Whether the regular file at path (not followed if a symlink) is ppd's recorded output."""
    if not storable(path):  # no row can name it (the store would refuse the name itself)
        return False
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return False
        sha = sha256_fd(fd)
    except OSError:
        return False
    finally:
        os.close(fd)
    try:
        row = ctx.store.file(path)
        return (row is not None and row["poisoned_sha256"] == sha) or ctx.store.find_poisoned(sha) is not None
    except (PpdError, sqlite3.Error) as exc:  # the store failing too: say failed, as asked
        log.warning(
            "%s: the store cannot say whether it is ppd's output (%s)", shown_name(path), one_line(exc),
            extra={"path": str(path)},
        )  # fmt: skip
        return False


# ---- datasets as a whole ---------------------------------------------------------------------
def dataset_pairs(ctx: AppContext, dataset: str) -> list[tuple[Path, Path]]:
    """(original in the vault, protected file) for every protected file of a dataset whose two
    files both still exist (missing ones are logged, not returned); one per original: a photo patched
    in place and copied with `--out` is one view (a diff review: verify staged every view twice)."""
    pairs, seen = [], set()
    for row in ctx.store.files(dataset, state=FileState.PATCHED):
        original = ctx.vault.path_for(row["original_sha256"])
        protected = Path(row["published_path"] or row["path"])
        if original.is_file() and protected.is_file():
            if row["original_sha256"] not in seen:
                seen.add(row["original_sha256"])
                pairs.append((original, protected))
        else:
            log.info("pair missing", extra={"dataset": dataset, "path": row["path"]})  # callers say why
    return pairs


def reprotect_dataset(ctx: AppContext, dataset: str, spec: PatchSpec) -> list[ProtectOutcome]:
    """Give a dataset a new spec and re-poison its protected files from their vault originals.

    The new poisoned file is made from the vault copy and renamed over the old poisoned one,
    so the original never reappears at the published path, not even briefly.
    """
    row = ctx.store.dataset(dataset)
    if row is None:
        raise ValueError(f"no dataset {dataset!r}")
    root = Path(row["root"])
    before = ctx.store.dataset_spec(dataset)
    ctx.store.set_dataset_spec(dataset, spec, allow_protected=True)
    gone, renamed = changed_since_patched(ctx, dataset, root)
    outcomes = []
    for file_row in ctx.store.files(dataset):
        path = Path(file_row["path"])
        if file_row["state"] == FileState.PATCHED and file_row["path"] in gone:
            outcomes.append(_record_gone(ctx, file_row, root, spec))
        elif file_row["state"] == FileState.PATCHED and file_row["path"] in renamed:
            why = renamed[file_row["path"]]  # it said "is gone (deleted or moved away)" of a renamed file
            note_not_reprotected(ctx, file_row, spec, why)
            outcomes.append(ProtectOutcome(path=path, dataset=dataset, state=Outcome.FAILED, reason=why))
        elif file_row["state"] == FileState.PATCHED:
            outcomes.append(_reprotect_one(ctx, file_row, root, spec))
        elif file_row["state"] in (FileState.SKIPPED, FileState.FAILED, FileState.PENDING) and path.is_file():
            outcomes.append(protect_file(path, ctx, dataset, root=root))
    tried = [o for o in outcomes if o.reason != GONE_REASON]
    if before is not None and tried and all(o.state == Outcome.FAILED for o in tried):
        # nothing carries the new spec: the dataset keeps the one its files carry (a black-box review:
        # a read-only folder, every file failed, and status said "patched 4" under the new spec)
        ctx.store.set_dataset_spec(dataset, before, allow_protected=True)
    return outcomes


GONE_REASON = "deleted or moved away since ppd patched it: recorded so, nothing to re-protect"


def changed_since_patched(ctx: AppContext, dataset: str, root: Path) -> tuple[set[str], dict[str, str]]:
    """(the dataset's patched files deleted or moved away since: status's "gone"; those renamed in its
    folder since, each with why a re-protect does not reach it), while the folder is where the dataset
    says (an outbox moved elsewhere is followed, never taken for deletions). A re-protect records the
    gone ones removed, as a running daemon does when it sees them go: it failed on each, every time, and
    status then held the dataset "patched with another spec" for a file that was not there (a black-box
    review)."""
    from daemon.datasets.folder_count import dataset_folder, resume_command

    folder = dataset_folder(ctx, dataset, str(root))
    if not folder.exists or folder.moved_to is not None:
        return set(), {}
    command = resume_command(dataset, folder)
    then = f"`{command}` records the new name, and a re-protect then reaches it"
    renamed = {str(old): f"{old.name} was renamed {new.name} since ppd patched it: {then}"
               for old, new in folder.renamed}  # fmt: skip
    # in its folder only: `--out` copies on a drive unplugged now are not deleted (a diff review)
    return {str(p) for p in folder.gone if p.is_relative_to(root)}, renamed


def _record_gone(ctx: AppContext, row: dict[str, Any], root: Path, spec: PatchSpec) -> ProtectOutcome:
    path = Path(row["path"])
    with ctx.path_lock(path):
        back = os.path.lexists(path)
        if not back:
            seen = {"previous_state": row["state"], "seen_by": "reprotect"}
            ctx.store.record_file(path, row["dataset"], FileState.REMOVED, event="removed", detail=seen)
    if back:  # there again since the folder was read: re-protected as any other
        return _reprotect_one(ctx, row, root, spec)
    return ProtectOutcome(path=path, dataset=row["dataset"], state=Outcome.UNCHANGED, reason=GONE_REASON)


def _reprotect_one(ctx: AppContext, row: dict[str, Any], root: Path, spec: PatchSpec) -> ProtectOutcome:
    with ctx.path_lock(Path(row["path"])):
        try:
            return reprotect_row(ctx, row, root, spec)
        except SourceChanged as exc:  # saved while it was made: nothing written, the next run judges it
            reason = one_line(exc)
            note_not_reprotected(ctx, row, spec, reason)
            return ProtectOutcome(path=Path(row["path"]), dataset=row["dataset"], state=Outcome.FAILED,
                                  reason=reason)  # fmt: skip
