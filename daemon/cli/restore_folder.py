"""What `ppd restore DATASET|FOLDER` restores, and what it leaves.

- the dataset's rows whose file is there (or whose copy is in an --out or publish folder);
- the files in its folder (or in the folder given, when the store has no dataset of it) that carry
  ppd's marker and have no row: after a lost store, a renamed file, a dataset folder moved (a
  black-box review: "not a folder ppd patched", or "restored 0 ... failed 0" with exit 0, while the
  files there were still patched). restore_file finds each by its seal, as it does for one file;
- not the files gone from their path since they were patched: deleted or moved by the user, they are
  listed, not made again (`ppd restore FILE` brings one back).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.states import FileState

if TYPE_CHECKING:
    from daemon.context import AppContext


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
    from daemon.protect.restoring import gone_from_its_place

    chosen = resolve_target(ctx.store, target)
    say_note(chosen, console)
    if chosen.dataset is None:
        assert chosen.folder is not None
        try:
            home = None if same_folder(chosen.folder, ctx.paths.outbox) else attribute(ctx, chosen.folder)
        except (DatasetConflict, DatasetNameError) as exc:
            raise TargetError(str(exc)) from None
        return FolderRestore(None, [], [], chosen.folder, home, None)
    # pending: a run killed after replacing a file, before recording it (restore_file reads its seal)
    rows = [*ctx.store.files(chosen.dataset, state=FileState.PATCHED)]
    rows += ctx.store.files(chosen.dataset, state=FileState.PENDING)
    gone = [r for r in rows if gone_from_its_place(ctx, r)]
    paths = sorted({Path(r["path"]) for r in rows if r not in gone})
    stored = ctx.store.dataset(chosen.dataset)
    if stored is None or not stored["root"]:
        return FolderRestore(chosen.dataset, paths, gone, None, None, None)
    root = Path(stored["root"])
    if not root.is_dir():
        return FolderRestore(chosen.dataset, paths, gone, None, None, root)
    return FolderRestore(chosen.dataset, paths, gone, root, (chosen.dataset, root), None)


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
    return [
        f for f in media_files(folder, recursive=not at_home)
        if f not in skip and not f.is_symlink() and ctx.store.file(f) is None
        and (own is None or innermost_holder(datasets, f, prefer=own) in (own, None))
        and (has_token(f) or (originals and sha256_file(f) in originals))
    ]  # fmt: skip


def still_gone(ctx: AppContext, gone: list[dict[str, Any]]) -> list[Path]:
    """The gone rows that are still patched once the files found by their seal were restored (a
    renamed file's old row is then marked moved away: it was restored under its new name)."""
    left = []
    for row in gone:
        now = ctx.store.file(row["path"])
        if now is not None and now["state"] in (FileState.PATCHED, FileState.PENDING):
            left.append(Path(row["path"]))
    return sorted(left)
