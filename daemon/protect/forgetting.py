"""`ppd dataset forget NAME`: a finished or deleted shoot leaves ppd, its records and its originals.

Rows first, then originals: the store forgets the dataset in one transaction (Store.forget_dataset),
noting the originals its rows named; then each of them that no remaining row names (any dataset, any
state: two datasets can share an original, the vault is content-addressed) leaves the vault, and the
note goes. A crash between the two leaves only originals no row names (what `ppd store rebuild`
counts as unreferenced), never a row whose original is gone; the next forget finishes the vault step
from the note. The caller holds the store alone (daemon.locks.store_alone) and no `ppd watch` runs:
no command can record a row for an original between the check and its removal.

The files ppd set aside for the dataset (`ppd restore --force`: DATA/displaced/NAME) are the user's and
stay; its verification run folders (DATA/runs/NAME: reconstructions of its photos) are ppd's and go.
"""

from __future__ import annotations

import os
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

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


def still_patched(ctx: AppContext, name: str) -> list[Path]:
    """The dataset's files that carry ppd's mark now, wherever they are (in place, an `--out` copy, a
    published one): their originals in the vault are the only way back. A 'pending' row's file counts
    when it no longer holds its original (a run killed after its rename, before its row)."""
    marked = []
    for row in ctx.store.files(name):
        place = Path(row.get("published_path") or row["path"])
        if not os.path.lexists(place):
            continue
        if row["state"] == FileState.PATCHED or (row["state"] == FileState.PENDING and _replaced(row)):
            marked.append(place)
    return marked


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
    no row names any more from the vault (this dataset's, and those of an earlier forget a crash stopped
    before its vault step)."""
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
            raise ForgetUnfinished(
                f"dataset {forgotten!r}'s records are forgotten, but its originals could not all leave the "
                f"vault ({exc.strerror or exc}: {exc.filename or ctx.paths.vault_dir}); "
                f"`ppd dataset forget {shlex.quote(forgotten)}` again finishes it"
            ) from None
        ctx.store.forget_done(forgotten)
    _remove_runs(ctx, name)
    folder = displaced_folder(ctx, name)
    aside = folder if folder.is_dir() and any(folder.iterdir()) else None
    return Forgotten(rows, removed, removed_bytes, kept, aside)


def _remove_runs(ctx: AppContext, name: str) -> None:
    """The dataset's verification run folders: ppd's own reconstructions of its photos (a later dataset
    of the same name must not find them). Only a real folder right inside runs_dir."""
    if name in ("", ".", "..") or os.sep in name:  # never a folder above or beside it
        return
    runs = Path(ctx.paths.runs_dir) / name
    if runs.is_dir() and not runs.is_symlink():
        shutil.rmtree(runs, ignore_errors=True)
