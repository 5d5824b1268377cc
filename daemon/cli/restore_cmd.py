"""`ppd restore DATASET|FILE`: put originals back from the vault."""

from __future__ import annotations

import os
import shlex
from collections import Counter
from collections.abc import Collection
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from daemon.cli.errors import die, open_ctx, reason_text
from daemon.cli.output import console, err_console
from poisoner.errors import ExitStatus

if TYPE_CHECKING:
    from daemon.cli.restore_folder import FolderRestore
    from daemon.context import AppContext
    from daemon.protect.job import ProtectOutcome


def restore(
    target: str = typer.Argument(
        ..., help="A dataset (its name, its folder, a verification folder of it) or a patched file."
    ),
    force: bool = typer.Option(
        False, "--force",
        help="Put the original back even if the file changed since (your version is kept aside).",
    ),
) -> None:
    """Put originals back from the vault (atomic). Files in an --out or publish folder are
    removed there, never replaced by originals. The daemon does not patch restored files again; a
    file it is patching now is waited for, those it has yet to patch are counted (exit 3).
    A folder's files that carry ppd's seal are restored too (renamed, moved, a lost store); a
    file deleted since it was patched is listed, not made again (give its path to restore it).

    \b
    Examples:
      ppd restore castle                 every patched file of the dataset
      ppd restore ~/shoots/castle        the same, by its folder
      ppd restore ~/shoots/castle/a.jpg  one file
    """
    from daemon.cli.targets import TargetError, user_path
    from daemon.protect.restoring import restore_file
    from poisoner.provenance import has_token

    ctx = open_ctx()
    held = 0  # files a running `ppd watch` has still to patch (_say_held)
    try:
        as_path = user_path(Path(target).expanduser())  # a dataset name or path, '~' as before
        if ctx.store.file(as_path) is not None or (as_path.is_file() and not as_path.is_symlink()):
            # a file: its row, or with no row (a lost store) its seal and the vault (restore_file says
            # "not in the store and carries no ppd provenance marker" for a file ppd never patched)
            if ctx.store.file(as_path) is not None or has_token(as_path):  # else nothing to restore: said so
                _refuse_unwritable(ctx, [as_path])
            outcomes = [restore_file(ctx, as_path, force=force)]
            _refuse_never_patched(ctx, as_path, outcomes[0])
            _print_outcomes(outcomes)
        else:
            try:
                outcomes, held = _restore_folder(ctx, target, force)
            except TargetError as exc:
                raise die(exc) from None
        _exit_if_failed(outcomes, held)
    finally:
        ctx.close()


# restore_file's reason for a file with no row, no ppd marker and no original of a gone row in it
NEVER_PATCHED = "is not in the store and carries no ppd provenance marker"


def _refuse_never_patched(ctx: AppContext, path: Path, outcome: ProtectOutcome) -> None:
    """A file ppd never patched is a bad target (exit 2, one line), as an unknown dataset or a missing
    path is (`ppd --help`: 2 = bad input: path, dataset name); it was counted "failed 1", exit 1, as if
    ppd had tried and failed on one of its own files (a black-box review, F11)."""
    from daemon.protect.job import shown_path

    never = outcome.state == "failed" and (outcome.reason or "").endswith(NEVER_PATCHED)
    if never and ctx.store.file(path) is None:
        raise die(f"{shown_path(path)}: not a file ppd patched (not in the store, no ppd marker); "
                  "nothing to restore")  # fmt: skip


def _exit_if_failed(outcomes: list[ProtectOutcome], held: int = 0) -> None:
    """Exit 1 when a file was not restored; 3 when one failed for lack of space, with the line `ppd
    poison` ends with: the disk, not the file, is what needs fixing (`--help`: 3 = cannot work here);
    3 as well when a running `ppd watch` held files (held: their count), or another ppd process held one
    past the wait (skipped): another ppd holds them."""
    from daemon.cli.poison_cmd import disk_full

    failed = [o for o in outcomes if restore_word(o) == "failed"]
    if failed and disk_full(failed):
        said = "ppd: a disk is full (or over its quota): free space, then run the same command again"
        err_console().print(f"{said}; what was restored stays restored", markup=False, highlight=False)
        raise typer.Exit(ExitStatus.ENVIRONMENT)
    if held or any(restore_word(o) == "skipped" for o in outcomes):
        raise typer.Exit(ExitStatus.ENVIRONMENT)
    if failed:
        raise typer.Exit(ExitStatus.FAILED)


def _restore_folder(ctx: AppContext, target: str, force: bool) -> tuple[list[ProtectOutcome], int]:
    """A dataset or a folder (daemon.cli.restore_folder): its rows' files, then the files in its folder
    that carry ppd's marker and have no row; the files gone from their path are listed, not made again.
    Also how many files a running `ppd watch` has still to patch (said: _say_held)."""
    from daemon.cli.restore_folder import held_by_watch, marked_files, plan_folder_restore, still_gone
    from daemon.cli.targets import TargetError
    from daemon.protect.restoring import restore_file

    plan = plan_folder_restore(ctx, target, console())
    marked = marked_files(ctx, plan)
    _refuse_unwritable(ctx, [*plan.paths, *marked])
    outcomes = [restore_file(ctx, p, force=force) for p in plan.paths]
    if plan.dataset is None and not marked:
        raise TargetError(f"{plan.scan} is not a folder ppd patched; nothing to restore there")
    if plan.dataset is None:
        console().print(f"{plan.scan}: no dataset of this folder in the store; restoring the {len(marked)} "
                        "files in it that carry ppd's marker", markup=False)  # fmt: skip
    outcomes += [restore_file(ctx, p, force=force, home=plan.home) for p in marked]
    gone = still_gone(ctx, plan.gone)
    if plan.root_gone is not None and gone and not outcomes:  # one line, not an "[Errno 2]" per file
        raise TargetError(
            f"dataset {plan.dataset!r}: its folder {plan.root_gone} is gone (moved or deleted?); "
            "`ppd restore FOLDER` restores its files in the folder they are in now"
        )
    if plan.root_gone is not None and not gone and not outcomes:
        _refuse_moved_on(ctx, plan)
    held = held_by_watch(ctx, plan, outcomes)
    _print_outcomes(outcomes, counted=held[0] if held is not None else ())
    _print_gone(gone, plan.root_gone)
    if held is not None:
        _say_held(plan.dataset or target, *held)
    return outcomes, len(held[0]) if held is not None else 0


def _say_held(dataset: str, files: list[Path], holder: str) -> None:
    """One line: the files the running daemon is patching or has yet to patch are not restored, and
    what to do (exit 3, "cannot work here": another ppd holds them)."""
    said = (
        f"ppd: not restored: {len(files)} file(s) of dataset {dataset!r} that the running ppd watch "
        f"({holder}) is patching or has yet to patch; it marks them: run `ppd restore "
        f"{shlex.quote(dataset)}` again when it is idle"
    )
    err_console().print(said, markup=False, highlight=False)


def _refuse_moved_on(ctx: AppContext, plan: FolderRestore) -> None:
    """A dataset whose folder is gone and whose files another dataset holds now (a renamed folder the
    daemon or `ppd poison` took as a new dataset): where they are, in status's words, one line (exit 2).
    It said "restored 0, removed 0, unchanged 0, failed 0", exit 0, its files still patched (F11)."""
    from daemon.cli.status_gone import moved_words
    from daemon.cli.status_queries import dataset_status
    from daemon.cli.targets import TargetError

    assert plan.dataset is not None
    d = dataset_status(ctx, plan.dataset)
    there = d["folder"].get("moved_to_dataset")
    if there:
        raise TargetError(f"dataset {plan.dataset!r}: its folder {plan.root_gone} is gone; {moved_words(d)}: "
                          f"`ppd restore {shlex.quote(there)}` restores them")  # fmt: skip


def _refuse_unwritable(ctx: AppContext, paths: list[Path]) -> None:
    """Exit 3 with one line, nothing restored, when a folder the restore writes in (where an original
    goes back, where a patched copy is removed) cannot be written: as `ppd poison` refuses (a black-box
    review: exit 1 and one "not restored ... folder not writable" line per file). A folder that is gone
    is left to restore_file, which says so per file."""
    from daemon.cli.planning import not_writable

    folders = {path.parent for path in paths}
    for path in paths:
        row = ctx.store.file(path)
        if row is not None and row.get("published_path"):  # its copy leaves the publish folder
            folders.add(Path(row["published_path"]).parent)
    folder = not_writable(f for f in folders if f.is_dir())
    if folder is not None:
        raise die(f"folder not writable: {folder}; nothing restored", ExitStatus.ENVIRONMENT)


def _print_gone(gone: list[Path], root_gone: Path | None) -> None:
    """The files patched in place that are gone from their path: deleted or moved by the user, not made
    again (a black-box review: `ppd restore` brought culled photos back into a folder to be published)."""
    from daemon.cli.output import verbosity
    from daemon.protect.job import shown_name, shown_path

    if not gone:
        return
    if root_gone is not None:
        why = f"their folder {root_gone} is gone (moved? `ppd restore FOLDER` restores them where they are)"
    else:
        names = ", ".join(shown_name(p) for p in gone[:3]) + (", ..." if len(gone) > 3 else "")
        why = f"{names} (`ppd restore FILE` brings one back)"
    console().print(f"{len(gone)} gone since patched, not recreated: {why}", markup=False)
    if verbosity() > 0:
        for p in gone:
            console().print(f"gone {shown_path(p)}", markup=False)


def restore_word(outcome: ProtectOutcome) -> str:
    """restored: the original is back at its place; removed: a patched copy (`--out`) was deleted
    and nothing put back there (an --out copy has no original of its own); unchanged; failed; skipped:
    another ppd process held the file past the wait (restore_file)."""
    if outcome.state == "restored" and outcome.output is None:
        return "removed"
    return str(outcome.state)


def _print_outcomes(outcomes: list[ProtectOutcome], counted: Collection[Path] = ()) -> None:
    """One count line, where removed copies were (a folder, not a line per file unless -v), then
    each file that was not restored with its reason; one skipped (another ppd process held it past the
    wait: restore_file) too, unless counted: the running ppd watch's line (_say_held) counts it."""
    from daemon.cli.output import verbosity
    from daemon.protect.displaced import SAVED_OVER
    from daemon.protect.job import shown_name, shown_path
    from daemon.protect.restoring import FROM_PUBLISH_FOLDER
    from daemon.store.datasets import natural_key

    counts = Counter(restore_word(o) for o in outcomes)
    words = ("restored", "removed", "unchanged", "failed")
    console().print(", ".join(f"{k} {counts.get(k, 0)}" for k in words))
    removed = [o.path for o in outcomes if restore_word(o) == "removed"]
    if removed:
        folder = removed[0].parent if len(removed) == 1 else Path(os.path.commonpath(removed))
        said = f"removed {len(removed)} patched copies from {folder} (--out copies: no original goes there)"
        console().print(said, markup=False)
    # a published file's original goes back to where it was patched, and its copy leaves the publish
    # folder: said, not only under -v (a black-box review: 'restored 2' and the published copies gone)
    unpublished = [o for o in outcomes if o.state == "restored" and FROM_PUBLISH_FOLDER in (o.reason or "")]
    if unpublished:
        console().print(f"removed {len(unpublished)} published copies from the publish folder; their "
                        "originals are back where they were patched", markup=False)  # fmt: skip
    for o in sorted(outcomes, key=lambda o: natural_key(str(o.path))):  # x2 before x10
        word = restore_word(o)
        for src, kept in o.displaced if word != "failed" else ():  # a failure's reason names them already
            shown = shown_name(src) if src == o.path else shown_path(src)  # a published file can have two
            console().print(f"kept your version of {shown} at {shown_path(kept)} (not ppd's output as ppd "
                            "wrote it; nothing is published from there)", markup=False)  # fmt: skip
        if word == "skipped" and o.path in counted:
            continue
        if word in ("failed", "skipped"):
            said = reason_text(o.reason, Path(o.path).parent, hint_out=False)  # restore has no --out
            said = f"ppd: not restored: {shown_path(o.path)}: {_escaped(said, o.path)}"
            err_console().print(said, markup=False)
        elif verbosity() > 0:  # -v names each file (README), with its reason when it has one
            why = f": {_escaped(o.reason, o.path)}" if o.reason else ""
            console().print(f"{word} {shown_path(o.path)}{why}", markup=False)
        elif o.reason and (word not in ("restored", "unchanged", "removed") or SAVED_OVER in o.reason):
            console().print(f"{word} {shown_path(o.path)}: {_escaped(o.reason, o.path)}", markup=False)


def _escaped(text: str, path: Path) -> str:
    """A reason that names the file, with the name escaped as the line's path is (shown_name): a name
    with a newline printed raw read as two lines (a black-box review, F9)."""
    from daemon.protect.job import shown_name

    shown = shown_name(path)
    return text.replace(path.name, shown) if path.name and shown != path.name else text


def register(app: typer.Typer) -> None:
    app.command("restore")(restore)
