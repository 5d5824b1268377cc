"""Subject-aware placement, the application's side: where a dataset's subject masks come from, the
corner its corner mark takes (chosen once, when the dataset gets its spec), and the words for it.

The pixels are the poisoner's (poisoner.subject: `load_subject_mask`, `dataset_corner`); this module
decides which folder, which files and when:
- masks: `ppd poison/preview/verify --subject-masks DIR`, else `[datasets.NAME] subject_masks`.
  A mask folder inside the outbox is refused: its masks would be protected and published as photos.
  A configured (or remembered) folder that is not there (a drive unplugged) is that dataset's state,
  not a bad setting: its files are not patched (never without their masks) until it is back
  (MaskFolderMissing; the daemon retries them then), other datasets go on.
- corner: a corner-bound spec (`PatchSpec.corner_bound`) whose position the user did not set gets
  the dataset's corner from `dataset_corner` over its first files and its masks; the choice is
  stored as the spec's position (the spec is locked per dataset, so every later file gets the
  same corner) and recorded as a `corner_chosen` event (what `ppd report` shows).

Light at import (`ppd poison --help`): numpy and PIL load inside the functions that need them.
"""

from __future__ import annotations

import logging
import os
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from poisoner.errors import ExitStatus, PpdError

if TYPE_CHECKING:
    from daemon.context import AppContext
    from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

CORNER_EVENT = "corner_chosen"
CORNER_SAMPLE = 8  # images the corner is judged on (dataset_corner's sample)
SOURCE_WORDS = {
    "masks": "from the subject masks: the corner the subject leaves freest",
    "estimated": "estimated: least detail",
    "default": "default: no masks, no estimate",
}


class SubjectMaskError(PpdError):
    """A subject-mask folder that cannot be used (message = one line). Not a ValueError on purpose:
    a file that fails for it is not the file's fault (daemon.protect.poisoning.file_is_the_cause)."""

    exit_status = ExitStatus.USAGE


class MaskFolderMissing(SubjectMaskError):
    """A dataset's configured or remembered mask folder is not a readable folder now (an unplugged
    drive): ppd cannot work on that dataset here (exit 3), and the daemon retries its files once
    `folder` is back."""

    exit_status = ExitStatus.ENVIRONMENT

    def __init__(self, message: str, folder: Path) -> None:
        super().__init__(message)
        self.folder = folder


@dataclass(frozen=True)
class Placed:
    """The spec a dataset gets, and the corner choice behind it (None: no choice was made)."""

    spec: PatchSpec
    choice: Any = None  # poisoner.subject.CornerChoice


def check_mask_folder(folder: Path, outbox: Path, what: str = "--subject-masks") -> Path:
    """folder, absolute, when it is a readable folder outside the outbox; else SubjectMaskError."""
    folder = Path(folder).expanduser().absolute()
    if not readable_folder(folder):
        raise SubjectMaskError(f"{what}: {folder} is not a readable folder")
    box = Path(outbox).absolute()
    if folder == box or folder.is_relative_to(box) or folder.resolve().is_relative_to(box.resolve()):
        raise SubjectMaskError(
            f"{what}: {folder} is inside the outbox {box}: its masks would be protected and published "
            "as photos; keep subject masks outside the outbox"
        )
    return folder


def subject_masks_for(ctx: AppContext, dataset: str, given: Path | None = None) -> Path | None:
    """The dataset's mask folder: given (a command's --subject-masks), else the config's, else the one
    remembered with the dataset (issue 25: `remember_masks`, so `ppd poison --force` after a restore
    and the daemon keep the mark off the subject without the flag); checked."""
    if given is not None:
        return check_mask_folder(given, ctx.paths.outbox)
    configured = ctx.config.subject_masks_for(dataset)
    if configured is not None:
        return _dataset_folder(configured, ctx.paths.outbox, dataset, config_key(dataset))
    stored = ctx.store.dataset_masks(dataset)
    if stored is None:
        return None
    return _dataset_folder(stored, ctx.paths.outbox, dataset, remembered_key(dataset))


def config_key(dataset: str) -> str:
    """What a dataset's mask folder set in config.toml is called in ppd's lines."""
    return f"[datasets.{dataset}] subject_masks"


def remembered_key(dataset: str) -> str:
    """What the mask folder remembered with a dataset (`remember_masks`) is called in ppd's lines."""
    return f"{dataset}'s remembered subject masks"


def _dataset_folder(folder: Path, outbox: Path, dataset: str, what: str) -> Path:
    """check_mask_folder for a dataset's own folder: one that is not there is MaskFolderMissing."""
    if not readable_folder(folder):
        raise MaskFolderMissing(missing_words(dataset, folder, what), Path(folder).expanduser().absolute())
    return check_mask_folder(folder, outbox, what)


def missing_words(dataset: str, folder: Path, what: str) -> str:
    """`[datasets.porch] subject_masks: /media/usb/m is not a readable folder (not mounted?): ...`, and
    how to point the dataset elsewhere: a user who deleted or renamed the folder had no way out but to
    make it again (a seventh black-box review, F1)."""
    if what == config_key(dataset):
        way_out = f"{what} in config.toml names another folder"
    else:
        way_out = (f"`ppd dataset set {shlex.quote(dataset)} --subject-masks DIR` points it at another "
                   "folder (`--no-subject-masks` drops them)")  # fmt: skip
    return (f"{what}: {folder} is not a readable folder (a drive not mounted?): {dataset}'s files are "
            f"not patched until it is back (never without their masks), or until {way_out}")  # fmt: skip


def readable_folder(folder: Path) -> bool:
    """A folder ppd can list and read (a mask folder on a drive that is back: daemon.watch.waiting)."""
    folder = Path(folder).expanduser()
    return folder.is_dir() and os.access(folder, os.R_OK | os.X_OK)


def remember_masks(ctx: AppContext, dataset: str, folder: Path | None) -> None:
    """Keep a dataset's mask folder with its store row (a no-op before the row exists or when no
    folder was given: a run without --subject-masks never forgets the one remembered)."""
    if folder is not None:
        ctx.store.set_dataset_masks(dataset, Path(folder).absolute())


def masks_or_none(ctx: AppContext, dataset: str) -> Path | None:
    """The config's subject masks of a dataset, or None when it has none or they cannot be used
    (where a mask folder is a nicety: redoing a run, judging a corner after a failure)."""
    try:
        return subject_masks_for(ctx, dataset)
    except SubjectMaskError:
        return None


def check_config_masks(config: Any, outbox: Path) -> list[str]:
    """What `ppd watch` checks before it starts: a [datasets.NAME] subject_masks inside the outbox is
    a SubjectMaskError (one line, the first); one that is not there now is returned, a line each
    (that dataset's files wait for it; the others' go on: one unplugged drive stopped the daemon)."""
    missing = missing_config_masks(config)
    for name, override in config.datasets.items():
        if override.subject_masks is not None and name not in missing:
            check_mask_folder(override.subject_masks, outbox, config_key(name))
    return list(missing.values())


def missing_config_masks(config: Any) -> dict[str, str]:
    """The datasets whose [datasets.NAME] subject_masks is not a readable folder now: the line saying so."""
    return {
        name: missing_words(name, override.subject_masks, config_key(name))
        for name, override in config.datasets.items()
        if override.subject_masks is not None and not readable_folder(override.subject_masks)
    }


def missing_masks(ctx: AppContext) -> dict[str, str]:
    """missing_config_masks, and each stored dataset's mask folder that is not there now: the one
    remembered with it too (`ppd status` said nothing of that one and sent the user to the `ppd poison`
    that then stopped, exit 3: a seventh black-box review, F1)."""
    missing = missing_config_masks(ctx.config)
    for row in ctx.store.datasets():
        if row["name"] not in missing and (gone := missing_mask_folder(ctx, row["name"])) is not None:
            missing[row["name"]] = str(gone)
    return missing


def missing_mask_folder(ctx: AppContext, dataset: str) -> MaskFolderMissing | None:
    """Why the dataset's own mask folder (the config's, else the remembered one) is not there now, as
    `ppd poison` would stop on it; None when it is there, or the dataset has none."""
    try:
        subject_masks_for(ctx, dataset)
    except MaskFolderMissing as exc:
        return exc
    except SubjectMaskError:  # there, but unusable (inside the outbox): `ppd poison` says why
        return None
    return None


def mask_folder_holding(config: Any, path: Path) -> str | None:
    """The config key of a subject-mask folder that holds path (its masks are never patched), or None."""
    for name, override in config.datasets.items():
        folder = override.subject_masks
        if folder is not None and Path(path).absolute().is_relative_to(Path(folder).absolute()):
            return config_key(name)
    return None


def wants_corner(spec: PatchSpec, position_set: bool) -> bool:
    """Whether the dataset's corner is ppd's to choose: a corner mark whose corner nobody set."""
    return spec.corner_bound and not position_set


def place_corner(spec: PatchSpec, files: Sequence[Path], mask_dir: Path | None) -> Placed:
    """spec with the corner `dataset_corner` picks over files (CORNER_SAMPLE of them, spread over the
    set, and their masks; unreadable files and masks are left out there). With nothing to judge on,
    the spec keeps its own position (source 'default')."""
    from poisoner.subject import CornerChoice, dataset_corner

    choice = dataset_corner(files, mask_dir, region=spec.corner_region, sample=CORNER_SAMPLE)
    if choice.source == "default":
        return Placed(spec, CornerChoice(corner=spec.position, source="default", cover={}))
    return Placed(spec.replace(position=choice.corner), choice)


def per_photo_line(
    dataset: str, mask_dir: Path | None, masked: tuple[int, int] | None = None, videos_only: bool = False
) -> str:
    """`lego: mark placed per photo, where each photo is plainest (estimated from its detail)`.
    masked: (photos with a mask in mask_dir, photos), so the line never claims masks none matched.
    videos_only: a set of clips is not told of photos (a second black-box review)."""
    if videos_only:
        return f"{dataset}: mark placed per video, where its keyframes are plainest (estimated from detail)"
    why = f"off the subject masks in {mask_dir}" if mask_dir else "estimated from its detail; no masks"
    if mask_dir and masked is not None and masked[0] < masked[1]:
        why = (f"no mask in {mask_dir} matches these photos: estimated from their detail" if masked[0] == 0
               else f"off the subject masks in {mask_dir} for {masked[0]} of {masked[1]} photos; "
               "the others estimated from their detail")  # fmt: skip
    return f"{dataset}: mark placed per photo, where each photo is plainest as shown ({why})"


def corner_line(dataset: str, choice: Any) -> str:
    """`lego: mark in the bottom-right corner (estimated: least detail)`."""
    return _corner_words(dataset, choice.corner, choice.source)


def _corner_words(dataset: str, corner: str, source: str) -> str:
    return f"{dataset}: mark in the {corner} corner ({SOURCE_WORDS.get(source, source)})"


def record_choice(ctx: AppContext, dataset: str, choice: Any, mask_dir: Path | None) -> None:
    """The choice as an event of the dataset (shown by `ppd report`), with the mask folder used."""
    cover = {k: round(float(v), 4) for k, v in dict(choice.cover or {}).items()}
    detail = {"corner": choice.corner, "source": choice.source, "cover": cover,
              "subject_masks": str(mask_dir) if mask_dir else None}  # fmt: skip
    ctx.store.add_event(dataset, None, CORNER_EVENT, detail)
    log.info("%s", corner_line(dataset, choice), extra={"dataset": dataset, **detail})


def latest_choice(ctx: AppContext, dataset: str, limit: int = 5000) -> dict[str, Any] | None:
    """The newest corner_chosen event's detail (within the last `limit` events of the dataset)."""
    for event in ctx.store.events(dataset, limit=limit):
        if event.get("kind") == CORNER_EVENT:
            detail = event.get("detail")
            return detail if isinstance(detail, dict) else None
    return None


def choice_text(dataset: str, detail: dict[str, Any] | None) -> str | None:
    """A recorded choice in the words of corner_line; None when there is none."""
    if not detail or not detail.get("corner"):
        return None
    return _corner_words(dataset, str(detail["corner"]), str(detail.get("source")))


def sibling_images(first: Path, limit: int = CORNER_SAMPLE) -> list[Path]:
    """Up to limit regular, non-hidden image files next to first (sorted, symlinks skipped): what the
    daemon judges a new dataset's corner on besides its first file."""
    from poisoner.media import is_photo

    try:
        entries = sorted(first.parent.iterdir())
    except OSError:
        return []
    found = []
    for p in entries:
        if p.name == first.name or p.name.startswith(".") or p.is_symlink() or not is_photo(p):
            continue
        if p.is_file():
            found.append(p)
        if len(found) >= limit:
            break
    return found


def load_keep_out(mask_dir: Path, src: Path, name: str | None = None) -> Any:
    """The subject mask of src (looked up by name, default src's) at src's stored pixel size, or
    None when the folder has none for it (a warning with the structured field `subject_mask`)."""
    from PIL import Image

    from poisoner.subject import load_subject_mask

    image_name = name or Path(src).name
    with Image.open(src) as im:
        size = im.size
    mask = load_subject_mask(Path(mask_dir), image_name, size)
    if mask is None:  # a warning: the user expects the subject kept clear, and this file has no mask
        log.warning(
            "%s: no subject mask in %s; patched without keep-out", image_name, mask_dir,
            extra={"subject_mask": "missing", "file": image_name, "subject_masks": str(mask_dir)},
        )  # fmt: skip
    return mask
