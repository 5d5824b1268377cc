"""A dataset whose folder the user moved: seen (moved_to: `ppd status`, `ppd dataset forget`) and
followed (adopt_moved: `ppd watch`, `ppd poison`, a moved file recognised by its hash).

A folder renamed beside itself, or the whole outbox moved to another disk (PPD_OUTBOX set anew, then
`ppd service install` again, as the README says): its patched files are at the same relative paths in
the new folder, with the size and time ppd wrote (`mv`, `cp -a` and `rsync -a` keep both). An eighth
black-box review (F1): `ppd watch` on the moved outbox recorded each file as moved, under its dataset
whose stored folder still named the old outbox; `ppd restore` then took them for `--out` copies and
deleted them, and `ppd dataset forget` the only originals. F2: `ppd status` called them "NOT
protected", and its advice, `ppd poison OUTBOX`, exited 2. Now the dataset follows its folder, by the
store's one move (Store.move_dataset, as `ppd dataset set NAME --root` does), said once.

Never while the stored folder still holds the dataset's files (the new one is a copy, or another
outbox's folder of the same name), nor onto a folder another dataset has.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.states import PATCHED_VALUES, FileState

if TYPE_CHECKING:
    from daemon.context import AppContext

log = logging.getLogger(__name__)

# moved_to looks at this many folders beside a gone one, and this many of its files in each: a stat
# apiece, never a walk (status runs on stores of 10k files in well under a second)
MOVE_PROBE_FOLDERS = 500
MOVE_PROBE_FILES = 3


def moved_to(
    folder: Path, rows: Iterable[Mapping[str, Any]], places: Iterable[Path] = (), beside: bool = True
) -> Path | None:
    """A folder that holds a gone one's patched files at the same relative paths with the size and
    time ppd wrote (a `mv` keeps both): places first (where the outbox's rule puts the dataset now: the
    outbox moved), then, with beside, the folders beside it (the folder renamed). None when none is
    seen: deleted, or moved further (a black-box review: a moved folder was said to "hold no file now")."""
    probes = _move_probes(folder, rows)
    if not probes:
        return None
    for candidate in places:
        if _holds(candidate, probes):
            return Path(candidate)
    if not beside:
        return None
    try:
        with os.scandir(folder.parent) as entries:
            near = [Path(e.path) for e in entries if not e.name.startswith(".") and _is_folder(e)]
    except OSError:  # its parent gone or unreadable too: nothing to say
        return None
    return next((c for c in sorted(near)[:MOVE_PROBE_FOLDERS] if _holds(c, probes)), None)


Probe = tuple[Path, tuple[int, int | None]]


def _move_probes(folder: Path, rows: Iterable[Mapping[str, Any]]) -> list[Probe]:
    """A few of folder's files patched in place: (path relative to it, (size, time) ppd wrote)."""
    return _written(folder, rows)[:MOVE_PROBE_FILES]


def _written(folder: Path, rows: Iterable[Mapping[str, Any]]) -> list[Probe]:
    """Folder's files patched in place, as ppd wrote them: (path relative to it, (size, time)). A row
    recorded removed counts when it was patched (its output's hash kept): a running `ppd watch` records
    a folder's files removed when the folder (or the whole outbox) is moved away."""
    return [
        (Path(r["path"]).relative_to(folder), (r["size"], r.get("mtime_ns"))) for r in rows
        if (r["state"] in PATCHED_VALUES or (r["state"] == FileState.REMOVED and r.get("poisoned_sha256")))
        and not r.get("published_path") and r.get("size") is not None
        and Path(r["path"]).is_relative_to(folder)
    ]  # fmt: skip


def patched_there(
    folder: Path, there: Path, rows: Iterable[Mapping[str, Any]], files: Iterable[Path]
) -> set[Path]:
    """Of files (in there, a gone folder's moved place), those that are its patched files at the same
    relative paths, as ppd wrote them (a stat each)."""
    wrote = dict(_written(folder, rows))
    return {f for f in files if (w := wrote.get(Path(f).relative_to(there))) is not None and _same_file(f, w)}


def _holds(candidate: Path, probes: list[Probe]) -> bool:
    return any(_same_file(Path(candidate) / rel, wrote) for rel, wrote in probes)


def _is_folder(entry: os.DirEntry[str]) -> bool:
    try:
        return entry.is_dir(follow_symlinks=False)
    except OSError:
        return False


def _same_file(path: Path, wrote: tuple[int, int | None]) -> bool:
    try:
        st = os.stat(path, follow_symlinks=False)
    except OSError:
        return False
    return (st.st_size, st.st_mtime_ns) == wrote


def moved_here(ctx: AppContext, name: str, root: Path, proof: tuple[Path, Path] | None = None) -> Path | None:
    """Dataset name's stored folder when root is that folder, moved: the stored one gone (or left without
    its files), root a folder no other dataset has, holding the dataset's patched files at the same
    relative paths as ppd wrote them. proof: (a file in root, the path of the row whose output it is by
    its hash): the same relative path proves it, whatever its time (`cp -r` gives a new one). None: not
    a move."""
    row = ctx.store.dataset(name)
    if row is None or not row["root"]:
        return None
    old, root = Path(row["root"]), Path(root).absolute()
    if old.absolute() == root or not root.is_dir() or _anothers(ctx, name, root):
        return None
    rows = ctx.store.files_below(name, old)
    if _still_there(old, rows):
        return None
    probes = _move_probes(old, rows)
    if proof is not None and _same_place(proof, old, root):
        return old
    return old if probes and _holds(root, probes) else None


def _still_there(old: Path, rows: list[dict[str, Any]]) -> bool:
    """Whether the stored folder is still there with any of the dataset's patched files: the new one is
    a copy (or another outbox's folder of the same name), or a part moved. Every row is looked at, not
    a few: a folder moved in two batches, or a backup copy whose first files were deleted from the
    outbox, took the whole dataset, and the files left behind were "gone" to status and restore (a diff
    review). An empty folder left behind is not (a running `ppd watch` makes its outbox again when it is
    moved away). A stat a row, once: after the move the stored folder is the new one."""
    if not os.path.lexists(old):
        return False
    written = _written(old, rows)
    if not written:
        return True  # nothing of the dataset's to tell a move by
    return any(r["state"] in PATCHED_VALUES and os.path.lexists(r["path"]) for r in rows)


def adopt_moved(ctx: AppContext, name: str, root: Path, proof: tuple[Path, Path] | None = None) -> bool:
    """Move dataset name to root when root is its folder, moved (moved_here), said once (the process
    that moves it says so); whether the dataset's folder is root now."""
    old = moved_here(ctx, name, root, proof)
    if old is None:
        return False
    root = Path(root).absolute()
    moved = ctx.store.move_dataset(name, old, root)
    if moved is None:  # another ppd process moved it first (the daemon's workers, a `ppd poison`)
        return (ctx.store.dataset(name) or {}).get("root") == str(root)
    log.warning(
        "dataset %s's folder moved: %s -> %s (%d file record(s) follow it)", name, old, root, moved,
        extra={"dataset": name},
    )  # fmt: skip
    return True


def _same_place(proof: tuple[Path, Path], old: Path, root: Path) -> bool:
    seen, was = Path(proof[0]).absolute(), Path(proof[1])
    if not (seen.is_relative_to(root) and was.is_relative_to(old)):
        return False
    return seen.relative_to(root) == was.relative_to(old)


def _anothers(ctx: AppContext, name: str, root: Path) -> bool:
    """Whether root is another dataset's folder (a folder is one dataset's)."""
    return any(
        d["name"] != name and d["root"] and Path(d["root"]).absolute() == root for d in ctx.store.datasets()
    )
