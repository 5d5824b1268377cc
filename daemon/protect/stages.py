"""One file patched end to end, as a list of named stages over one small state object (`Job`).

    STAGES = check_name → open_contained_file → check_complete → hash_original → recognise →
             decide → keep_in_vault → mark_pending → poison → replace_atomically →
             record_provenance → publish

Each stage is a small function `stage(job) -> ProtectOutcome | None`: None hands the job to the
next stage, an outcome ends the run there (unchanged, skipped, dry run). Exceptions end it as
'failed' (daemon.protect.one_file.protect_file records them).

The crash-safety argument is the order of the last six (docs/STORE.md):
1. keep_in_vault: an independent copy of the original's bytes (Vault.keep_fd, read through the
   file's descriptor, never a link) is in the vault, fsynced and hash-checked, before anything else;
2. mark_pending: a 'pending' row naming the original's sha256 is committed;
3. poison: the complete patched file (with its provenance marker) is written in ppd's private
   work folder (in a child process when the last attempt on this file died with its process);
4. replace_atomically: it is copied to a flock()ed temporary in the file's own folder (through
   that folder's descriptor), fsynced, and renamed over the file only if the file at that name is
   still the one that was hashed (compare-and-swap on device, inode, size, mtime and sha256, just
   before the rename); otherwise the new version is left in place and the run starts over;
5. record_provenance: the patched row with the patched sha256;
6. publish: the patched file moved to the dataset's publish folder, if it has one.
A crash between any two steps leaves the original or the complete patched file at the path, and
the original in the vault whenever the path may hold the patched one.

Containment (daemon.fsops): the file is opened once, relative to a descriptor of its folder
reached from the anchor (the outbox or the folder given to `ppd poison`) without following a
symlink; every later read and write goes through those descriptors, never through the path.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import shutil
import stat
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.datasets.dataset import ensure_dataset
from daemon.datasets.subject_masks import SubjectMaskError, mask_folder_holding, masks_or_none
from daemon.fsops import (
    ContainedFile,
    clear_stale_temps_once,
    copy_fd_to_path,
    copy_path_to_fd,
    identity,
    move_out,
    open_contained,
    open_dir,
)
from daemon.platform import fd_path, writers_of
from daemon.states import FileState
from daemon.store.vault import VaultContentChanged, sha256_file
from poisoner.atomic import TEMP_PREFIX, atomic_replace_at
from poisoner.errors import ExitStatus, PpdError
from poisoner.media import is_image, is_video
from poisoner.spec import PatchSpec

if TYPE_CHECKING:
    from daemon.context import AppContext

log = logging.getLogger(__name__)

Progress = Callable[[int, int | None], None]
PATCHED_PREFIX = "patched-"  # the poison stage's output in the private work folder
FileSignature = tuple[int, int, int]  # (inode, size, mtime_ns), as daemon.watch.watcher compares them


class Outcome(StrEnum):
    """What protect_file / restore_file did with one file (ProtectOutcome.state)."""

    PATCHED = "patched"  # the mark is in the file now
    UNCHANGED = "unchanged"  # nothing to do (already ppd's output, restored by the user, ...)
    SKIPPED = "skipped"  # left as it is (not a supported file, not selected, still being written)
    FAILED = "failed"  # could not be patched; reason says why, nothing lost
    QUARANTINED = "quarantined"  # the daemon moved it out of the outbox (reason says why)
    RESTORED = "restored"  # restore_file put the original back


class ProtectRefused(PpdError):
    """The file must not be touched (symlink, outside its dataset, not a regular file)."""

    exit_status = ExitStatus.FAILED


class SourceChanged(PpdError):
    """The source changed while it was being patched."""

    exit_status = ExitStatus.FAILED


@dataclass
class ProtectOutcome:
    path: Path
    dataset: str | None
    state: str  # an Outcome
    reason: str | None = None  # why skipped/unchanged, or the one-line error when failed
    kind: str | None = None  # 'image' | 'video'
    original_sha256: str | None = None
    poisoned_sha256: str | None = None
    spec_id: str | None = None
    output: Path | None = None  # where the patched file is now
    seconds: float = 0.0
    dry_run: bool = False
    report: Any = None  # poisoner.formats.PoisonReport (poisoner.video.VideoReport is one)
    # What ppd judged or wrote at path (the watcher's echo filter): a later version differs.
    signature: FileSignature | None = None
    requeue: bool = False  # a newer version arrived meanwhile: process the path again
    hopeless: bool = False  # failed because of the file itself (format, structure, name): a retry fails too
    incomplete: bool = False  # failed because its structure is incomplete: its writer may not be done


@dataclass
class Job:
    """The state one file carries through the stages."""

    path: Path  # absolute, as asked; for messages and the store only
    ctx: AppContext
    dataset: str
    root: Path  # the dataset's folder (the spec's ratio is judged by the path below it)
    anchor: Path  # the trusted folder containment is judged from (outbox, or the dataset's root)
    out_path: Path | None = None  # `ppd poison --out`: write there, leave path as it is
    dry_run: bool = False
    force: bool = False
    progress: Progress | None = None
    wanted_spec: PatchSpec | None = None
    keep_location: bool = False
    subject_masks: Path | None = None  # the caller's mask folder (`--subject-masks`); else the config's
    # filled by the stages
    mask_dir: Path | None = None  # the dataset's subject masks, checked (daemon.datasets.subject_masks)
    file: ContainedFile | None = None
    kind: str | None = None
    sha: str | None = None
    row: dict[str, Any] | None = None
    spec: PatchSpec | None = None
    work: Path | None = None  # private folder inside the vault
    original: Path | None = None  # private copy of the original, named like the file
    poisoned: Path | None = None
    poisoned_sha: str | None = None
    written: FileSignature | None = None
    report: Any = None
    final: Path | None = None
    held: contextlib.ExitStack = field(default_factory=contextlib.ExitStack)  # released by close()
    died_before: int = 0  # earlier attempts on this file that died with their process

    @property
    def record_path(self) -> Path:
        return Path(self.out_path).absolute() if self.out_path is not None else self.path

    def outcome(self, state: str, reason: str | None = None, **kw: Any) -> ProtectOutcome:
        kw.setdefault("kind", self.kind)
        if "signature" not in kw and self.file is not None:
            kw["signature"] = (self.file.st.st_ino, self.file.st.st_size, self.file.st.st_mtime_ns)
        return ProtectOutcome(
            path=self.path, dataset=self.dataset, state=state, reason=reason, dry_run=self.dry_run, **kw
        )

    def close(self) -> None:
        self.held.close()
        if self.file is not None:
            self.file.close()
        if self.work is not None:
            shutil.rmtree(self.work, ignore_errors=True)


# ---- small helpers ---------------------------------------------------------------------------
def tool_version() -> str:
    from daemon.version import ppd_version

    return f"ppd {ppd_version()}"


def one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def storable(path: Path) -> bool:
    """Whether the store can record this path: SQLite text is UTF-8, and a name with bytes
    that are not UTF-8 (surrogate-escaped by Python) cannot be written to it."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def shown_name(path: Path) -> str:
    """path's name as it can be shown on one line: escaped (repr-style) when it holds a newline,
    another control character or bytes that are not UTF-8."""
    name = path.name
    return name if name.isprintable() and storable(path) else repr(name)[1:-1]


def media_kind(path: Path) -> str | None:
    """'image', 'video' or None, by suffix."""
    if is_image(path):
        return "image"
    return "video" if is_video(path) else None


def poison_to(
    kind: str,
    src: Path,
    dst: Path,
    spec: PatchSpec,
    progress: Progress | None = None,
    subject_masks: Path | None = None,
    **options: Any,
) -> Any:
    """Write the complete poisoned version of src to dst; never touches src. subject_masks: a folder
    whose mask for src's name (daemon.datasets.subject_masks.load_keep_out) marks pixels the mark never
    changes;
    a folder without one for this image patches it without keep-out (logged)."""
    if kind == "video":
        from poisoner.video import poison_video

        return poison_video(src, dst, spec, progress=progress, **options)
    from PIL import Image

    from poisoner.formats import poison_file

    max_pixels = options.get("max_pixels")
    if max_pixels is not None and (Image.MAX_IMAGE_PIXELS or 0) < max_pixels:
        # Pillow's own bomb check would refuse what the user's raised [limits] allows.
        Image.MAX_IMAGE_PIXELS = max_pixels
    if subject_masks is not None:
        from daemon.datasets.subject_masks import load_keep_out

        keep_out = load_keep_out(Path(subject_masks), src)
        if keep_out is not None:
            options["keep_out"] = keep_out
    return poison_file(src, dst, spec, **options)


class PoisonerDied(PpdError):
    """The isolated poisoner process died (a signal: out of memory, a decoder crash)."""

    exit_status = ExitStatus.FAILED


def poison_isolated(
    kind: str,
    src: Path,
    dst: Path,
    spec: PatchSpec,
    marker: Any,
    keep_location: bool,
    subject_masks: Path | None = None,
    **limits: int,
) -> None:
    """poison_to in a child process: a file that kills its process kills only the child. A child
    killed by a signal raises PoisonerDied; one that fails raises its last error line. The mask
    folder crosses as a path; the child loads the mask."""
    import json
    import subprocess
    import sys

    args = {
        "kind": kind, "src": os.fsdecode(src), "dst": os.fsdecode(dst), "spec": spec.to_dict(),
        "marker": {"text": marker.text},  # the placeholder only: the key never leaves this process
        "keep_location": keep_location, "limits": limits,
        "subject_masks": os.fsdecode(subject_masks) if subject_masks is not None else None,
    }  # fmt: skip
    from verifier.childenv import child_env

    done = subprocess.run(
        [sys.executable, "-m", "daemon.protect.child", json.dumps(args)],
        capture_output=True, text=True, env=child_env(), check=False,
    )  # fmt: skip
    if done.returncode < 0:
        raise PoisonerDied(
            f"{src.name}: patching it killed its process twice (signal {-done.returncode}: out of memory or "
            "a decoder crash); not retried"
        )
    if done.returncode != 0:
        lines = [line for line in done.stderr.strip().splitlines() if line.strip()]
        raise RuntimeError(lines[-1] if lines else f"the isolated poisoner failed ({done.returncode})")
    return None


def file_is_the_cause(exc: BaseException) -> bool:
    """Whether a failure is the file's own (its format, structure, size or name), so retrying it
    changes nothing (the daemon quarantines such files); disk, store, lock and vault-limit
    failures are not."""
    from poisoner.formats import ImageFormatError

    try:
        from poisoner.video import VideoFormatError
    except ImportError:  # PyAV missing
        VideoFormatError = ImageFormatError  # noqa: N806
    return isinstance(
        exc, ProtectRefused | IncompleteFile | PoisonerDied | ImageFormatError | VideoFormatError
    ) or (isinstance(exc, ValueError) and not isinstance(exc, OSError))


def is_ignored_name(path: Path) -> bool:
    """Dot-files and our own temporaries are never protected."""
    return path.name.startswith(".") or path.name.startswith(TEMP_PREFIX)


def provenance_marker(ctx: AppContext, spec_id: str, original_sha256: str | None) -> Any:
    """The seal placeholder every patched file carries (poisoner.provenance); `seal_output` seals
    the finished file: ppd knows its own output without a row, nobody else can read or forge it."""
    from poisoner.provenance import Marker

    return Marker.placeholder(ctx.seal_key(), spec_id, original_sha256 or "")


def seal_output(ctx: AppContext, path: Path) -> None:
    """Seal a finished patched file in place (its placeholder's tag over exactly its bytes)."""
    from poisoner.provenance import seal_file

    seal_file(path, ctx.seal_key())


def link_or_copy(src: Path, dst: Path) -> None:
    """A hard link between two of ppd's private files (the vault and its work folders), else a copy."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


NAME_MAX = 255  # bytes in one file name (Linux filesystems)


def work_copy_name(prefix: str, name: str) -> str:
    """prefix + name for a private work copy, shortened (the suffix kept: poisoners pick the
    format by it) when that would pass NAME_MAX: a 255-byte name is still patched."""
    full = prefix + name
    if len(os.fsencode(full)) <= NAME_MAX:
        return full
    import hashlib

    suffix = Path(name).suffix if len(os.fsencode(Path(name).suffix)) <= 32 else ""
    return f"{prefix}{hashlib.sha256(os.fsencode(name)).hexdigest()[:32]}{suffix}"


WORK_PREFIX = ".work-"
_work_cleared: set[Path] = set()


def work_folder(ctx: AppContext, held: contextlib.ExitStack | None = None) -> Path:
    """A private scratch folder inside the vault (same filesystem: the vault links from it),
    flock()ed while in use (held owns the lock). The first call in a process removes stale
    ones: left by a killed process, so unlocked."""
    vault_dir = Path(ctx.vault.vault_dir)
    if vault_dir not in _work_cleared:
        _work_cleared.add(vault_dir)
        clear_stale_work_folders(vault_dir)
    folder = Path(tempfile.mkdtemp(prefix=WORK_PREFIX, dir=vault_dir))
    if held is not None:
        fd = os.open(folder / ".lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        fcntl.flock(fd, fcntl.LOCK_EX)
        held.callback(os.close, fd)
    return folder


def clear_stale_work_folders(vault_dir: Path, min_age_s: float = 10.0) -> list[Path]:
    """Remove `.work-*` folders no living process holds (their lock is free) and at least
    min_age_s old (the instant between a folder's creation and its lock)."""
    removed = []
    for folder in Path(vault_dir).glob(f"{WORK_PREFIX}*"):
        try:
            if time.time() - folder.lstat().st_mtime < min_age_s or folder.is_symlink():
                continue
            fd = os.open(folder / ".lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            continue
        finally:
            os.close(fd)
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    return removed


def place_note(report: Any) -> str | None:
    """A patched file's note when its per-photo mark found no free place (issue 25: said per file
    and counted in the summary, never silent); None otherwise."""
    place = getattr(report, "place", None)
    return place.short() if place is not None else None


def report_detail(report: Any) -> dict[str, Any]:
    detail: dict[str, Any] = {}
    for name in ("format", "width", "height", "preserved", "notes", "frames", "codec"):
        if hasattr(report, name):
            detail[name] = getattr(report, name)
    placement = getattr(report, "placement", None)
    if placement is not None:
        detail["placement"] = {
            "x": placement.x,
            "y": placement.y,
            "size": placement.size,
            "block": placement.block,
        }
    place = getattr(report, "place", None)
    if place is not None:  # where a per-photo mark shows and why (ppd report, status)
        detail["place"] = {"box": list(place.box), "words": place.words, "source": place.source,
                           "free": place.free, "orientation": place.orientation}  # fmt: skip
    return detail


def publish_dir(ctx: AppContext, dataset: str) -> Path | None:
    row = ctx.store.dataset(dataset)
    return Path(row["publish_dir"]) if row and row["publish_dir"] else None


# ---- runs that stopped half-way, files that moved ------------------------------------------
def carry_moved_row(ctx: AppContext, earlier: dict[str, Any], path: Path, dataset: str, root: Path) -> bool:
    """A patched file that was moved or renamed (a dataset folder renamed in the outbox, say)
    keeps its provenance: its row follows it to the new path instead of dropping out of the
    store, so status, restore and verification still see it. Copies (the old path still there)
    are left as they are."""
    old = Path(earlier["path"])
    if old == path or old.exists() or earlier["state"] not in (FileState.PATCHED, FileState.REMOVED):
        return False
    fields = {k: earlier[k] for k in ("original_sha256", "poisoned_sha256", "spec_id", "tool_version")}
    # A dataset first seen through moved files (a renamed folder) inherits their patch spec.
    ensure_dataset(ctx, dataset, root, ctx.store.get_spec(earlier["spec_id"]))
    st = path.stat()
    ctx.store.record_file(
        path, dataset, FileState.PATCHED, event="moved", detail={"from": str(old)},
        size=st.st_size, mtime_ns=st.st_mtime_ns, **fields,
    )  # fmt: skip
    ctx.store.record_file(
        old, earlier["dataset"], FileState.REMOVED, event="moved_away", detail={"to": str(path)}
    )
    return True


def recover_pending(ctx: AppContext, row: dict[str, Any], path: Path, sha: str, kind: str | None) -> bool:
    """A 'pending' row means a run stopped between keeping the original and recording the
    result. If the file now differs from the original, it may be our complete output (the
    rename happened, the final row did not): poisoning is deterministic, so poison the vault
    original again and compare. True (and the row completed) when it is ours."""
    original_sha = row["original_sha256"]
    if not kind or not original_sha or sha == original_sha or not ctx.vault.verify(original_sha):
        return False
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
        except Exception:  # cannot redo it: treat the file as new content
            return False
        if sha256_file(scratch) != sha:
            return False
    st = path.stat()
    ctx.store.record_file(
        path, row["dataset"], FileState.PATCHED, poisoned_sha256=sha, size=st.st_size,
        mtime_ns=st.st_mtime_ns, error=None, event="recovered", detail={"from": "pending"},
    )  # fmt: skip
    return True


@contextlib.contextmanager
def named_vault_copy(ctx: AppContext, sha256: str, name: str) -> Iterator[Path]:
    """The vault blob under its original file name (poisoners pick the format by suffix), as a
    hard link in a private temporary folder inside the vault."""
    folder = Path(tempfile.mkdtemp(prefix=".named-", dir=ctx.vault.vault_dir))
    link = folder / name
    try:
        try:
            os.link(ctx.vault.path_for(sha256), link)
        except OSError:
            shutil.copyfile(ctx.vault.path_for(sha256), link)
        yield link
    finally:
        shutil.rmtree(folder, ignore_errors=True)


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
    from daemon.fsops import NotContained

    try:
        job.file = open_contained(job.anchor, job.path)
    except NotContained as exc:
        raise ProtectRefused(str(exc)) from None
    job.kind = media_kind(job.path)
    if job.kind is None:  # not ours to judge (sidecars, notes): left alone, no row
        return job.outcome(Outcome.SKIPPED, "not a supported image or video")
    return None  # an empty file is judged by check_complete (a writer may be about to fill it)


class IncompleteFile(PpdError):
    """The file's structure is incomplete (a truncated upload, a writer that gave up)."""

    exit_status = ExitStatus.FAILED


class UnrecognisedFile(PpdError, ValueError):
    """The file does not begin like any image or video ppd reads (nor can appending make it one)."""

    exit_status = ExitStatus.FAILED


def check_complete(job: Job) -> ProtectOutcome | None:
    """Only complete files go on: one still open for writing by another process is skipped (its
    close re-arms the watcher); one whose structure is incomplete, or whose header declares more
    pixels than the decode budget, is refused here, before anything reaches the vault."""
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
        why = f"still open for writing by pid {pids[0]}; patched once it is closed"
        return job.outcome(Outcome.SKIPPED, why, signature=None)
    if starts_like_media(os.pread(job.file.fd, 16, 0)) is False:
        # before the vault: a tail fragment (a writer's next append) is never kept as an original
        raise UnrecognisedFile(
            f"{job.path.name} is not a recognised image or video (its first bytes match no format ppd reads)"
        )
    if reason is not None:
        raise IncompleteFile(f"{job.path.name} is incomplete ({reason}); not patched")
    if job.kind == "image":
        from poisoner.limits import check_decode_budget

        limits = {"name": job.path.name, "max_bytes": job.ctx.config.max_memory_bytes}
        check_decode_budget(through_fd, job.ctx.config.max_pixels, **limits)  # type: ignore[arg-type]
    return None


def hash_original(job: Job) -> ProtectOutcome | None:
    assert job.file is not None
    job.sha = job.file.sha256()
    job.row = job.ctx.store.file(job.record_path)
    return None


def recognise(job: Job) -> ProtectOutcome | None:
    """What is never patched again: ppd's own output (by its row, its sha256 anywhere in the
    store, or its provenance marker), a run of this path that was interrupted (finished here), a
    file the user restored (unless force)."""
    ctx, row, sha, out_path = job.ctx, job.row, job.sha, job.out_path
    # Never poison twice: ppd's own output (here or anywhere) is left alone.
    if out_path is None and row is not None and row["poisoned_sha256"] == sha:
        return job.outcome(Outcome.UNCHANGED, "already patched", poisoned_sha256=sha, output=job.path)
    # An interrupted run of this very path first: its output may equal another file's (the same
    # photo in two datasets), which the look-up below would take as "someone else's output".
    interrupted = (
        out_path is None and row is not None and row["state"] == FileState.PENDING and not job.dry_run
    )
    if interrupted and recover_pending(ctx, row, job.path, sha, job.kind):
        return job.outcome(Outcome.UNCHANGED, "recovered after an interrupted run", poisoned_sha256=sha)
    earlier = ctx.store.find_poisoned(sha)
    if earlier is not None:
        moved = out_path is None and not job.dry_run
        if moved and carry_moved_row(ctx, earlier, job.path, job.dataset, job.root):
            return job.outcome(Outcome.UNCHANGED, f"moved from {earlier['path']}", poisoned_sha256=sha)
        return job.outcome(Outcome.UNCHANGED, "already ppd output", poisoned_sha256=sha)
    if (recognised := _recognise_by_marker(job)) is not None:
        return recognised
    if (
        row is not None
        and row["state"] == FileState.RESTORED
        and row["original_sha256"] == sha
        and not job.force
    ):
        return job.outcome(Outcome.UNCHANGED, "restored by the user (use --force to protect it again)")
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
    if not spec.selects(rel):
        same = row is not None and row["state"] == FileState.SKIPPED and row["original_sha256"] == sha
        if same and row is not None and row["spec_id"] == spec.spec_id:
            return job.outcome(Outcome.UNCHANGED, "not selected by the spec's ratio")
        if not job.dry_run:
            if out_path is not None:  # the copy is published as it is
                job.work = work_folder(ctx, job.held)
                copy = job.work / job.path.name
                if copy_fd_to_path(job.file.fd, copy) != sha:  # type: ignore[union-attr]
                    raise SourceChanged(f"{job.path.name} changed while being patched; left as it is now")
                _write_out(job, copy)
            ctx.store.record_file(
                record_path, job.dataset, FileState.SKIPPED, original_sha256=sha, spec_id=spec.spec_id,
                poisoned_sha256=None, error=None, event="skipped", detail={"reason": "ratio"},
            )  # fmt: skip
        return job.outcome(Outcome.SKIPPED, "not selected by the spec's ratio", spec_id=spec.spec_id)
    if job.dry_run:
        return job.outcome(Outcome.PATCHED, "would patch", original_sha256=sha, spec_id=spec.spec_id)
    return None


def _dataset_spec(job: Job) -> PatchSpec:
    """The dataset's subject masks (checked), then its spec: a new dataset's is set now, its corner
    judged on this file and its neighbours (daemon.datasets.dataset.ensure_dataset)."""
    from daemon.datasets.subject_masks import remember_masks, subject_masks_for

    ctx = job.ctx
    job.mask_dir = subject_masks_for(ctx, job.dataset, job.subject_masks)
    if job.dry_run:
        return job.wanted_spec or ctx.store.dataset_spec(job.dataset) or ctx.config.spec_for(job.dataset)
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
    from daemon.datasets.subject_masks import sibling_images

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
    from poisoner.provenance import read_seal

    assert job.file is not None and job.sha is not None
    ctx = job.ctx
    seal = read_seal(fd_path(job.file.fd), ctx.seal_key())
    if seal is None:
        return None
    if job.out_path is None and not job.dry_run and ctx.vault.has(seal.original_sha256):
        ensure_dataset(ctx, job.dataset, job.root, job.wanted_spec)
        ctx.store.record_file(
            job.path, job.dataset, FileState.PATCHED, original_sha256=seal.original_sha256,
            poisoned_sha256=job.sha, spec_id=seal.spec_id, tool_version=None,
            size=job.file.st.st_size, mtime_ns=job.file.st.st_mtime_ns, error=None,
            event="recognised", detail={"from": "provenance seal"},
        )  # fmt: skip
    return job.outcome(
        Outcome.UNCHANGED, "already ppd output (its provenance seal says so)", poisoned_sha256=job.sha
    )


def keep_in_vault(job: Job) -> ProtectOutcome | None:
    """1. An independent copy of the original (read through its descriptor) goes to the vault."""
    assert job.file is not None and job.sha is not None
    try:
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
    from daemon.protect.quarantine import attempt

    assert job.spec is not None
    job.died_before = job.held.enter_context(attempt(job.ctx.paths.data_dir, job.path, job.dataset))
    job.ctx.store.record_file(
        job.record_path, job.dataset, FileState.PENDING, original_sha256=job.sha, spec_id=job.spec.spec_id,
        poisoned_sha256=None, error=None, tool_version=tool_version(), event="pending",
        detail={"kind": job.kind},
    )  # fmt: skip
    return None


def poison(job: Job) -> ProtectOutcome | None:
    """3. The complete patched file, written in the private work folder."""
    assert job.work is not None and job.original is not None and job.spec is not None and job.kind
    job.poisoned = job.work / work_copy_name(PATCHED_PREFIX, job.path.name)
    marker = provenance_marker(job.ctx, job.spec.spec_id, job.sha)
    limits = {"max_pixels": job.ctx.config.max_pixels} if job.kind == "image" else {}
    if job.died_before:  # the last attempt took its process down: this one cannot
        job.report = poison_isolated(
            job.kind, job.original, job.poisoned, job.spec, marker, job.keep_location, job.mask_dir, **limits
        )
    else:
        job.report = poison_to(
            job.kind, job.original, job.poisoned, job.spec, job.progress, job.mask_dir, marker=marker,
            keep_location=job.keep_location, **limits,
        )  # fmt: skip
    seal_output(job.ctx, job.poisoned)
    job.poisoned_sha = sha256_file(job.poisoned)
    return None


def replace_atomically(job: Job) -> ProtectOutcome | None:
    """4. The patched file replaces the original at its name, through the folder's descriptor, only
    if the name still holds the version that was hashed (else SourceChanged: the newer version
    stays). With --out, the copy is written into the output folder instead."""
    assert job.file is not None and job.poisoned is not None
    if job.out_path is not None:
        _write_out(job, job.poisoned)
        return None
    f = job.file
    clear_stale_temps_once(f.dir_fd)

    def still_the_hashed_version() -> None:
        # The slow hash first, the identity of the name last: nothing but the rename follows it.
        if f.changed() or f.sha256() != job.sha:
            raise SourceChanged(f"{job.path.name} was written to while being patched; left as it is now")
        if not f.folder_in_place():
            raise SourceChanged(f"{job.path.name}: its folder was moved or replaced; nothing written")
        if f.current_identity() != identity(f.st):
            raise SourceChanged(f"{job.path.name} was replaced while being patched; the new version stays")

    with atomic_replace_at(
        f.dir_fd, f.name, mode=stat.S_IMODE(f.st.st_mode), check=still_the_hashed_version
    ) as (
        fd,
        _tmp,
    ):
        copy_path_to_fd(job.poisoned, fd)
        st = os.fstat(fd)
    job.written = (st.st_ino, st.st_size, st.st_mtime_ns)
    job.final = job.path
    return None


def record_provenance(job: Job) -> ProtectOutcome | None:
    """5. The patched row: what the original was, which spec, what ppd wrote."""
    assert job.spec is not None
    record_path = job.record_path
    st = os.stat(record_path, follow_symlinks=False) if job.out_path is not None else None
    size, mtime = (st.st_size, st.st_mtime_ns) if st else (job.written[1], job.written[2])  # type: ignore[index]
    job.ctx.store.record_file(
        record_path, job.dataset, FileState.PATCHED, original_sha256=job.sha,
        poisoned_sha256=job.poisoned_sha, spec_id=job.spec.spec_id, tool_version=tool_version(),
        size=size, mtime_ns=mtime, error=None, published_path=None, event="patched",
        detail=report_detail(job.report),
    )  # fmt: skip
    job.final = record_path
    return None


def publish(job: Job) -> ProtectOutcome | None:
    """6. A dataset with a publish folder gets its patched file moved there."""
    target_dir = publish_dir(job.ctx, job.dataset) if job.out_path is None else None
    if target_dir is None:
        return None
    assert job.file is not None
    rel = job.path.relative_to(job.root) if job.path.is_relative_to(job.root) else Path(job.path.name)
    job.final = move_out(job.file.dir_fd, job.file.name, target_dir / rel)
    job.ctx.store.record_file(
        job.record_path, job.dataset, FileState.PATCHED, published_path=str(job.final), event="published",
        detail={"to": str(job.final)},
    )  # fmt: skip
    return None


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
def _write_out(job: Job, content: Path) -> None:
    """`--out`: the copy goes into the output folder the user named (trusted, created if needed)."""
    out = job.record_path
    out.parent.mkdir(parents=True, exist_ok=True)
    dir_fd = open_dir(out.parent)
    try:
        clear_stale_temps_once(dir_fd)
        mode = stat.S_IMODE(job.file.st.st_mode) if job.file is not None else None
        with atomic_replace_at(dir_fd, out.name, mode=mode) as (fd, _tmp):
            copy_path_to_fd(content, fd)
    finally:
        os.close(dir_fd)
