"""`ppd dataset show NAME` and `ppd dataset set NAME [spec flags]`: a dataset's patch spec; `ppd dataset
forget NAME`: a finished or deleted dataset leaves ppd, its originals with it."""

from __future__ import annotations

import contextlib
import json
import os
import shlex
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import typer

from daemon.cli.dataset_masks import (
    apply_masks_change,
    masks_change,
    masks_show_line,
    no_subject_masks_option,
    remembered_masks_option,
)
from daemon.cli.errors import die, file_reason, one_line, open_ctx
from daemon.cli.options import SpecOptions, spec_options
from daemon.cli.output import console, err_console, print_line
from poisoner.errors import ExitStatus

if TYPE_CHECKING:
    from daemon.context import AppContext
    from daemon.protect.forgetting import Forgotten, Patched
    from poisoner.spec import PatchSpec

# a dataset whose spec no file and no `dataset set` gave yet (set up with its masks, or rebuilt)
NO_SPEC_YET = "no spec yet: its first patched file gets the config's"

dataset_app = typer.Typer(
    help="Show or set a dataset's patch spec; forget a finished one.", no_args_is_help=True
)


@dataset_app.command("show")
def dataset_show(name: str, as_json: bool = typer.Option(False, "--json")) -> None:
    """A dataset's spec and counts."""
    from daemon.cli.status_queries import dataset_status
    from poisoner.spec import PatchSpec

    ctx = open_ctx()
    try:
        info = dataset_status(ctx, name)
        if as_json:
            typer.echo(json.dumps(info, indent=2, default=str))
            return
        said = f"spec {info['spec_id']}: {info['spec_summary']}" if info["spec_id"] else _no_spec(ctx, name)
        console().print(f"[bold]{name}[/] at {info['root']}  {said}")
        if info["publish_dir"]:
            console().print(f"publish folder: {info['publish_dir']}", markup=False)
        if masks := masks_show_line(ctx, name):  # no command named the remembered folder (F1)
            print_line(console(), masks)
        if info["spec"]:
            console().print(PatchSpec.from_dict(info["spec"]).to_toml(), end="")
        console().print(" ".join(f"{k}={v}" for k, v in info["counts"].items()))
    finally:
        ctx.close()


def _no_spec(ctx: AppContext, name: str) -> str:
    """A dataset without a spec: none yet, or one a store rebuild did not recover (its files carry it;
    `dataset show` said "no spec yet: its first patched file gets the config's", and before that "None")."""
    from daemon.store.datasets import spec_not_recovered

    lost = ctx.store.lost_spec(name)
    return spec_not_recovered(name, lost) if lost else NO_SPEC_YET


def _reprotect(ctx: AppContext, name: str, spec: PatchSpec) -> int:
    """Every patched file of the dataset again from its vault original, with the new spec; returns
    how many failed (the command then exits 1, as `ppd poison` does: it exited 0; a black-box review)."""
    from daemon.protect.one_file import GONE_REASON, reprotect_dataset

    outcomes = reprotect_dataset(ctx, name, spec)
    gone = [o for o in outcomes if o.reason == GONE_REASON]
    counts = Counter(o.state for o in outcomes if o.reason != GONE_REASON)
    console().print(f"patched again {name}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    if gone:  # not failures: nothing of them is left to re-protect (status counts them no more)
        said = "deleted or moved away since ppd patched them: recorded so, nothing to re-protect"
        print_line(console(), f"{name}: {len(gone)} {said}")
    for o in outcomes:
        if o.state == "failed":
            err_console().print(f"ppd: failed: {o.path}: {file_reason(o.path, o.reason)}", markup=False)
    if line := _unmarked_line(ctx, name, spec):
        print_line(console(), line)
    return counts.get("failed", 0)


def _unmarked_line(ctx: AppContext, name: str, spec: PatchSpec) -> str | None:
    """The dataset's files a re-protect does not reach, as they carry no mark of ppd's (it patches its
    patched files again and retries the failed, skipped and pending ones): how many, why, and what
    patches them. It said nothing of them, and the user took the whole dataset for one carrying the new
    spec (a black-box review). A file ppd patches later gets the dataset's spec (ensure_dataset)."""
    from daemon.datasets.folder_count import current_counts, dataset_folder, restored_in_place, resume_command

    root = str((ctx.store.dataset(name) or {})["root"])
    folder = dataset_folder(ctx, name, root)
    counts, restored = current_counts(ctx, name, folder), restored_in_place(ctx, name, root)
    kept = (ctx.store.dataset_spec(name) or spec).spec_id == spec.spec_id  # not when every file failed
    which = "the new spec" if kept else "the dataset's spec (still the earlier one: no file took the new)"
    command = resume_command(name, folder)
    kinds = [
        (counts.get("untracked", 0), f"not patched yet (`{command}` patches them with {which})"),
        (restored, f"restored by you (`{command} --force` patches them with {which})"),
        (counts.get("quarantined", 0), "quarantined, as ppd could not patch them "
                                       f"(`ppd status {shlex.quote(name)} --failed` says where they went)"),
        (counts.get("not_utf8", 0), "named in bytes that are not UTF-8: ppd patches them once renamed"),
    ]  # fmt: skip
    said = [f"{n} {why}" for n, why in kinds if n]
    if not said:
        return None
    total = sum(n for n, _ in kinds)
    return f"{name}: {total} of its files not re-protected, as they carry no mark of ppd's: {'; '.join(said)}"


def _spec_line(ctx: AppContext, name: str, asked: PatchSpec, summary: Callable[[PatchSpec], str]) -> str:
    """The dataset's spec as the store holds it: a re-protect that no file took keeps the earlier one
    (it printed the new one's id; a helper's review); none yet: its first patched file sets it."""
    held = ctx.store.dataset_spec(name)
    if held is None:
        return f"{name}: {_no_spec(ctx, name)}"
    if held.spec_id == asked.spec_id:
        return f"{name}: spec {held.spec_id} ({summary(held)})"
    return f"{name}: spec still {held.spec_id} ({summary(held)}): no file took the new spec {asked.spec_id}"


def _move_root(ctx: AppContext, name: str, old: Path, new: Path) -> None:
    """--root on an existing dataset: its folder was moved (`mv shoot shoot_new`), the dataset follows
    (name, spec, verdicts, its rows re-pointed), by the store's one move (the one `ppd restore` uses).
    A black-box review: the option was silently ignored (exit 0), and the status advice `ppd poison NEW`
    made a second dataset. Refused (exit 2) when it would not be a move."""
    from daemon.cli.targets import same_folder

    if os.path.lexists(old):
        raise die(f"the folder of dataset {name!r}, {old}, is still there: --root moves a dataset whose "
                  f"folder was moved; `ppd poison {shlex.quote(str(new))}` makes a new dataset of "
                  f"{new}")  # fmt: skip
    if not new.is_dir():
        raise die(f"--root {new}: no such folder")
    for other in ctx.store.datasets():
        if other["name"] != name and other["root"] and same_folder(Path(other["root"]), new):
            raise die(f"--root {new} is the folder of dataset {other['name']!r}; a folder is one dataset's")
    moved = ctx.store.move_dataset(name, old, new)
    if moved is None:  # another ppd moved it first
        raise die(f"dataset {name!r} was moved by another ppd meanwhile: `ppd dataset show {name}`")
    console().print(f"{name}: moved from {old} to {new} ({moved} files' records moved with it)", markup=False)


@dataset_app.command("set")
@spec_options()
def dataset_set(
    name: str = typer.Argument(..., help="The dataset."),
    root: Path | None = typer.Option(
        None, "--root", help="Dataset folder (default: OUTBOX/NAME); a moved dataset folder's new place."
    ),
    publish_dir: Path | None = typer.Option(None, "--publish-dir", help="Move patched files here."),
    subject_masks: Path | None = remembered_masks_option(),
    no_subject_masks: bool = no_subject_masks_option(),
    reprotect: bool = typer.Option(False, "--reprotect", help="Patch again from the vault originals."),
    spec_options: SpecOptions = SpecOptions(),
) -> None:
    """Set a dataset's spec. Once files are patched, a new spec needs --reprotect (every
    image must carry the same patch). --root NEWFOLDER moves a dataset whose folder you moved. A new
    dataset needs its folder: OUTBOX/NAME made first, or --root.

    \b
    Examples:
      ppd dataset set castle --design paper
      ppd dataset set castle --patch-size 8% --reprotect
      ppd dataset set castle --root ~/Photos/castle-2026
      ppd dataset set castle --subject-masks ~/Photos/castle-masks
    """
    from daemon.cli.status_queries import spec_summary
    from daemon.datasets.dataset import dataset_root
    from daemon.store import DatasetSpecLocked
    from poisoner.spec import SpecError

    ctx = open_ctx(needs_key=reprotect)  # --reprotect seals files
    failed = 0
    try:
        existing = ctx.store.dataset(name)
        if existing is None:
            _refuse_without_folder(ctx, name, root)
        # before anything is written (a refused folder made the dataset): published, never ppd's own,
        # nor in (or holding) this dataset's folder, as it will be, or another's
        if publish_dir is not None and (why := ctx.paths.publish_dir_problem(
                publish_dir, _roots(ctx, name, root, existing))):  # fmt: skip
            raise die(f"--publish-dir {publish_dir}: {why}; choose another folder")
        masks = masks_change(ctx, name, subject_masks, no_subject_masks)
        if root is not None and existing and existing["root"] and not _same_root(existing["root"], root):
            _move_root(ctx, name, Path(existing["root"]), root.absolute())
            existing = ctx.store.dataset(name)
        base = ctx.store.dataset_spec(name) or ctx.config.spec_for(name)
        try:
            spec = spec_options.build(base)
        except (SpecError, OSError, ValueError) as exc:
            raise die(one_line(exc)) from None
        folder = root.absolute() if root else (Path(existing["root"]) if existing else None)
        folder = folder or dataset_root(ctx.paths.outbox.absolute(), name)
        if existing is None:  # its row, with the config's publish folder (a row made with the spec had none)
            ctx.store.add_dataset(name, folder, None, ctx.config.publish_dir_for(name))
        if masks is not None:  # before the spec: never set without its masks
            print_line(console(), apply_masks_change(ctx, name, masks, reprotect))
        if reprotect and existing is not None:
            failed = _reprotect(ctx, name, spec)
        elif spec_options.given() or (masks is None and existing is None):
            # an existing dataset's spec only by its flags: `--root` alone on one whose spec a rebuild
            # lost moved it, then failed on the config's spec (a diff review)
            try:
                ctx.store.set_dataset_spec(name, spec, root=folder)
            except DatasetSpecLocked as exc:
                raise die(str(exc)) from None
        if publish_dir is not None:
            _set_publish_dir(ctx, name, publish_dir)
        console().print(_spec_line(ctx, name, spec, spec_summary), markup=False)
    finally:
        ctx.close()
    if failed:
        raise typer.Exit(ExitStatus.FAILED)


def _set_publish_dir(ctx: AppContext, name: str, publish_dir: Path) -> None:
    """--publish-dir: said to apply to files patched from now on (the review found the folder with 1
    photo of 3), and when the installed service cannot write there yet."""
    from daemon.watch.service import unit_lacks

    ctx.store.set_dataset_publish_dir(name, publish_dir.absolute())
    earlier = ctx.store.counts(name).get("patched", 0)
    stay = f"; the {earlier} patched before stay where they are" if earlier else ""
    console().print(f"{name}: files patched from now on go to {publish_dir.absolute()}{stay}", markup=False)
    if unit_lacks(publish_dir):  # ProtectSystem=strict: read-only to the service until listed
        said = "ppd.service cannot write there yet: run `ppd service install` again"
        console().print(said, markup=False)


@dataset_app.command("forget")
def dataset_forget(
    name: str = typer.Argument(..., help="The dataset."),
    force: bool = typer.Option(
        False, "--force", help="Forget it while patched files of it are there (they keep the mark for good), "
        "or while its folder in the outbox holds files (`ppd watch` patches them again)."
    ),
) -> None:
    """Forget a finished or deleted dataset. Its records leave the store, and its originals that no
    other dataset uses leave the vault. Its patched photos must be gone or restored (`ppd restore NAME`)
    first: the vault's originals are the only way back. A folder in the outbox must be moved out first:
    `ppd watch` would patch its files again. Stop `ppd watch` first.

    \b
    Examples:
      ppd dataset forget castle
    """
    from daemon.paths import AppPaths
    from daemon.protect.forgetting import ForgetUnfinished, Patched, forget_dataset, unfinished
    from daemon.store import StoreError
    from daemon.store.vault import VaultError

    paths = AppPaths.from_env()
    with _alone(paths.data_dir):
        ctx = open_ctx(store_held=True)
        try:
            finishing = unfinished(ctx, name)  # its rows gone already: nothing to check
            marked, again = (Patched([], []), None) if finishing else _forget_check(ctx, name, force)
            done = forget_dataset(ctx, name)
        except ForgetUnfinished as exc:
            raise die(exc, ExitStatus.ENVIRONMENT) from None
        except (StoreError, VaultError, OSError) as exc:
            raise die(f"cannot forget dataset {name!r}: {one_line(exc)}", ExitStatus.ENVIRONMENT) from None
        finally:
            ctx.close()
    _say_forgotten(name, done, marked, again)


@contextlib.contextmanager
def _alone(data_dir: Path) -> Iterator[None]:
    """No other ppd process on this data folder while a dataset is forgotten: one could record a row
    for an original between the check that none names it and its removal; refused with one line,
    exit 3 (as `ppd store rebuild` and `ppd key new` are)."""
    from daemon.locks import LockHeld, store_alone, watch_running, watching

    then = "forget the dataset"
    if holders := watching(data_dir):
        raise die(watch_running(holders[0], then), ExitStatus.ENVIRONMENT)
    try:
        with store_alone(data_dir, "ppd dataset forget is forgetting a dataset", then):
            yield
    except LockHeld as exc:
        raise die(exc, ExitStatus.ENVIRONMENT) from None
    except OSError as exc:  # the lock file's folder
        raise die(f"cannot lock the store: {one_line(exc)}", ExitStatus.ENVIRONMENT) from None


def _forget_check(ctx: AppContext, name: str, force: bool) -> tuple[Patched, Again | None]:
    """Refused (exit 2) unless --force: a folder seen moved (its patched files there: `ppd dataset
    set --root` follows it), patched files of the dataset still there (their originals are the
    only way back), while its folder is there, patched files not found where they were patched
    (moved to an album? `ppd restore FILE` needs the original), or a folder in the outbox that still
    holds files `ppd watch` would patch again. Returns the patched files, there and gone, and those
    files of the outbox; an unknown dataset is refused by dataset_status."""
    from daemon.cli.status_queries import dataset_status
    from daemon.protect.forgetting import patched_files, removed_as_copies
    from daemon.states import FileState

    info = dataset_status(ctx, name)  # as `ppd status` judges it
    folder = info["folder"]
    root, moved, there = folder["folder"], folder.get("moved_to"), folder.get("moved_to_dataset")
    # seen moved while its rows still call them patched: no other row names their originals (a run
    # in the new folder carries the rows over, after which they are that dataset's: forgetting is free)
    # (or recorded removed, by a `ppd watch` that saw the outbox move away: no other dataset holds them)
    held = ctx.store.counts(name).get(FileState.PATCHED) or not there
    if not force and not folder["exists"] and moved and held:
        follow = f"`ppd poison {shlex.quote(moved)}` records them in dataset {there!r}" if there else (
            f"`ppd dataset set {shlex.quote(name)} --root {shlex.quote(moved)}` moves the dataset there")
        raise die(f"the folder of dataset {name!r}, {root}, is gone, but its patched files are in {moved} "
                  f"(moved?): {follow}; --force forgets it all the same (those files then keep the mark "
                  "for good)")  # fmt: skip
    marked = patched_files(ctx, name)
    if marked.there and not force:
        there = marked.there
        inside = folder["exists"] and all(Path(p).is_relative_to(root) for p in there)
        where = f"in {root}" if inside else f"({there[0]}{', ...' if len(there) > 1 else ''})"
        raise die(f"dataset {name!r} has {len(there)} patched file(s) still there {where}: their "
                  f"originals in the vault are the only way back; `ppd restore {shlex.quote(name)}` "
                  "first, or --force to forget it all the same (those files then keep the mark for "
                  "good)")  # fmt: skip
    # a folder still there with patched files missing from it: moved somewhere status cannot see (an
    # album, another drive)? A whole shoot deleted (its folder gone) is what forget is for: said, below
    if marked.gone and folder["exists"] and not force:
        gone = marked.gone
        named = ", ".join(str(p.relative_to(root) if p.is_relative_to(root) else p) for p in gone[:2])
        named += ", ..." if len(gone) > 2 else ""
        raise die(f"dataset {name!r} has {len(gone)} patched file(s) not found where they were patched "
                  f"(moved or deleted?): {named}; their originals in the vault are the only way back for "
                  "a copy of them: `ppd restore FILE` on a moved one first, or --force to forget it all the "
                  "same (any copy of them then keeps the mark for good)")  # fmt: skip
    if (lost := removed_as_copies(ctx, name)) and not force:  # an earlier ppd's restore (F1)
        raise die(lost)
    if (before := _photos_from_before(ctx, name)) and not force:
        raise die(f"dataset {name!r} has {len(before)} photo(s) saved over ppd's patched ones (an edit of "
                  "the marked picture?): the photo from before each is only in the vault "
                  f"({before[0]}{', ...' if len(before) > 1 else ''}): copy it out first, or --force to "
                  "forget it all the same (it then leaves the vault)")  # fmt: skip
    again = _in_the_outbox(ctx, folder, marked)
    if again is not None and not force:
        raise die(f"the folder of dataset {name!r}, {again.folder}, is in the outbox: `ppd watch` would "
                  f"patch its {again.files} file(s) again once it is forgotten (restored ones too: no record "
                  "says restored any more); move the folder out of the outbox first, or --force to forget it "
                  "all the same")  # fmt: skip
    return marked, again


def _photos_from_before(ctx: AppContext, name: str) -> list[Path]:
    """The vault copies of the photos from before an edit of ppd's patched photo (files.saved_over) that
    forgetting the dataset would remove: `ppd restore` named each as the only unmarked copy, to be copied
    out (a diff review: forget then removed them without a word)."""
    shas = {row["saved_over"] for row in ctx.store.files(name) if row.get("saved_over")}
    kept = [sha for sha in sorted(shas) if ctx.vault.has(sha)]
    return [ctx.vault.path_for(sha) for sha in kept]


class Again(NamedTuple):
    """A dataset folder in the outbox and how many of its files `ppd watch` would patch again."""

    folder: Path
    files: int


def _in_the_outbox(ctx: AppContext, folder: dict[str, Any], marked: Patched) -> Again | None:
    """The dataset's folder, when it is in the outbox and holds media files other than its patched
    ones (restored, never patched, failed): forgotten, they have no row, and the daemon's catch-up scan
    patches them as new files (a black-box review: `ppd restore` then `forget`, the README's flow for a
    finished shoot, had every restored original patched again at the next `ppd watch` start). Its
    patched files carry the seal: the daemon leaves them."""
    root = Path(folder["folder"])
    if not folder["exists"] or not _inside(root, ctx.paths.outbox):
        return None
    files = folder["on_disk"] - sum(1 for p in marked.there if Path(p).is_relative_to(root))
    return Again(root, files) if files > 0 else None


def _inside(path: Path, outbox: Path) -> bool:
    """Whether path is the outbox or in it, as the daemon sees it (either reached through a symlink)."""
    real, box = Path(os.path.realpath(path)), Path(os.path.realpath(outbox))
    return real.is_relative_to(box)


def _say_forgotten(name: str, done: Forgotten, marked: Patched, again: Again | None) -> None:
    from poisoner.video.model import size_text

    line = (f"forgot dataset {name}: {done.rows} file record(s); {done.removed} original(s) "
            f"({size_text(done.removed_bytes)}) removed from the vault")  # fmt: skip
    if done.kept:
        line += f"; {done.kept} original(s) kept: another dataset uses them"
    console().print(line, markup=False)
    if marked.there:  # --force: said, not implied
        console().print(f"its {len(marked.there)} patched file(s) still there keep the mark for good: ppd "
                        "can no longer restore them", markup=False)  # fmt: skip
    if marked.gone:  # --force, or a deleted folder: a copy kept elsewhere is marked for good, said
        console().print(f"{len(marked.gone)} patched file(s) not found where they were patched (moved or "
                        "deleted?): any copy of them keeps the mark for good", markup=False)  # fmt: skip
    if again is not None:  # --force: said, not implied
        console().print(f"its {again.files} file(s) in the outbox ({again.folder}) are no dataset's now: "
                        "`ppd watch` patches them again", markup=False)  # fmt: skip
    if done.displaced is not None:
        console().print(f"the files ppd set aside for it (`ppd restore --force`) stay in {done.displaced}: "
                        "they are yours", markup=False)  # fmt: skip


def _refuse_without_folder(ctx: AppContext, name: str, root: Path | None) -> None:
    """A new dataset without its folder: refused (exit 2), one line, with a "did you mean" when the name
    is like an existing one's. `ppd dataset set garden --design paper` made a dataset of OUTBOX/garden, a
    folder that did not exist (exit 0); status called it "gone", and `ppd poison` of the real garden folder
    was refused as the name was taken (a seventh black-box review, F4; a fifth refused only a likely
    typo). The folder made first, or --root naming one, says a new dataset is meant."""
    from daemon.datasets.dataset import dataset_root, likely_meant

    if root is not None:
        if not root.is_dir():
            raise die(f"--root {root}: no such folder; a new dataset needs its folder")
        return
    folder = dataset_root(ctx.paths.outbox.absolute(), name)
    if folder.is_dir():
        return
    near = likely_meant(name, [d["name"] for d in ctx.store.datasets()])
    meant = f" (did you mean {near!r}?)" if near else ""
    raise die(f"no dataset {name!r}{meant}; a new dataset of that name needs its folder: make {folder} "
              "first, or give --root")  # fmt: skip


def _roots(
    ctx: AppContext, name: str, root: Path | None, existing: dict[str, Any] | None
) -> list[tuple[str, Path]]:
    """Every stored dataset's folder, with this one's as `dataset set` leaves it (--root, else the
    stored one, else OUTBOX/NAME): a publish folder must lie apart from each."""
    from daemon.datasets.dataset import dataset_root

    own = root.absolute() if root else (Path(existing["root"]) if existing and existing["root"] else None)
    roots = [(d["name"], Path(d["root"])) for d in ctx.store.datasets() if d["root"] and d["name"] != name]
    return [*roots, (name, own or dataset_root(ctx.paths.outbox.absolute(), name))]


def _same_root(stored: str, root: Path) -> bool:
    return Path(stored).absolute() == root.absolute()


def register(app: typer.Typer) -> None:
    app.add_typer(dataset_app, name="dataset")
