"""`ppd dataset forget NAME`: a finished or deleted shoot leaves ppd, its records and its originals.

Rows first, then originals: the store forgets the dataset in one transaction (Store.forget_dataset),
noting the originals its rows named; then each of them that no remaining row names (any dataset, any
state: two datasets can share an original, the vault is content-addressed) leaves the vault, and the
note goes. A crash between the two leaves only originals no row names (what `ppd store rebuild`
counts as unreferenced), never a row whose original is gone; the next forget finishes the vault step
from the note. The caller holds the store alone (daemon.locks.store_alone) and no `ppd watch` runs:
no command can record a row for an original between the check and its removal.

The files ppd set aside for the dataset (`ppd restore --force`: DATA/displaced/NAME) are the user's and
stay; its verification run folders (DATA/runs/NAME: reconstructions of its photos) and `ppd experiment`'s
default folder (DATA/experiments/NAME: its originals staged as links to the vault's blobs, their
reconstructions; a black-box review found them kept after "originals removed from the vault"), its
report page (DATA/reports/NAME) and its cached previews (each shows an original beside the patched
photo; a privacy review) are ppd's and go before the note does (the previews, a cache, best effort),
so that a crash or a failed removal leaves the note, and the next forget removes them.
"""

from __future__ import annotations

import os
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from daemon.protect.displaced import displaced_folder
from daemon.states import FileState
from daemon.store.vault import VaultError, sha256_file

if TYPE_CHECKING:
    from daemon.context import AppContext


@dataclass(frozen=True)
class Forgotten:
    """What forgetting a dataset removed, and what it left."""

    rows: int  # file rows removed from the store
    removed: int  # originals removed from the vault
    removed_bytes: int
    kept: int  # the dataset's originals another dataset's rows still name: left in the vault
    displaced: Path | None  # the files ppd set aside for it, left where they are (None: none)


class Patched(NamedTuple):
    """The dataset's files its rows call patched, by whether they are where they were patched."""

    there: list[Path]  # carry ppd's mark now where the rows say: their originals are the only way back
    gone: list[Path]  # not found where they were patched (moved or deleted by the user)


def patched_files(ctx: AppContext, name: str) -> Patched:
    """The dataset's files that carry ppd's mark now (in place, an `--out` copy, a published one), and
    its patched files not found where they were patched. A 'pending' row's file counts as there when it
    no longer holds its original (a run killed after its rename, before its row). The gone ones matter
    as much: a patched photo moved to an album has no row of its new place, and `ppd restore FILE` on it
    needs its original (a diff review: forget deleted it silently). A gone 'pending' row is not counted:
    whether its file was ever replaced cannot be told without the file."""
    there, gone = [], []
    for row in ctx.store.files(name):
        place = Path(row.get("published_path") or row["path"])
        if not os.path.lexists(place):
            if row["state"] == FileState.PATCHED:
                gone.append(place)
        elif row["state"] == FileState.PATCHED or (row["state"] == FileState.PENDING and _replaced(row)):
            there.append(place)
    return Patched(there, gone)


def removed_as_copies(ctx: AppContext, name: str) -> str | None:
    """Why forgetting the dataset would lose photos (one line), or None: the originals of its photos that
    a `ppd restore` removed as `--out` copies, putting no original back, where ppd has no record of
    writing them as copies and they lay in its folder, or its folder was gone: its own photos. A ppd
    before this one did that to a moved outbox's photos (an eighth black-box review, F1), and forget then
    removed their only originals from the vault."""
    from daemon.protect.restoring import written_as_copy

    stored = ctx.store.dataset(name)
    root = Path(stored["root"]) if stored and stored["root"] else None
    found = []
    for row in ctx.store.files(name, state=FileState.RESTORED):
        sha, path = row["original_sha256"], row["path"]
        if row.get("published_path") or not sha or os.path.lexists(path) or not ctx.vault.has(sha):
            continue
        said = (ctx.store.last_event(path, "restored") or {}).get("detail") or {}
        ours = root is None or not root.is_dir() or Path(path).is_relative_to(root)
        if "to" in said and said["to"] is None and ours and not written_as_copy(ctx, path):
            found.append(ctx.vault.path_for(sha))
    if not found:
        return None
    named = f"{found[0]}{', ...' if len(found) > 1 else ''}"
    return (f"dataset {name!r}: {len(found)} of its photos were removed by `ppd restore` as --out copies, "
            f"no original put back: their originals are only in the vault ({named}): copy them out first, or "
            "--force to forget it all the same (they then leave the vault)")  # fmt: skip


def _replaced(row: dict[str, object]) -> bool:
    """Whether a pending row's file is no longer its original (unreadable: it may be ppd's output)."""
    try:
        return sha256_file(Path(str(row["path"]))) != row["original_sha256"]
    except OSError:
        return True


class ForgetUnfinished(VaultError):
    """The store forgot the dataset; its originals could not all leave the vault (one line, exit 3)."""


def unfinished(ctx: AppContext, name: str) -> bool:
    """Whether a forget of this dataset stopped after its rows, before its vault step was done."""
    return ctx.store.dataset(name) is None and name in ctx.store.forget_notes()


def forget_dataset(ctx: AppContext, name: str) -> Forgotten:
    """Remove the dataset from the store (unless an earlier forget did: unfinished), then the originals
    no row names any more from the vault and its verification run folders (this dataset's, and those of
    an earlier forget a crash stopped before its note went)."""
    previews = _preview_folders(ctx, name)  # found by the rows' folders: before the rows go
    rows = 0 if unfinished(ctx, name) else ctx.store.forget_dataset(name)
    removed = removed_bytes = kept = 0
    for forgotten, originals in sorted(ctx.store.forget_notes().items()):
        named = ctx.store.named_originals(originals)
        if forgotten == name:
            kept = len(named)
        try:
            for sha in originals:
                if sha not in named and (freed := ctx.vault.discard(sha)) is not None:
                    removed, removed_bytes = removed + 1, removed_bytes + freed
        except OSError as exc:  # the note stays: a run again finishes it
            why = "its originals could not all leave the vault"
            raise _unfinished(forgotten, why, exc, ctx.paths.vault_dir) from None
        # before the note goes (a review: after it, a crash or a failed removal left them for good)
        if ctx.store.dataset(forgotten) is None:  # not a new dataset of that name: its runs would be its
            try:
                _remove_runs(ctx, forgotten)
            except OSError as exc:
                why = "its verification runs or experiment folder could not all be removed"
                raise _unfinished(forgotten, why, exc, ctx.paths.runs_dir) from None
        ctx.store.forget_done(forgotten)
    for preview in previews:  # cached pictures of its originals beside ppd's output (a privacy review)
        shutil.rmtree(preview, ignore_errors=True)
    folder = displaced_folder(ctx, name)
    aside = folder if folder.is_dir() and any(folder.iterdir()) else None
    return Forgotten(rows, removed, removed_bytes, kept, aside)


def _unfinished(name: str, what: str, exc: OSError, place: Path) -> ForgetUnfinished:
    """The one line of a forget stopped after its rows (exit 3): its note stays, a run again finishes."""
    where = exc.filename or place
    return ForgetUnfinished(
        f"the records of dataset {name!r} are forgotten, but {what} ({exc.strerror or exc}: {where}); "
        f"`ppd dataset forget {shlex.quote(name)}` again finishes it"
    )


def _remove_runs(ctx: AppContext, name: str) -> None:
    """The dataset's verification run folders and its default experiment folder: ppd's own
    reconstructions of its photos and copies of its originals (a later dataset of the same name must
    not find them). Only a real folder right inside runs_dir or the experiments folder. OSError: one
    could not be removed (the caller keeps the note, so that a forget again tries it again)."""
    if name in ("", ".", "..") or os.sep in name:  # never a folder above or beside it
        return
    # its report page too: it shows one of its originals beside the patched photo (a privacy review)
    reports = Path(ctx.paths.data_dir) / "reports" / name
    for folder in (Path(ctx.paths.runs_dir) / name, ctx.paths.experiment_dir(name), reports):
        if folder.is_dir() and not folder.is_symlink():
            shutil.rmtree(folder, onerror=_whole_name)


def _preview_folders(ctx: AppContext, name: str) -> list[Path]:
    """The cached `ppd preview` folders of the dataset's photo folders (each picture shows a clean
    original; daemon.paths.preview_folder), those that are there."""
    from daemon.paths import preview_folder

    folders = {Path(r["path"]).parent for r in ctx.store.files(name)}
    if root := (ctx.store.dataset(name) or {}).get("root"):
        folders.add(Path(root))
    cached = [preview_folder(ctx.paths.cache_dir, folder) for folder in folders]
    return [c for c in cached if c.is_dir() and not c.is_symlink()]


def _whole_name(_func: object, path: str, exc_info: tuple[type, BaseException, object]) -> None:
    """rmtree's error with the whole path it failed on (its own names only the entry: 'report.json')."""
    exc = exc_info[1]
    if isinstance(exc, OSError):
        raise OSError(exc.errno, exc.strerror, path) from None
    raise exc
