"""One file's run as data: the Job the stages carry, the outcome they end with, and the small
helpers every stage and daemon.protect.one_file share (names as the store and a line can hold them)."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.fsops import ContainedFile, identity
from daemon.states import storable as storable  # re-exported: its callers import it from here
from poisoner.atomic import TEMP_PREFIX
from poisoner.errors import ExitStatus, PpdError
from poisoner.media import IMAGE, VIDEO, media_class
from poisoner.spec import PatchSpec

if TYPE_CHECKING:
    from daemon.context import AppContext


Progress = Callable[[int, int | None], None]
FileSignature = tuple[int, int, int]  # (inode, size, mtime_ns), as daemon.watch.watcher compares them


class IncompleteFile(PpdError):
    """The file's structure is incomplete (a truncated upload, a writer that gave up)."""

    exit_status = ExitStatus.FAILED


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


def still_the_version(f: ContainedFile, sha: str, name: str) -> Callable[[], None]:
    """The compare-and-swap before a patched file is renamed over f's name (atomic_replace_at's
    check): raises SourceChanged unless the name still holds the opened file, unwritten, of sha."""

    def check() -> None:
        # The slow hash first, the identity of the name last: nothing but the rename follows it.
        if f.changed() or f.sha256() != sha:
            raise SourceChanged(f"{name} was written to while being patched; left as it is now")
        if not f.folder_in_place():
            raise SourceChanged(f"{name}: its folder was moved or replaced; nothing written")
        if f.current_identity() != identity(f.st):
            raise SourceChanged(f"{name} was replaced while being patched; the new version stays")

    return check


NO_SPACE_WORDS = "no space left on the disk of"  # daemon.watch.outcomes.is_no_space reads them


class NoSpaceLeft(PpdError):
    """A write ran out of space (ENOSPC, EDQUOT); the message names the disk by a folder on it."""

    exit_status = ExitStatus.ENVIRONMENT

    def __init__(self, folders: list[Path], errno_: int) -> None:
        quota = " (over your quota)" if errno_ == errno.EDQUOT else ""
        super().__init__(f"{NO_SPACE_WORDS} {' or of '.join(map(str, folders))}{quota}")
        self.errno = errno_


@contextlib.contextmanager
def no_space_in(folder: Path) -> Iterator[None]:
    """ENOSPC or EDQUOT raised in the block, where it wrote into folder, as NoSpaceLeft: a black-box
    review read "[Errno 28] No space left on device" on every file, which disk unsaid."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        raise NoSpaceLeft([folder], exc.errno) from None


def name_the_disk(exc: BaseException, folders: list[Path]) -> BaseException:
    """exc, or for an ENOSPC or EDQUOT no write site named (no_space_in), a NoSpaceLeft naming the disks
    it can be on: the folder of the file it names, else folders (the file's, ppd's data folder), one per
    filesystem."""
    if not isinstance(exc, OSError) or exc.errno not in (errno.ENOSPC, errno.EDQUOT):
        return exc
    if exc.filename and os.path.isabs(os.fsdecode(exc.filename)):
        return NoSpaceLeft([Path(os.fsdecode(exc.filename)).parent], exc.errno)
    disks: dict[int, Path] = {}
    for folder in folders:
        with contextlib.suppress(OSError):
            disks.setdefault(os.stat(folder).st_dev, folder)
    return NoSpaceLeft(list(disks.values()) or folders, exc.errno)


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
    # restore --force: (the user's file it replaced or removed, where that was kept), each of them: a
    # published file can have two, an edited publish copy and another photo at its source path
    displaced: tuple[tuple[Path, Path], ...] = ()
    seconds: float = 0.0
    dry_run: bool = False
    report: Any = None  # poisoner.formats.PoisonReport (poisoner.video.VideoReport is one)
    # What ppd judged or wrote at path (the watcher's echo filter): a later version differs.
    signature: FileSignature | None = None
    requeue: bool = False  # a newer version arrived meanwhile: process the path again
    hopeless: bool = False  # failed because of the file itself (format, structure, name): a retry fails too
    incomplete: bool = False  # failed because its structure is incomplete: its writer may not be done
    # failed because the dataset's subject-mask folder is not there (a drive unplugged): retried once
    # this folder is back (daemon.datasets.subject_masks.MaskFolderMissing)
    waits_for: Path | None = None
    # not started: the caller stopped while another ppd process worked on the file (daemon.locks.WaitLeft);
    # a batch counts it with the files it never reached
    left: bool = False


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
    shown_size: tuple[int, int] | None = None  # an image's (width, height) as shown, from its header
    sha: str | None = None
    data: bytes | None = None  # the original's bytes as hashed (small images), until poison
    row: dict[str, Any] | None = None
    spec: PatchSpec | None = None
    work: Path | None = None  # private folder inside the vault
    original: Path | None = None  # private copy of the original, named like the file
    poisoned: Path | None = None
    poisoned_sha: str | None = None
    poisoned_data: bytes | bytearray | None = None  # the sealed output's bytes as hashed (small images)
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


def tool_version() -> str:
    from daemon.version import ppd_version

    return f"ppd {ppd_version()}"


def anchor_for(ctx: AppContext, path: Path, root: Path) -> Path:
    """The trusted folder containment is judged from: the outbox for its files (a dataset folder
    inside it may itself be swapped for a symlink), else the dataset's root."""
    outbox = Path(ctx.paths.outbox).absolute()
    return outbox if path.is_relative_to(outbox) and root.absolute().is_relative_to(outbox) else root


def one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def shown_name(path: Path) -> str:
    """path's name as it can be shown on one line: escaped (repr-style) when it holds a newline,
    another control character or bytes that are not UTF-8."""
    name = path.name
    if not storable(Path(name)):  # bytes that are not UTF-8 as \xe9, as `ls -b` shows them (not \udce9)
        shown = os.fsencode(name).decode("utf-8", "backslashreplace")
        return "".join(c if c.isprintable() else repr(c)[1:-1] for c in shown)
    return name if name.isprintable() else repr(name)[1:-1]


def shown_path(path: Path) -> str:
    """path on one line: its name escaped as shown_name escapes it (a name with a newline split the
    line that named it: a black-box review)."""
    name = shown_name(path)
    return str(path) if name == path.name else str(path.parent / name)


def media_kind(path: Path, head: Callable[[], bytes] | None = None) -> str | None:
    """'image', 'video' or None (not a file ppd patches): by suffix, else by its first bytes
    (poisoner.media.media_class; head: read through the file's open descriptor)."""
    kind = media_class(path, head)
    return kind if kind in (IMAGE, VIDEO) else None


def is_ignored_name(path: Path) -> bool:
    """Dot-files and our own temporaries are never protected."""
    return path.name.startswith(".") or path.name.startswith(TEMP_PREFIX)


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
                           "free": place.free, "orientation": place.orientation,
                           "note": place.short()}  # fmt: skip  # ppd status counts it (mark_notes)
    return detail


def publish_dir(ctx: AppContext, dataset: str) -> Path | None:
    row = ctx.store.dataset(dataset)
    return Path(row["publish_dir"]) if row and row["publish_dir"] else None
