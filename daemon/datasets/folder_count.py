"""A dataset's files as its folder holds them, next to its store rows.

The store has a row only for files ppd has reached: after a run stopped half-way (Ctrl-C, a
SIGTERM, a crash) the folder still holds originals that no row mentions. `ppd status` counts them
from the folder, so it never says "8 files, 6 patched" of a folder of 23 photos.

A folder may hold another dataset's files (`owned_elsewhere`): a dataset whose folder is nested in
this one, the outbox's datasets, a file another dataset's row names. They are never this dataset's
"not patched yet": `ppd poison FOLDER` would find them patched already, or finish the wrong dataset.

Light at import (`ppd status` loads it): no numpy, no PIL.
"""

from __future__ import annotations

import hashlib
import os
import shlex
import stat
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.datasets.linked_folders import LinkedFolder, linked_folders_under
from daemon.datasets.moved import moved_to
from daemon.datasets.sealed_files import Sealed, split_sealed
from daemon.states import PATCHED_VALUES, WAITING_PREFIX, FileState, patched_count, storable
from poisoner.atomic import TEMP_PREFIX, is_temp_name, remove_stale_temp
from poisoner.media import IMAGE, UNPROTECTED, VIDEO, media_class, unpatched_name

if TYPE_CHECKING:
    from daemon.context import AppContext

# A row in one of these states stands for a file that still needs `ppd poison`: it was never
# finished (pending: the run stopped between the vault and the provenance row).
UNFINISHED_STATES = frozenset({FileState.PENDING.value})


@dataclass(frozen=True)
class FolderCount:
    """What the dataset's folder holds beside the rows."""

    folder: Path
    exists: bool
    on_disk: int = 0  # media files in the folder now (hidden files, temporaries, mask folders left out)
    untracked: list[Path] = field(default_factory=list)  # media files that no row mentions
    copies: Path | None = None  # `ppd poison --out`: the folder the patched copies went to
    changed: list[Path] = field(default_factory=list)  # patched in place, another size or time now
    gone: list[Path] = field(default_factory=list)  # patched (in place or --out copy), no longer there
    # photos and videos ppd cannot protect (poisoner.media.media_class: BMP, GIF, raw files),
    # which a reconstruction reads all the same (a black-box review: status and --check ignored them)
    unprotectable: list[Path] = field(default_factory=list)
    # the folder gone (or left empty): a folder that holds its patched files as ppd wrote them (moved_to)
    moved_to: Path | None = None
    # (old path, new path): a file patched in place, renamed since (in neither untracked nor gone)
    renamed: list[tuple[Path, Path]] = field(default_factory=list)
    # patched in place, now holding their original's bytes: a `ppd restore` killed after its rename,
    # before its row (a black-box review: status called them "changed since patched")
    restored_unrecorded: list[Path] = field(default_factory=list)
    # ppd's own `.ppd-tmp-*` files in the folder; after dataset_folder's sweep, the stale ones it could
    # not remove (a killed run's hidden copy, published with the folder by a sync)
    temps: list[Path] = field(default_factory=list)
    # the stale ones dataset_folder's sweep removed: said, never removed in silence
    temps_removed: list[Path] = field(default_factory=list)
    # photos and videos under names ppd does not patch (hidden, backups, partial downloads), which a
    # sync publishes all the same (daemon.datasets.unpatched_names)
    unpatched_names: list[Path] = field(default_factory=list)
    # media files whose names are not UTF-8: no row can name them (ppd refuses them: rename them), never
    # "not patched yet" with a `ppd poison` that fails on them the same way every time (F7)
    not_utf8: list[Path] = field(default_factory=list)
    # symlinked folders in it, never followed: their photos, unmarked, ship with a publisher that follows
    # links (daemon.datasets.linked_folders)
    linked: list[LinkedFolder] = field(default_factory=list)
    # files no row names that are ppd's output, their seal verified (daemon.datasets.sealed_files): not
    # among untracked (a run leaves them unchanged), counted in "files"
    sealed: Sealed = field(default_factory=Sealed)

    def to_dict(self) -> dict[str, Any]:
        copies = None if self.copies is None else str(self.copies)
        moved = None if self.moved_to is None else str(self.moved_to)
        return {"folder": str(self.folder), "exists": self.exists, "on_disk": self.on_disk,
                "untracked": len(self.untracked), "copies": copies, "changed": len(self.changed),
                "unprotectable": len(self.unprotectable), "gone": len(self.gone),
                "moved_to": moved, "renamed": len(self.renamed),
                "restored_unrecorded": len(self.restored_unrecorded),
                "leftover_temps": len(self.temps), "unpatched_names": len(self.unpatched_names),
                "not_utf8": len(self.not_utf8)}  # fmt: skip


def folder_media(folder: Path, skip: Iterable[Path] = ()) -> list[Path]:
    """Media files under folder, sorted: no hidden files or folders, no ppd temporaries, nothing
    under a skipped folder (subject masks are never patched), no symlinks."""
    return _walk(folder, skip)[0]


Walked = tuple[list[Path], list[Path], list[Path]]


def _walk(folder: Path, skip: Iterable[Path] = ()) -> Walked:
    """(folder_media's files, the photos and videos of formats ppd cannot protect, ppd's temporaries),
    sorted, one walk."""
    skipped = [Path(s).absolute() for s in skip]
    found: list[Path] = []
    unprotectable: list[Path] = []
    temps: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(folder):
        here = Path(dirpath)
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".") and here / d not in skipped)
        for name in filenames:
            path = here / name
            if is_temp_name(name):  # ppd's form only (a user's `.ppd-tmp-notes.txt` is not ppd's)
                temps.append(path)
            if unpatched_name(name) is not None or path.is_symlink():  # the daemon's rule (unpatched_names)
                continue
            kind = media_class(path)  # by suffix, else by its first bytes (a .jfif, a file with no suffix)
            if kind in (IMAGE, VIDEO):
                found.append(path)
            elif kind == UNPROTECTED:
                unprotectable.append(path)
    return sorted(found), sorted(unprotectable), sorted(temps)


Parts = tuple[str, ...]


def _match_copies(outside: list[Path], rels: set[Parts]) -> tuple[set[Parts], Path | None]:
    """The folder files that `--out` copies stand for (OUT/DATASET/a/b.jpg: a/b.jpg, the longest
    tail of the copy's path that names a file of the folder), and the copies' folder (OUT/DATASET;
    without a match, the deepest folder holding every copy)."""
    covered: set[Parts] = set()
    roots: list[str] = []
    for path in outside:
        parts = path.parts
        tail = next((parts[-k:] for k in range(len(parts) - 1, 0, -1) if parts[-k:] in rels), None)
        if tail is not None:
            covered.add(tail)
            roots.append(str(Path(*parts[: -len(tail)])))
    if not roots:
        roots = [str(p.parent) for p in outside]
    return covered, (Path(os.path.commonpath(roots)) if roots else None)


def owned_elsewhere(
    folder: Path, roots: Iterable[Path], paths: Iterable[str], outbox: Path | None = None
) -> tuple[list[Path], set[str]]:
    """What of folder belongs to other datasets: the folders to skip and the files to leave out.

    roots: the other datasets' folders; those strictly inside folder are skipped (one with the same
    folder shares it: its files are told apart by paths). paths: the files other datasets' rows name.
    outbox: by the outbox's rule (daemon.datasets.dataset) its first-level subfolders are datasets
    of their own, registered or not, so the outbox's loose-file dataset skips them, and a folder
    holding the outbox skips it."""
    folder = Path(folder).absolute()
    others = {Path(root).absolute() for root in roots}
    skip = sorted(r for r in others if r != folder and r.is_relative_to(folder))
    if outbox is not None:
        box = Path(outbox).absolute()
        if box == folder and folder.is_dir():
            skip += sorted(d for d in folder.iterdir() if d.is_dir() and d not in skip)
        elif box != folder and box.is_relative_to(folder) and box not in skip:
            skip.append(box)
    return skip, {str(p) for p in paths}


def count_folder(
    folder: Path, rows: Iterable[Mapping[str, Any]], skip: Iterable[Path] = (), foreign: Iterable[str] = (),
    original_stat: OriginalStat | None = None, places: Iterable[Path] = (),
) -> FolderCount:  # fmt: skip
    """The folder's media files and those of them no row mentions: by path, or for `--out` copies
    by their path below the copies' folder (OUT/DATASET/a/b.jpg stands for FOLDER/a/b.jpg).
    skip: folders whose files are not the dataset's; foreign: files (str paths) that are another
    dataset's (owned_elsewhere): neither is counted. original_stat: the vault's copy of an original
    (None: not kept), to tell a changed file holding its original again (_holds_original). places: where
    a gone folder is looked for first (moved_to)."""
    folder = Path(folder).absolute()
    rows = list(rows)
    paths = [Path(row["path"]) for row in rows]
    # removed rows left out: a file moved away (its old path) is no `--out` copy (a review: "patched
    # copies in" the old folder, after `ppd dataset set --root` moved a dataset the daemon carried)
    outside = [Path(r["path"]) for r in rows if r["state"] != FileState.REMOVED]
    outside = [p for p in outside if not p.is_relative_to(folder)]
    theirs = set(foreign)
    files, unprotectable, temps = _walk(folder, skip) if folder.is_dir() else ([], [], [])
    files = [f for f in files if str(f) not in theirs]
    rels = {f.relative_to(folder).parts for f in files}
    copies = _match_copies(outside, rels)[1]
    if not folder.is_dir():  # deleted or renamed: its files patched in place went with it
        gone = _gone_in_place(rows, folder, theirs)
        moved = moved_to(folder, rows, places)
        copies = None if copies == moved else copies  # its own files, carried there: no `--out` copies
        return FolderCount(folder, exists=False, copies=copies, gone=gone, moved_to=moved)
    # an `--out` copy deleted or moved away: its photo has no protected copy now (a run makes one
    # again), so the photo counts "not patched yet" and the copy's row "gone" (a black-box review)
    copies_gone = [
        Path(r["path"]) for r in rows
        if r["state"] in PATCHED_VALUES and not Path(r["path"]).is_relative_to(folder)
        and not os.path.lexists(r["path"])
    ]  # fmt: skip
    covered = _match_copies([p for p in outside if p not in set(copies_gone)], rels)[0]
    inside = {str(p) for p in paths}
    untracked = [f for f in files if str(f) not in inside and f.relative_to(folder).parts not in covered]
    present = {str(f) for f in files}
    changed_rows = [r for r in rows if r["path"] in present and changed_since_patched(r)]
    restored = [Path(r["path"]) for r in changed_rows if _holds_original(r, original_stat)]
    changed = [Path(r["path"]) for r in changed_rows if Path(r["path"]) not in restored]
    # a file patched in place that is no longer there is no file of the dataset's (a black-box review:
    # deleted, it still counted patched); the daemon records it removed, a one-shot user has no daemon
    in_place = _gone_in_place(rows, folder, theirs | present)
    renamed = _renamed(rows, in_place, untracked)
    olds, news = {old for old, _ in renamed}, {new for _, new in renamed}
    untracked = [f for f in untracked if f not in news]
    not_utf8 = [f for f in untracked if not storable(f)]
    untracked = [f for f in untracked if f not in not_utf8]
    gone = [p for p in in_place if p not in olds] + copies_gone
    # none of its files left, seen where the outbox's rule puts it now: the outbox moved, the folder left
    # behind empty (a running `ppd watch` makes the outbox it watched again)
    moved = moved_to(folder, rows, places, beside=False) if not files else None
    return FolderCount(folder, exists=True, on_disk=len(files), untracked=untracked, copies=copies,
                       changed=changed, unprotectable=unprotectable, gone=gone, renamed=renamed,
                       restored_unrecorded=restored, temps=temps, not_utf8=not_utf8,
                       moved_to=moved)  # fmt: skip


def _renamed(
    rows: Iterable[Mapping[str, Any]], gone: list[Path], untracked: list[Path]
) -> list[tuple[Path, Path]]:
    """Files patched in place and gone from their paths, matched to the folder's files no row names
    by the size and time ppd wrote (a rename keeps both; what status judges changed files on): the
    same file renamed, ppd's output, never "not patched yet" (a black-box review). A stat for each
    file no row names, only when a patched one is gone."""
    if not gone or not untracked:
        return []
    wanted = {str(p) for p in gone}
    wrote: dict[tuple[int, int], list[Path]] = {}
    for r in rows:
        if r["path"] in wanted and r.get("size") is not None and r.get("mtime_ns") is not None:
            wrote.setdefault((r["size"], r["mtime_ns"]), []).append(Path(r["path"]))
    pairs = []
    for f in untracked:
        try:
            st = os.stat(f, follow_symlinks=False)
        except OSError:
            continue
        olds = wrote.get((st.st_size, st.st_mtime_ns))
        if olds:  # one old row for one new file
            pairs.append((olds.pop(0), f))
    return pairs


def _gone_in_place(rows: Iterable[Mapping[str, Any]], folder: Path, left_out: set[str]) -> list[Path]:
    """The files patched in place under folder that are no longer there (left_out: paths that are
    another dataset's or present)."""
    return [
        Path(r["path"]) for r in rows
        if r["state"] in PATCHED_VALUES and not r.get("published_path")
        and Path(r["path"]).is_relative_to(folder) and str(r["path"]) not in left_out
        and not os.path.lexists(r["path"])
    ]  # fmt: skip


def changed_since_patched(row: Mapping[str, Any]) -> bool:
    """Whether a file patched in place now has another size or modification time than ppd wrote: an
    original copied back over it, an edit. What the daemon's catch-up scan looks at (a black-box
    review: with no daemon running, `ppd status` counted such files patched)."""
    if row["state"] not in PATCHED_VALUES or row.get("published_path") or row.get("size") is None:
        return False
    try:
        st = os.stat(row["path"], follow_symlinks=False)
    except OSError:
        return False
    return (st.st_size, st.st_mtime_ns) != (row["size"], row.get("mtime_ns"))


OriginalStat = Callable[[str], os.stat_result | None]  # the vault's copy of an original, by its sha256


def _holds_original(row: Mapping[str, Any], original_stat: OriginalStat | None) -> bool:
    """Whether a changed file (changed_since_patched) holds exactly its original's bytes: put back by
    a restore stopped before recording it, or copied back by the user. Hashed only when its size is the
    vault copy's and its time the one a restore gives it (the row's original time, else the vault
    copy's): an edited or touched file, a video above all, is never read whole at each `ppd status` (a
    diff review: a rebuilt store, whose rows know no original time, read every changed file)."""
    original, original_mtime = row.get("original_sha256"), row.get("original_mtime_ns")
    kept = original_stat(original) if original and original_stat is not None else None
    if kept is None:  # no original kept: nothing could have put one back
        return False
    try:  # not blocking on a FIFO given a photo's name
        fd = os.open(row["path"], os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return False
    with open(fd, "rb") as fh:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size != kept.st_size:
            return False
        if st.st_mtime_ns != (kept.st_mtime_ns if original_mtime is None else original_mtime):
            return False
        return hashlib.file_digest(fh, "sha256").hexdigest() == original


def with_folder(counts: Mapping[str, int], folder: FolderCount) -> dict[str, int]:
    """Store.counts() with the folder's files that have no row as "untracked", counted in "files"."""
    merged = dict(counts)
    merged["untracked"] = len(folder.untracked)
    # a removed file (deleted, moved away) is no longer one of the dataset's: its row is history
    removed = int(counts.get(FileState.REMOVED.value, 0))
    merged["files"] = int(counts.get("files", 0)) - removed + len(folder.untracked)
    if folder.not_utf8:  # files of the dataset, not patched, named apart from "untracked"
        merged["not_utf8"] = len(folder.not_utf8)
        merged["files"] += len(folder.not_utf8)
    if folder.unprotectable and folder.copies is None:  # --out: they are not where the copies are
        merged["unprotectable"] = len(folder.unprotectable)
    if folder.unpatched_names and folder.copies is None:
        merged["unpatched_names"] = len(folder.unpatched_names)
    _count_outside(merged, folder)
    if folder.renamed:  # still patched and in the folder: counted by their old rows, under "patched"
        merged["renamed"] = len(folder.renamed)
    if folder.gone:  # deleted or moved away since patched: neither a file of the dataset nor patched
        merged["gone"] = len(folder.gone)
        merged["files"] -= len(folder.gone)
        merged[FileState.PATCHED.value] = int(merged.get(FileState.PATCHED.value, 0)) - len(folder.gone)
    for key, paths in (("changed", folder.changed), ("restored_unrecorded", folder.restored_unrecorded)):
        if paths:  # no longer ppd's output: not counted patched
            merged[key] = len(paths)
            merged[FileState.PATCHED.value] = int(merged.get(FileState.PATCHED.value, 0)) - len(paths)
    return merged


def not_patched_yet(counts: Mapping[str, int]) -> int:
    """Files a run has still to do: those without a row and those it left unfinished."""
    return int(counts.get("untracked", 0)) + sum(int(counts.get(s, 0)) for s in UNFINISHED_STATES)


def resume_command(name: str, count: FolderCount) -> str:
    """The `ppd poison` that finishes the dataset: its folder, its name when that is not the
    folder's, and `--out` when its copies went elsewhere (never in place by mistake)."""
    words = ["ppd", "poison", str(count.folder)]
    if name != count.folder.name:
        words += ["--dataset", name]
    if count.copies is not None:
        out = count.copies.parent if count.copies.name == name else count.copies
        words += ["--out", str(out)]
    return shlex.join(words)


def resume_line(counts: Mapping[str, int], command: str, masks_missing: str | None = None) -> str | None:
    """`patched 6 of 23; 17 not patched yet: run `ppd poison FOLDER``, or None when none is left.
    masks_missing: the dataset's subject-mask folder, not there now: the run would stop (exit 3), so
    what they wait for instead (a seventh black-box review, F1: status sent the user to that run)."""
    left = not_patched_yet(counts)
    if not left:
        return None
    done = f"patched {patched_count(counts)} of {counts.get('files', 0)}"
    if masks_missing:
        return (f"{done}; {left} not patched yet, NOT protected: they wait for its subject masks, and "
                f"{masks_missing} is not there (see the warning)")  # fmt: skip
    return f"{done}; {left} not patched yet: run `{command}`"


def mask_folders(ctx: AppContext, name: str) -> list[Path]:
    """The dataset's subject-mask folders (its config's, the one its corner was chosen with):
    masks are never patched, so they are not files of the dataset."""
    from daemon.datasets.subject_masks import latest_choice, masks_or_none

    folders = [masks_or_none(ctx, name)]
    used = (latest_choice(ctx, name) or {}).get("subject_masks")
    folders.append(Path(used) if used else None)
    return [f for f in folders if f is not None]


def dataset_folder(ctx: AppContext, name: str, root: str) -> FolderCount:
    """The dataset's folder next to its rows, without the files that are other datasets' (a dataset
    nested in its folder, the outbox's, another's row)."""
    folder = Path(root)
    roots = [Path(d["root"]) for d in ctx.store.datasets() if d["name"] != name]
    theirs = [r["path"] for r in ctx.store.files_under(folder, not_of=name)]
    skip, foreign = owned_elsewhere(folder, roots, theirs, outbox=ctx.paths.outbox)
    masks = mask_folders(ctx, name)
    count = count_folder(
        folder, ctx.store.files(name), skip=[*masks, *skip], foreign=foreign,
        original_stat=lambda sha: _vault_stat(ctx.paths.vault_dir, sha),
        places=outbox_places(ctx, name, folder),
    )  # fmt: skip
    if count.exists and count.copies is None:  # with --out, the copies' folder is the one published
        count = replace(count, unpatched_names=_unpatched(folder, [*masks, *skip], foreign))
        # its symlinked folders, but those into the outbox (their files are counted there)
        count = replace(count, linked=linked_folders_under(folder, [*masks, *skip], own=[ctx.paths.outbox]))
    if count.untracked:  # ppd's output among them: a run leaves it unchanged, so not "not patched yet"
        rest, sealed = split_sealed(count.untracked, ctx.paths.data_dir, ctx.paths.vault_dir)
        count = replace(count, untracked=rest, sealed=sealed)
    # `--out` copies: their folder is the one published, where a killed run's partial copy would be
    temps = count.temps + (_walk(count.copies, [])[2] if count.copies and count.copies.is_dir() else [])
    if not temps:
        return count
    left, removed = sweep_temps(temps)
    return replace(count, temps=left, temps_removed=removed)


def outbox_places(ctx: AppContext, name: str, folder: Path) -> list[Path]:
    """Where the outbox's rule puts a dataset of this name, or a folder of this name, now: a gone
    folder's place after the whole outbox moved (PPD_OUTBOX set anew; a review, F2)."""
    from daemon.datasets.dataset import dataset_root

    outbox = Path(ctx.paths.outbox).absolute()
    return list(dict.fromkeys([dataset_root(outbox, name), outbox / folder.name]))


def _unpatched(folder: Path, skip: list[Path], foreign: set[str]) -> list[Path]:
    """The folder's photos under names ppd does not patch, but another dataset's files."""
    from daemon.datasets.unpatched_names import unpatched_media

    return [p for p in unpatched_media(folder, skip) if str(p) not in foreign]


def _count_outside(merged: dict[str, int], folder: FolderCount) -> None:
    """with_folder's counts of the photos behind symlinked folders ("linked", not among "files": ppd never
    reaches them) and of ppd's output no row names ("sealed", among "files", not "patched": no row)."""
    if photos := sum(link.photos for link in folder.linked):
        merged["linked"] = photos
    if folder.sealed:
        merged["sealed"] = len(folder.sealed)
        merged["files"] += len(folder.sealed)


def _vault_stat(vault_dir: Path, sha256: str) -> os.stat_result | None:
    """The vault's copy of the original with this digest, or None (not kept, or no digest)."""
    from daemon.store.vault import VaultError, blob_path

    try:
        return os.stat(blob_path(vault_dir, sha256), follow_symlinks=False)
    except (OSError, VaultError):
        return None


def sweep_temps(temps: Iterable[Path]) -> tuple[list[Path], list[Path]]:
    """Remove ppd's stale temporaries (poisoner.atomic.remove_if_stale: of ppd's form, no living writer
    holds them): (the stale ones that stay, as the folder cannot be written now; those removed), both
    named by `ppd status`. A run killed mid-file left a hidden copy where the folder is published, until
    the next poison or restore there (a black-box review)."""
    left: list[Path] = []
    removed: list[Path] = []
    for path in temps:
        try:
            if remove_stale_temp(path):
                removed.append(path)
            elif _unreadable(path):
                left.append(path)  # not ours to judge (another user's, left by a `sudo ppd`): named
        except FileNotFoundError:
            pass  # removed meanwhile (its writer renamed it, or another sweep)
        except OSError:
            left.append(path)
    return left, removed


def _unreadable(path: Path) -> bool:
    """A temporary this process cannot open: the sweep neither removes nor judges it (a diff review: it
    was left unnamed, and --check passed a folder holding it)."""
    try:
        os.close(os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC))
    except PermissionError:
        return True
    except OSError:
        return False
    return False


def current_counts(ctx: AppContext, name: str, folder: FolderCount) -> dict[str, int]:
    """The dataset's counts as its folder is now: the store's rows, the folder's files no row mentions
    ("untracked"), files changed since ppd patched them, files the daemon waits for ("waiting", not
    "skipped"). What `ppd status` and `ppd report` both judge protection on."""
    counts = with_folder(ctx.store.counts(name), folder)
    if counts.get(FileState.QUARANTINED.value):
        # a quarantined file the user has since deleted (or taken) from the quarantine folder and not
        # put back: dealt with, so no longer one of the dataset's (a black-box review: `--check` then
        # failed on it for ever)
        cleared = sum(_cleared(ctx, r) for r in ctx.store.files(name, state=FileState.QUARANTINED))
        counts[FileState.QUARANTINED.value] -= cleared
        counts["files"] = int(counts.get("files", 0)) - cleared
    skipped = ctx.store.files(name, state=FileState.SKIPPED)
    waiting = sum(str(r.get("error") or "").startswith(WAITING_PREFIX) for r in skipped)
    if waiting:  # skipped for now, not by the spec's ratio
        counts["waiting"] = waiting
        counts["skipped"] = counts.get("skipped", 0) - waiting
    if not_moved := len(ctx.store.not_moved(name)):  # a part of "patched": still in the outbox
        counts["not_moved"] = not_moved
    return counts


def outbox_unclaimed(outbox: Path, roots: Iterable[str | Path]) -> list[Path]:
    """Photos and videos in the outbox that no dataset holds yet: its first-level folders that are no
    dataset's, and its loose files when there is no "default" dataset. The daemon patches them as it
    sees them; with it stopped (or not watching) they sit there unprotected, and `ppd status`, which
    listed the store's datasets only, never said so: `--check && publish` passed (a black-box review).
    roots: the datasets' folders (their files, and folders nested in the outbox's, are theirs)."""
    box = Path(os.path.realpath(outbox))  # one spelling for both sides (a symlinked outbox: a review)
    if not box.is_dir():
        return []
    known = {Path(os.path.realpath(root)) for root in roots}
    found: list[Path] = []
    for entry in sorted(box.iterdir()):
        if entry.name.startswith((".", TEMP_PREFIX)) or entry.is_symlink():
            continue
        if entry.is_dir():
            if entry not in known:
                files, unprotectable, _temps = _walk(entry, [k for k in known if k.is_relative_to(entry)])
                found += files + unprotectable
        elif box not in known and unpatched_name(entry.name) is None and media_class(entry) is not None:
            found.append(entry)
    return found


def _cleared(ctx: AppContext, row: Mapping[str, Any]) -> bool:
    """A quarantined file that is neither where it was quarantined to nor back at its own path."""
    moved = ctx.store.last_event(row["path"], "quarantined")
    to = ((moved or {}).get("detail") or {}).get("to")
    return to is not None and not os.path.lexists(to) and not os.path.lexists(row["path"])


# How `ppd status --check`, `ppd verify` and `ppd report` name the files of a dataset that are not protected.
UNPROTECTED_WORDS = {
    "failed": "failed", "quarantined": "quarantined", "waiting": "still being written",
    "changed": "changed since patched", "untracked": "not patched yet", "pending": "not finished",
    "unprotectable": "in a format ppd cannot protect",
    "restored_unrecorded": "holding the original again", "not_utf8": "named in bytes that are not UTF-8",
    "unpatched_names": "under names ppd does not patch",
    "linked": "in symlinked folders ppd does not follow",
}  # fmt: skip


def unprotected_phrases(counts: Mapping[str, int], restored_here: int = 0) -> list[str]:
    """`2 failed`, `5 restored by you`, ...: a dataset's files (current_counts) that carry no mark (or
    no longer the one ppd wrote), one phrase per kind; restored_here: restored_in_place's count."""
    said = [f"{counts[k]} {w}" for k, w in UNPROTECTED_WORDS.items() if counts.get(k, 0) > 0]
    if restored_here:
        said.append(f"{restored_here} restored by you")
    return said


def restored_in_place(ctx: AppContext, name: str, root: str) -> int:
    """Files the user restored where they were patched in place: their originals are back where they
    are published. A restored `--out` or publish-folder copy was removed, which leaves nothing
    unprotected behind."""
    return len(_restored_here(ctx, name, root))


def _restored_here(ctx: AppContext, name: str, root: str) -> list[dict[str, Any]]:
    rows = ctx.store.files(name, state=FileState.RESTORED)
    return [r for r in rows if not r.get("published_path") and Path(r["path"]).is_relative_to(root)]


def unmarked_names(ctx: AppContext, name: str, root: str) -> list[str]:
    """The files of a dataset its rows say carry no mark, relative to its folder, x2 before x10:
    failed, quarantined (not yet dealt with: _cleared), restored where they were patched. The other
    unprotected_phrases are the folder's (new files, changed ones): counted, not named."""
    from daemon.store.datasets import natural_key

    rows = ctx.store.files(name, state=FileState.FAILED) + [
        r for r in ctx.store.files(name, state=FileState.QUARANTINED) if not _cleared(ctx, r)
    ]
    paths = sorted((r["path"] for r in rows + _restored_here(ctx, name, root)), key=natural_key)
    return [os.path.relpath(p, root) if Path(p).is_relative_to(root) else p for p in paths]


def unmarked_why(phrases: list[str], names: list[str], shown: int = 3) -> str:
    """`1 failed, unmarked: a.tif`: unprotected_phrases, then the first few files they name."""
    if not names:
        return ", ".join(phrases)
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return f"{', '.join(phrases)}, unmarked: {', '.join(names[:shown])}{more}"
