"""What `ppd restore DATASET|FOLDER` restores, and what it leaves.

- the dataset's rows whose file is there (or whose copy is in an --out or publish folder);
- the files in its folder (or in the folder given, when the store has no dataset of it) that carry
  ppd's marker and have no row: after a lost store, a renamed file, a dataset folder moved (a
  black-box review: "not a folder ppd patched", or "restored 0 ... failed 0" with exit 0, while the
  files there were still patched). restore_file finds each by its seal, as it does for one file;
- not the files gone from their path since they were patched: deleted or moved by the user, they are
  listed, not made again (`ppd restore FILE` brings one back);
- not the files a running `ppd watch` has still to patch (held_by_watch): counted, said, exit 3.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.states import FileState

if TYPE_CHECKING:
    from daemon.context import AppContext
    from daemon.protect.job import ProtectOutcome


@dataclass(frozen=True)
class FolderRestore:
    dataset: str | None  # None: a folder the store has no dataset of
    paths: list[Path]  # the dataset's rows restored by their path
    gone: list[dict[str, Any]]  # rows patched in place whose file is gone from its path
    scan: Path | None  # the folder searched for files with ppd's marker and no row
    home: tuple[str, Path] | None  # where a file found there is recorded (None: the outbox's own rule)
    root_gone: Path | None  # the dataset's folder, when it is gone


def plan_folder_restore(ctx: AppContext, target: str, console: Any) -> FolderRestore:
    """The plan for X, a dataset's name or a folder (TargetError: neither, one line)."""
    from daemon.cli.targets import TargetError, resolve_target, same_folder, say_note
    from daemon.datasets.dataset import DatasetConflict, DatasetNameError, attribute

    chosen = resolve_target(ctx.store, target)
    say_note(chosen, console)
    if chosen.dataset is not None:
        return _dataset_plan(ctx, chosen.dataset)
    assert chosen.folder is not None
    try:
        home = None if same_folder(chosen.folder, ctx.paths.outbox) else attribute(ctx, chosen.folder)
    except (DatasetConflict, DatasetNameError) as exc:
        raise TargetError(str(exc)) from None
    if home is not None and _moved_here(ctx, home, console):
        return _dataset_plan(ctx, home[0])
    return FolderRestore(None, [], [], chosen.folder, home, None)


def _moved_here(ctx: AppContext, home: tuple[str, Path], console: Any) -> bool:
    """Whether the folder is a stored dataset's of the same name that the user moved (`mv a/shoot
    b/shoot`): its recorded folder gone, the dataset moves here (root and rows) and is restored as itself.
    Before, its files were recorded in the old dataset outside its root: `ppd poison` then refused the
    folder and status did not count them (a diff review). TargetError when that folder is still there:
    another folder of the same name, which ppd poison refuses the same way."""
    from daemon.cli.targets import TargetError

    name, folder = home
    stored = ctx.store.dataset(name)
    if stored is None or Path(stored["root"]).absolute() == folder.absolute():
        return False
    old = Path(stored["root"])
    if os.path.lexists(old):
        raise TargetError(
            f"dataset {name!r} already belongs to {old}; name this one with --dataset NAME "
            f"(`ppd poison {folder} --dataset NAME`, then `ppd restore NAME`)"
        )
    moved = ctx.store.move_dataset(name, old, folder.absolute())  # None: another ppd moved it (here) first
    console.print(f"dataset {name!r}: its folder {old} is gone; {folder} is its folder now "
                  f"({moved or 0} files' records moved with it)", markup=False)  # fmt: skip
    return True


def _dataset_plan(ctx: AppContext, dataset: str) -> FolderRestore:
    """A stored dataset's plan: its rows, its folder scanned."""
    from daemon.protect.restoring import gone_from_its_place

    # pending: a run killed after replacing a file, before recording it (restore_file reads its seal)
    rows = [*ctx.store.files(dataset, state=FileState.PATCHED)]
    rows += ctx.store.files(dataset, state=FileState.PENDING)
    gone = [r for r in rows if gone_from_its_place(ctx, r)]
    paths = sorted({Path(r["path"]) for r in rows if r not in gone})
    stored = ctx.store.dataset(dataset)
    if stored is None or not stored["root"]:
        return FolderRestore(dataset, paths, gone, None, None, None)
    root = Path(stored["root"])
    if not root.is_dir():
        if _followed(ctx, dataset, root):  # its folder moved (the outbox did): restored where it is now
            return _dataset_plan(ctx, dataset)
        return FolderRestore(dataset, paths, gone, None, None, root)
    return FolderRestore(dataset, paths, gone, root, (dataset, root), None)


def _followed(ctx: AppContext, dataset: str, root: Path) -> bool:
    """Whether the dataset whose folder root is gone moved to where the outbox's rule puts it now, as
    the daemon or `ppd poison` there would follow it (daemon.datasets.moved: the outbox moved): restore
    said "folder gone", or took its photos for `--out` copies (a review, F1). A folder renamed is the
    user's to name (`ppd restore NEWFOLDER`, `ppd dataset set NAME --root NEWFOLDER`)."""
    from daemon.datasets.folder_count import outbox_places
    from daemon.datasets.moved import adopt_moved, moved_to

    places = outbox_places(ctx, dataset, root)
    seen = moved_to(root, ctx.store.files(dataset), places, beside=False)
    return seen is not None and adopt_moved(ctx, dataset, seen)


def marked_files(ctx: AppContext, plan: FolderRestore) -> list[Path]:
    """The files under plan.scan that carry something shaped like ppd's marker (any key) and have no row
    in the store: restore_file says what each is. Others are not read past the marker search, unless
    rows are gone from their path: then one holding such a row's original is taken too (a restore by
    seal killed after its rename left it there unrecorded; restore_file records it).

    Only the files of the dataset restored: not those in another dataset's folder below it (the innermost
    folder's dataset owns a file, as `ppd poison` attributes it), and of a dataset whose folder is the home
    folder, the files right in it (a diff review: `ppd restore` of one such dataset restored other datasets'
    renamed files and copies anywhere in the home tree)."""
    from daemon.cli.planning import media_files
    from daemon.datasets.dataset import innermost_holder
    from daemon.store.vault import sha256_file
    from poisoner.provenance import has_token

    folder = plan.scan
    if folder is None:
        return []
    skip = set(plan.paths)
    originals = {r["original_sha256"] for r in plan.gone if r["original_sha256"]}
    own = plan.home[0] if plan.home is not None else None  # None: the outbox, each file its own dataset's
    datasets = ctx.store.datasets() if own is not None else []
    at_home = Path(folder).absolute() == Path.home().absolute()
    published = _publish_folder(ctx, own)
    return [
        f for f in media_files(folder, recursive=not at_home)
        if f not in skip and not f.is_symlink() and _unrecorded_or_refused(ctx, f)
        and (published is None or not f.absolute().is_relative_to(published))
        and (own is None or innermost_holder(datasets, f, prefer=own) in (own, None))
        and (has_token(f) or (originals and sha256_file(f) in originals))
    ]  # fmt: skip


def _publish_folder(ctx: AppContext, dataset: str | None) -> Path | None:
    """The dataset's publish folder: its files are published copies, never restored in place (one
    stored inside the dataset's folder before `dataset set` refused it: `ppd restore` wrote the
    originals into it; a diff review, F3)."""
    row = ctx.store.dataset(dataset) if dataset is not None else None
    return Path(row["publish_dir"]).absolute() if row and row["publish_dir"] else None


def _unrecorded_or_refused(ctx: AppContext, path: Path) -> bool:
    """A file with no row, or one `ppd poison` refused (failed: ppd's output sealed with another key,
    say): restore_file says what it is. A folder of such files restored "restored 0 ... failed 0", exit
    0, after a run with a mistyped PPD_DATA_DIR had sealed them with that folder's new key (a black-box
    review)."""
    row = ctx.store.file(path)
    return row is None or row["state"] == FileState.FAILED


def still_gone(ctx: AppContext, gone: list[dict[str, Any]]) -> list[Path]:
    """The gone rows that are still patched once the files found by their seal were restored (a
    renamed file's old row is then marked moved away: it was restored under its new name)."""
    left = []
    for row in gone:
        now = ctx.store.file(row["path"])
        if now is not None and now["state"] in (FileState.PATCHED, FileState.PENDING):
            left.append(Path(row["path"]))
    return sorted(left)


def held_by_watch(
    ctx: AppContext, plan: FolderRestore, outcomes: list[ProtectOutcome]
) -> tuple[list[Path], str] | None:
    """The dataset's files a running `ppd watch` has still to finish once the restore is done, and who
    watches ("pid N"); None when no daemon watches the outbox the folder is in, or it holds none of them.
    Those are the folder's photos no row names (queued, or in its first stages) and its patched or
    pending rows in place that the restore did not reach or restore (patched meanwhile). A black-box
    review (F13): a restore while the daemon patched a drop said "restored 12", exit 0, and the daemon
    then marked the rest; the file a restore meets mid-patch is waited for (restore_file), these are said."""
    from daemon.datasets.folder_count import dataset_folder
    from daemon.locks import watching
    from daemon.protect.restoring import gone_from_its_place

    outbox = Path(ctx.paths.outbox).absolute()
    if plan.dataset is None or plan.scan is None or not Path(plan.scan).absolute().is_relative_to(outbox):
        return None
    holders = watching(ctx.paths.data_dir)
    if not holders:
        return None
    # restored, or failed with its reason; skipped: another ppd held the file past the wait, counted here
    reported = {o.path for o in outcomes if o.state not in ("unchanged", "skipped")}
    rows = [*ctx.store.files(plan.dataset, state=FileState.PATCHED)]
    rows += ctx.store.files(plan.dataset, state=FileState.PENDING)
    left = {Path(r["path"]) for r in rows if not gone_from_its_place(ctx, r)} - reported
    untracked = set(dataset_folder(ctx, plan.dataset, str(plan.scan)).untracked)
    left |= untracked - {o.path for o in outcomes}
    return (sorted(left), holders[0]) if left else None
