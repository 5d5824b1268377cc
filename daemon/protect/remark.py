"""One dataset, one spec (docs/STORE.md): a patched file patched again from its vault original with its
dataset's spec, by `ppd dataset set NAME --reprotect` (reprotect_row, for each of its files) and when
ppd's output arrives in a dataset that gives another spec (take_in: moved or copied in from another
dataset; a file known only by its seal, no row naming its output, is a lost store's, whose specs may be
lost too: left as it is).

A black-box review: a photo moved from shoot30 into papers (another design) kept shoot30's mark; the
daemon logged "unchanged ... moved from", `ppd poison` said "unchanged" (exit 0), and the dataset held
two specs. Now it gets papers' mark from its vault original, and the outcome says where it came from;
an original not in the vault fails with one line naming it. A later review: the re-mark was renamed over
the path unchecked (an edit saved meanwhile was lost, kept nowhere), and a file saved again by another
program (a rating written in place) was re-marked, its bytes dropped. Now the write is the stages'
compare-and-swap through the folder's descriptor, and such a file is left as it is, said and noted.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sqlite3
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from daemon.context import AppContext
from daemon.datasets.dataset import ensure_dataset_row
from daemon.datasets.subject_masks import subject_masks_for
from daemon.fsops import ContainedFile, copy_path_to_fd, open_contained
from daemon.protect.job import (
    Job,
    Outcome,
    ProtectOutcome,
    ProtectRefused,
    SourceChanged,
    anchor_for,
    media_kind,
    no_space_in,
    one_line,
    report_detail,
    shown_name,
    still_the_version,
    tool_version,
)
from daemon.protect.poisoning import named_vault_copy, poison_to, provenance_marker, seal_output
from daemon.protect.publishing import not_moved, publish, published_there
from daemon.protect.recovery import carry_moved_row
from daemon.states import EARLIER_SPEC_WORDS, REMARKED_PREFIX
from daemon.store.vault import sha256_file
from poisoner.atomic import atomic_replace_at
from poisoner.errors import PpdError
from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

# stages' _record_recognised: a copy of ppd's output recorded as this dataset's patched file
# (job, original sha256, output sha256, spec_id, tool version, source, original's mtime)
Recorder = Callable[[Job, str, str, str | None, str | None, str, int | None], None]


def reprotect_row(
    ctx: AppContext, row: dict[str, Any], root: Path, spec: PatchSpec, opened: ContainedFile | None = None
) -> ProtectOutcome:
    """A patched file's row made again from its vault original with spec: the new file is made from the
    vault copy and renamed over the old patched one through its folder's descriptor, only if the name
    still holds the file as it was read (the stages' compare-and-swap; the original never shows at its
    path). The caller holds the file's lock; opened: the file as the stages opened and hashed it (else
    it is opened here). A file changed since ppd wrote it, one saved again by another program (its
    bytes the creator's), or an original not in the vault, is refused: the row keeps its earlier spec,
    the reason noted (`ppd status --failed`), outcome failed. A version saved while it is made raises
    SourceChanged, nothing written: the caller judges that version as new (the stages start over)."""
    from daemon.states import FileState

    path, dataset = Path(row["path"]), row["dataset"]
    target = Path(row["published_path"] or row["path"])
    try:
        with contextlib.ExitStack() as held:
            f = opened or held.enter_context(_opened_as_recorded(ctx, row, target, root))
            selected, report, new_sha, st = _remark_in_place(ctx, row, f, root, spec)
        state = Outcome.PATCHED if selected else Outcome.SKIPPED
        ctx.store.record_file(
            path, dataset, FileState.PATCHED if selected else FileState.SKIPPED,
            poisoned_sha256=new_sha if selected else None, spec_id=spec.spec_id,
            tool_version=tool_version(), size=st.st_size, mtime_ns=st.st_mtime_ns,
            error=row["error"] if not_moved(row) else None,  # still to publish: the next run moves it
            event="reprotected", detail={"spec_id": spec.spec_id, **report_detail(report)},
        )  # fmt: skip
    except SourceChanged:
        raise  # the caller's: nothing was written (the stages start over, `--reprotect` notes it)
    except Exception as exc:
        note_not_reprotected(ctx, row, spec, one_line(exc))
        return ProtectOutcome(path=path, dataset=dataset, state=Outcome.FAILED, reason=one_line(exc))
    return ProtectOutcome(
        path=path, dataset=dataset, state=state, original_sha256=row["original_sha256"],
        poisoned_sha256=new_sha if state == Outcome.PATCHED else None, spec_id=spec.spec_id, output=target,
        signature=(st.st_ino, st.st_size, st.st_mtime_ns), report=report,
    )  # fmt: skip


def resaved_reason(name: str) -> str:
    """Why a file saved again by another program (files.resaved) is not re-marked: its bytes are the
    creator's (a rating, keywords), and a re-mark from the vault original would drop them, kept nowhere;
    restore --force keeps them in DATA/displaced, as it does for any such file."""
    return (
        f"{name} was saved again by another program since ppd patched it (its bytes are yours): not "
        f"re-marked; `ppd restore FILE --force` keeps your version, then `ppd poison FILE --force` marks "
        "it with this dataset's spec"
    )


@contextlib.contextmanager
def _opened_as_recorded(
    ctx: AppContext, row: dict[str, Any], target: Path, root: Path
) -> Iterator[ContainedFile]:
    """The patched file opened without following a symlink (daemon.fsops), refused unless it holds
    what ppd wrote there (read through its descriptor)."""
    if not target.is_file():  # it said "changed" of a deleted photo (a helper's review)
        raise ProtectRefused(f"{target.name} is gone (deleted or moved away since ppd protected it); "
                             "not re-protecting it")  # fmt: skip
    root = root.absolute()
    # a publish folder (outside the dataset's folder) is ppd's own: trusted as far as the file's folder
    anchor = anchor_for(ctx, target, root) if target.absolute().is_relative_to(root) else target.parent
    f = open_contained(anchor, target)
    try:
        if f.sha256() != row["poisoned_sha256"]:
            raise ProtectRefused(f"{target.name} changed since ppd protected it; not re-protecting it")
        yield f
    finally:
        f.close()


def _remark_in_place(
    ctx: AppContext, row: dict[str, Any], f: ContainedFile, root: Path, spec: PatchSpec
) -> tuple[bool, Any, str, os.stat_result]:
    """Make row's file again from its vault original with spec in a private work folder, then put it at
    f's name if that still holds f as read (job.still_the_version): (whether the spec's ratio selects
    it, else its original is put back; the poisoner's report; the sha256 written; its stat)."""
    name, dataset = f.path.name, row["dataset"]
    if row.get("resaved"):
        raise ProtectRefused(resaved_reason(name))
    if not ctx.vault.verify(row["original_sha256"]):
        raise ProtectRefused(f"the vault copy of {Path(row['path']).name} is missing or corrupt")
    ctx.vault.keep_spec(spec)  # as the stages' keep_in_vault does: a rebuilt store finds it there
    kind = media_kind(f.path) or "image"
    path = Path(row["path"])
    rel = path.relative_to(root).as_posix() if path.is_relative_to(root) else path.name
    report, selected = None, spec.selects(rel)
    with named_vault_copy(ctx, row["original_sha256"], name) as original:
        made = original
        if selected:
            made = original.with_name(f"remarked-{name}")  # the same suffix: poisoners go by it
            marker = provenance_marker(ctx, spec.spec_id, row["original_sha256"])
            limits: dict[str, Any] = {"max_pixels": ctx.config.max_pixels} if kind == "image" else {}
            with no_space_in(ctx.vault.vault_dir):  # the work folder is in the vault
                report = poison_to(
                    kind, original, made, spec, subject_masks=subject_masks_for(ctx, dataset),
                    marker=marker, keep_location=ctx.config.keep_location, **limits,
                )  # fmt: skip
                seal_output(ctx, made)
        new_sha = sha256_file(made)
        check = still_the_version(f, row["poisoned_sha256"], name)
        with no_space_in(f.path.parent), atomic_replace_at(
            f.dir_fd, f.name, mode=stat.S_IMODE(f.st.st_mode), check=check
        ) as (fd, _tmp):
            copy_path_to_fd(made, fd)
            st = os.fstat(fd)
    return selected, report, new_sha, st


def note_not_reprotected(ctx: AppContext, row: dict[str, Any], spec: PatchSpec, reason: str) -> None:
    """Keep why a patched file was not re-protected, for `ppd status --failed`; a store that fails
    here too leaves the command's own line as the only word of it."""
    try:
        ctx.store.note_not_reprotected(row["path"], row["dataset"], reason, spec.spec_id)
    except (PpdError, sqlite3.Error) as exc:
        log.warning("%s: not recorded as not re-protected (%s)", shown_name(Path(row["path"])), one_line(exc))


def take_in(job: Job, earlier: dict[str, Any], record: Recorder) -> ProtectOutcome:
    """ppd's output found at job.path, earlier the row of the file it is (a move: the row follows it)
    or a copy of (recorded as this dataset's file when the vault holds its original). Patched with
    another spec than this dataset's, it is patched again with this one's (remarked); a new dataset
    takes the spec it came with, as a renamed folder does (unless `ppd poison` flags ask another)."""
    ctx, sha = job.ctx, job.sha
    assert sha is not None  # hash_original ran first
    published = published_there(job.row)
    if published is not None and (job.row or {}).get("original_sha256") != earlier["original_sha256"]:
        # carried here, its row took the place of the published photo's, whose original then no
        # restore could give back, and its publish moved it over that photo (a diff review)
        return job.outcome(Outcome.FAILED, (
            f"{shown_name(job.path)}: ppd's output ({_came(job, earlier)}), but dataset {job.dataset!r} "
            f"published another photo under this name ({published}); left as it is, with its mark: "
            "rename it, and the next run takes it in"), poisoned_sha256=sha)  # fmt: skip
    if job.dry_run:
        if (foreign := _foreign(job, earlier["spec_id"])) is not None:
            why = f"would patch: {_came(job, earlier)}"
            return job.outcome(Outcome.PATCHED, why, spec_id=foreign.spec_id)
        return job.outcome(Outcome.UNCHANGED, "already ppd output", poisoned_sha256=sha)
    ensure_dataset_row(ctx, job.dataset, job.root, job.wanted_spec or _spec(ctx, earlier["spec_id"]))
    original = earlier["original_sha256"]
    if carry_moved_row(ctx, earlier, job.path, job.dataset, job.root):
        return remarked(job, earlier, f"moved from {earlier['path']}")
    if original and ctx.vault.has(original):
        # a copy of ppd's output kept where it is (another dataset's file copied in): with no row
        # status called it "not patched yet" and poison "unchanged", round and round (a review)
        record(job, original, sha, earlier.get("spec_id"), earlier.get("tool_version"), earlier["path"],
               earlier.get("original_mtime_ns"))  # fmt: skip
    return remarked(job, earlier, "already ppd output")


def finish_remark(job: Job, row: dict[str, Any]) -> ProtectOutcome | None:
    """job.path's own patched row (its bytes ppd's output) with another spec than its dataset's and no
    failed re-mark noted: a re-mark a kill stopped after the moved row was recorded, or a `--reprotect`
    that did not finish. Every later run said "already patched" and the file kept the other spec's mark
    (a diff review); it is marked again now. None: nothing to finish (a failed re-mark stays listed by
    `ppd status --failed`, as before)."""
    if row.get("error") is not None or (spec := _foreign(job, row.get("spec_id"))) is None:
        return None
    if job.dry_run:
        return job.outcome(Outcome.PATCHED, f"would patch: {_came(job, row)}", spec_id=spec.spec_id)
    return remarked(job, row, "already patched")


def _spec(ctx: AppContext, spec_id: str | None) -> PatchSpec | None:
    try:
        return ctx.store.get_spec(spec_id) if spec_id else None
    except PpdError:  # not stored: the config's
        return None


def remarked(job: Job, came: dict[str, Any], said: str) -> ProtectOutcome:
    """job.path's file, recorded with came's spec and original (came: the row of the output it is),
    patched again with its dataset's spec when that is another one; else unchanged (said). Either way,
    recorded as this dataset's patched file, it is published as the dataset's others are."""
    row = job.ctx.store.file(job.path)
    recorded = row is not None and row["dataset"] == job.dataset and row["poisoned_sha256"] == job.sha
    spec = _foreign(job, came.get("spec_id"))
    if spec is None:
        unchanged = job.outcome(Outcome.UNCHANGED, said, poisoned_sha256=job.sha)
        return _published(job, unchanged) if recorded else unchanged
    why = _came(job, came)
    if row is None or not recorded:
        # not recorded here: its original is not in the vault (a forgotten dataset's, a lost vault)
        reason = (f"{shown_name(job.path)} carries ppd's mark with another spec than the one of "
                  f"dataset {job.dataset!r} ({why}), and its original is not in the vault to patch it again "
                  "with this one's: put the unmarked photo here instead")  # fmt: skip
        return job.outcome(Outcome.FAILED, reason, poisoned_sha256=job.sha)
    if came.get("resaved"):  # a copy of a file saved again by another program: its bytes the creator's too
        row = {**row, "resaved": 1}
    # a version saved meanwhile: SourceChanged, the stages start over on it (one_file._run_until_settled)
    outcome = reprotect_row(job.ctx, row, job.root, spec, job.file)
    if outcome.state == Outcome.FAILED:
        theirs = f"not the one of dataset {job.dataset!r}"
        outcome.reason = f"{outcome.reason} ({why}: it keeps that mark, {theirs})"
    elif outcome.state == Outcome.SKIPPED:  # its mark taken off: the original, as the spec's ratio leaves it
        outcome.reason = f"not selected by this dataset's spec's ratio: its original put back ({why})"
    else:
        outcome.reason = f"{REMARKED_PREFIX}: {why}"
    outcome.kind = job.kind
    return _published(job, outcome) if outcome.state == Outcome.PATCHED else outcome


def _published(job: Job, outcome: ProtectOutcome) -> ProtectOutcome:
    """A file moved or copied in (re-marked or not) goes where its dataset's patched files go: the stages'
    publish step, a move that fails recorded and moved at the next run as theirs is (publishing). A diff
    review: a re-marked file stayed in the outbox while every other patched file of its dataset was
    published."""
    job.poisoned_sha, job.written = outcome.poisoned_sha256, outcome.signature
    if (failed := publish(job)) is not None:
        return failed
    if job.final is not None:  # moved out
        outcome.output = job.final
    return outcome


def _foreign(job: Job, spec_id: str | None) -> PatchSpec | None:
    """The dataset's spec, when a file patched with spec_id does not carry it (None: it does, or the
    dataset has none yet: a first file of a dataset gives it its spec)."""
    spec = job.ctx.store.dataset_spec(job.dataset)
    return spec if spec is not None and spec_id and spec.spec_id != spec_id else None


def _came(job: Job, came: dict[str, Any]) -> str:
    """Where a file with another spec's mark came from, for its outcome's reason."""
    source, dataset = came["path"], came["dataset"]
    if dataset != job.dataset:
        moved = not os.path.lexists(source)
        return f"it came from dataset {dataset!r} ({'moved' if moved else 'copied'} from {source})"
    return EARLIER_SPEC_WORDS
