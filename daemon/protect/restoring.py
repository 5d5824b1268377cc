"""`ppd restore`'s one file: restore_file puts a patched file's original back from the vault, found
by the file's row or, without one (a lost store, a file moved or renamed), by its provenance seal."""

from __future__ import annotations

import contextlib
import os
import shlex
import stat
from pathlib import Path
from typing import Any, Literal

from daemon.context import AppContext
from daemon.datasets.dataset import (
    OutsideOutboxError,
    dataset_of,
    dataset_root,
    ensure_dataset,
    innermost_holder,
)
from daemon.fsops import sha256_fd
from daemon.locks import LockHeld
from daemon.platform import fd_path
from daemon.protect.displaced import (
    changed_words,
    displaced_folder,
    keep_aside,
    resaved_words,
    saved_over_note,
)
from daemon.protect.job import Outcome, ProtectOutcome, ProtectRefused, name_the_disk, no_space_in, one_line
from daemon.protect.recovery import ORIGINAL_FIELDS
from daemon.states import FileState
from daemon.store.vault import sha256_file
from poisoner.provenance import has_token

__all__ = ["FROM_PUBLISH_FOLDER", "restore_file", "written_as_copy"]


def restore_file(
    ctx: AppContext, path: Path, *, force: bool = False, home: tuple[str, Path] | None = None
) -> ProtectOutcome:
    """Put a patched file's original back where the file was changed in place (atomic); never
    into an output (`--out`) or publish folder: a patched copy there is removed instead, and the
    reason says so. Refuses when the file is no longer ppd's output (the user changed it) unless
    force. With no row of its path (a lost store, a renamed file), its seal or its exact bytes (another
    row's recorded output) name its original. home: the (dataset, root) of the folder `ppd restore`
    was given, where such a file is recorded unless it lies in its output's dataset folder.

    The file's lock is taken before its row is read: a file another ppd process is patching now (its
    row pending, or none yet) is waited for, then restored as the output it is. Its pending row was
    read first and said "state is pending", nothing restored, and the daemon then marked it (a
    black-box review, F13). Still held after the wait (the daemon encoding a long video): skipped,
    the reason naming the holder, and a folder's restore goes on with its other files; the lock's error
    ended it mid-folder, the lines of the files restored so far never said (a diff review)."""
    path = Path(path).absolute()
    with contextlib.ExitStack() as held:
        try:
            held.enter_context(ctx.path_lock(path))
        except LockHeld as exc:
            return ProtectOutcome(path=path, dataset=None, state=Outcome.SKIPPED, reason=one_line(exc))
        return _restore_held(ctx, path, force, home)


def _restore_held(ctx: AppContext, path: Path, force: bool, home: tuple[str, Path] | None) -> ProtectOutcome:
    """restore_file's work, its lock held."""
    row, why = ctx.store.file(path), ""
    if row is None:
        row, why = _row_by_provenance(ctx, path)
    if row is None:
        row = _restored_unrecorded(ctx, path)
    if row is None:
        return ProtectOutcome(path=path, dataset=None, state=Outcome.FAILED, reason=why)
    dataset = row["dataset"]
    if row["state"] == FileState.PENDING:  # a run killed mid-file: the file says whether it is patched
        row = _pending_as_patched(ctx, path, row)
    if row["state"] == FileState.FAILED and has_token(path):  # ppd's output a poison refused (another key's
        found, why = _row_by_provenance(ctx, path)  # seal): "unchanged" read as "your original" (a review)
        if found is None:
            return ProtectOutcome(path=path, dataset=dataset, state=Outcome.FAILED, reason=why)
        row = found
    if row["state"] != FileState.PATCHED or not row["original_sha256"]:
        return ProtectOutcome(
            path=path, dataset=dataset, state=Outcome.UNCHANGED, reason=f"state is {row['state']}"
        )
    # A file found by its seal, not by its path, is ppd's output moved or copied by the user: it is
    # theirs, never removed as an --out copy (a black-box review: `ppd restore desk/moved.jpg` deleted
    # it); a copy of an --out or published copy still gets no original.
    if row.get("from_marker") and home is not None and (owner := _owned_elsewhere(ctx, path, row, home[0])):
        return ProtectOutcome(path=path, dataset=owner, state=Outcome.UNCHANGED,
                              reason=f"a file of dataset {owner!r}, not of {home[0]!r}: `ppd restore "
                                     f"{owner}` or `ppd restore FILE` restores it")  # fmt: skip
    copy = None if row.get("from_marker") else _copy_outside_the_source(ctx, row)
    if copy is not None and (doubt := _maybe_not_a_copy(ctx, row)) is not None:
        return ProtectOutcome(path=path, dataset=dataset, state=Outcome.FAILED, reason=doubt)
    if row.get("from_marker") and (refusal := _copied_output(ctx, row)):
        return ProtectOutcome(path=path, dataset=dataset, state=Outcome.FAILED, reason=refusal)
    kept: list[tuple[Path, Path]] = []  # (the user's file that stood in the original's way, its copy)
    reason: str | None = None
    try:
        if copy is not None:
            target = Path(row["path"]) if row["published_path"] else None
            # published: the original goes back to where it was patched. Refused before the copy goes:
            # the published photo was removed, then its original refused its place (a diff review)
            now = _content_now(target) if target is not None else None
            taken = now is not None and now != row["original_sha256"]
            if target is not None and taken and not force:
                raise ProtectRefused(f"{target} exists (another photo under this name?); not overwriting "
                                     "it with the original, nor removing the published copy (use --force)")
            reason = _remove_patched_copy(ctx, row, copy, force, kept)
            if target is not None:
                replaces: str | None | Literal[True] = None  # nothing there, or a restore killed midway
                if taken:
                    replaces = _displace(ctx, dataset, target, kept)
                if now != row["original_sha256"]:
                    with no_space_in(target.parent):
                        ctx.vault.restore(
                            row["original_sha256"], target, replaces=replaces,
                            mtime_ns=row.get("original_mtime_ns"),
                        )  # fmt: skip
                reason = f"original back at {target}; {reason}"
        else:
            target = path
            if not target.parent.is_dir():  # not a raw "[Errno 2]" per file (a black-box review)
                raise ProtectRefused(f"its folder {target.parent} is gone (moved or deleted?); "
                                     "`ppd restore` the folder or file where it is now")  # fmt: skip
            now = _content_now(target)
            # the check again just before the rename: a writer between the two is not overwritten
            replaces = row["poisoned_sha256"]
            if now is not None and (now not in (row["poisoned_sha256"], row["original_sha256"])
                                    or (now == row["poisoned_sha256"] and row.get("resaved"))):
                if not force:
                    words = (resaved_words(target) if now == row["poisoned_sha256"]
                             else changed_words(ctx, target, row["original_sha256"]))
                    aside = displaced_folder(ctx, dataset)
                    raise ProtectRefused(f"{words}; not overwriting it (--force keeps your version in "
                                         f"{aside} and puts the original back)")  # fmt: skip
                replaces = _displace(ctx, dataset, target, kept)
            if now != row["original_sha256"]:  # the original already (a restore killed after its
                with no_space_in(target.parent):  # rename): recorded
                    ctx.vault.restore(
                        row["original_sha256"], target, replaces=replaces,
                        mtime_ns=row.get("original_mtime_ns"),
                    )  # fmt: skip
            reason = saved_over_note(ctx, row.get("saved_over"))
    except Exception as exc:
        said = one_line(name_the_disk(exc, [path.parent, ctx.paths.data_dir]))  # not a raw "[Errno 28]"
        said += "".join(f"; your version of {src} is kept at {to}" for src, to in kept)
        return ProtectOutcome(
            path=path, dataset=dataset, state=Outcome.FAILED, reason=said, displaced=tuple(kept)
        )
    carried: dict[str, Any] = {}
    if row.get("from_marker"):
        where = _record_by_provenance(ctx, path, row, home)
        if where is None:
            return ProtectOutcome(
                path=path, dataset=dataset, state=Outcome.RESTORED, reason=reason,
                original_sha256=row["original_sha256"], output=target, displaced=tuple(kept),
            )  # fmt: skip
        dataset, carried = where
    # the restored file's size and time: the daemon's catch-up scan leaves it alone while they hold
    # (it judged every restored file again at each start, one "restored by the user" line each)
    signature = _size_and_time(target) if target is not None else {}
    ctx.store.record_file(
        path, dataset, FileState.RESTORED, original_sha256=row["original_sha256"], published_path=None,
        event="restored", **signature, **carried,
        detail={"to": str(target) if target else None, "sha256": row["original_sha256"], "note": reason,
                **({"displaced": [str(to) for _, to in kept]} if kept else {})},
    )  # fmt: skip
    return ProtectOutcome(
        path=path, dataset=dataset, state=Outcome.RESTORED, reason=reason,
        original_sha256=row["original_sha256"], output=target, displaced=tuple(kept),
    )  # fmt: skip


def _copy_outside_the_source(ctx: AppContext, row: dict[str, Any]) -> Path | None:
    """Where a patched *copy* sits that must never receive an original: the publish folder
    (published_path), or an output folder (`ppd poison --out`: the row's path lies outside its
    dataset's source folder). None: the file was patched in place."""
    if row["published_path"]:
        return Path(row["published_path"])
    dataset = ctx.store.dataset(row["dataset"])
    if dataset is not None and not Path(row["path"]).is_relative_to(Path(dataset["root"])):
        return Path(row["path"])
    return None


def _maybe_not_a_copy(ctx: AppContext, row: dict[str, Any]) -> str | None:
    """Why a row outside its dataset's folder is not removed as an `--out` copy: the folder is gone, and
    no record says ppd wrote the file as a copy (stages' `copy_of`, a `copied` row). It may be the
    dataset's own photo, moved with its folder: an eighth black-box review (F1) saw `ppd restore` delete
    a moved outbox's photos as copies, their originals put back nowhere. None: a copy (a publish folder's
    is ppd's own; an `--out` copy of a folder that is there, or recorded as one)."""
    stored = ctx.store.dataset(row["dataset"])
    if row["published_path"] or stored is None or Path(stored["root"]).is_dir():
        return None
    path, name = row["path"], row["dataset"]
    if written_as_copy(ctx, path):
        return None
    return (f"not removed: {path} lies outside the folder of dataset {name!r}, {stored['root']}, which is "
            "gone, and ppd has no record of writing it as an --out copy: if the dataset's folder moved, "
            f"`ppd dataset set {shlex.quote(name)} --root NEWFOLDER` (the folder it is in now), then "
            f"`ppd restore {shlex.quote(name)}`, gives back its originals; an --out copy an earlier ppd "
            "made is yours to delete")  # fmt: skip


def written_as_copy(ctx: AppContext, path: str) -> bool:
    """Whether ppd recorded writing path as an `--out` copy (stages' `copy_of`; a `copied` output)."""
    written = ctx.store.last_event(path, "patched") or {}
    return "copy_of" in (written.get("detail") or {}) or ctx.store.last_event(path, "copied") is not None


def _stored_output(ctx: AppContext, row: dict[str, Any]) -> dict[str, Any] | None:
    """The store's row of the output a file found by its seal is (a patched row of the same bytes;
    of several, one whose file is gone from its path: this file is that one, moved or renamed)."""
    sha = row["poisoned_sha256"]
    if not sha:
        return None
    return ctx.store.find_poisoned(sha, moved_first=True, state=FileState.PATCHED, near=Path(row["path"]))


def _record_by_provenance(
    ctx: AppContext, path: Path, row: dict[str, Any], home: tuple[str, Path] | None
) -> tuple[str, dict[str, Any]] | None:
    """Where the restore of a file found by its seal (no row of its path) is recorded: (the dataset,
    the fields carried from the store's row of that output); None: nowhere.

    The store's row of the same output whose file is gone from its path is that file, moved or renamed:
    it is marked removed, and this path takes its place; in that row's dataset folder it is recorded
    restored there, so `ppd poison` leaves it unpatched as it does every restored file (a black-box
    review: after `mv A/0000.jpg A/r.jpg; ppd restore A/r.jpg`, poison patched r.jpg again). Elsewhere
    it is recorded in home's dataset, the folder `ppd restore` was given (a dataset folder moved), as
    `ppd poison` records a moved file in its new folder's dataset; a single file moved out of its
    dataset's folder is recorded nowhere: no dataset is made of the folder it sits in now (a review:
    that folder's other photos became "not patched yet"). With no row of that output (a lost store),
    the dataset comes back with it: home's, else the file's own folder's."""
    stored = _stored_output(ctx, row)
    if stored is None and home is not None:
        ensure_dataset(ctx, home[0], home[1], None)
        return home[0], {}
    if stored is None:
        dataset = row["dataset"]
        outbox = Path(ctx.paths.outbox).absolute()  # outside it, the folder (not one in the outbox)
        root = dataset_root(outbox, dataset) if path.is_relative_to(outbox) else path.parent
        ensure_dataset(ctx, dataset, root, None)
        return dataset, {}
    if not os.path.lexists(stored["path"]):
        ctx.store.record_file(
            stored["path"], stored["dataset"], FileState.REMOVED, event="moved_away", detail={"to": str(path)}
        )
    carried = {k: stored.get(k) for k in ORIGINAL_FIELDS if k != "original_sha256"}
    own = ctx.store.dataset(stored["dataset"])
    if own is not None and path.is_relative_to(Path(own["root"]).absolute()):
        return stored["dataset"], carried
    if home is None:
        return None
    spec = ctx.store.get_spec(stored["spec_id"]) if stored["spec_id"] else None
    ensure_dataset(ctx, home[0], home[1], spec)  # a dataset first seen through moved files: their spec
    return home[0], carried


def _owned_elsewhere(ctx: AppContext, path: Path, row: dict[str, Any], home: str) -> str | None:
    """The other dataset a file found by its seal belongs to, when a folder restore of home came upon
    it: the dataset whose folder holds it (the innermost), or the one whose row of the same output
    lies in a folder holding it; None: home may take it (a diff review: `ppd restore castle` restored
    and recorded castle/day2's renamed file)."""
    datasets = ctx.store.datasets()
    holder = innermost_holder(datasets, path, prefer=home)
    if holder is not None and holder != home:
        return holder
    stored = _stored_output(ctx, row)
    if stored is None or stored["dataset"] == home:
        return None
    held = innermost_holder([d for d in datasets if d["name"] == stored["dataset"]], path)
    return held


def _copied_output(ctx: AppContext, row: dict[str, Any]) -> str | None:
    """Why a file found by its seal gets no original: the store's row of the same output is a copy
    in an --out or publish folder (originals never go where copies are published); None otherwise."""
    stored = _stored_output(ctx, row)
    copy = _copy_outside_the_source(ctx, stored) if stored is not None else None
    if stored is None or copy is None:
        return None
    return (f"a copy of ppd's output in {copy.parent}, which gets no original; its source's photos were "
            f"never changed (`ppd restore {stored['dataset']}` removes the dataset's copies)")


def _size_and_time(path: Path) -> dict[str, Any]:
    try:
        st = os.stat(path, follow_symlinks=False)
    except OSError:
        return {}
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


FROM_PUBLISH_FOLDER = "from the publish folder"  # the reason's words `ppd restore` counts


def _remove_patched_copy(
    ctx: AppContext, row: dict[str, Any], copy: Path, force: bool, kept: list[tuple[Path, Path]]
) -> str:
    """Delete ppd's patched copy from an output/publish folder; the reason line for the outcome. A copy
    changed since ppd wrote it is added to kept when --force keeps it aside."""
    where = "publish folder" if row["published_path"] else "output folder"
    if not copy.exists():
        return f"no patched copy left in the {where} {copy.parent}; originals are never written there"
    if sha256_file(copy) != row["poisoned_sha256"]:
        if not force:
            raise ProtectRefused(f"{copy} changed since ppd patched it; not removing it (use --force)")
        _displace(ctx, row["dataset"], copy, kept)
    copy.unlink()
    said = FROM_PUBLISH_FOLDER if row["published_path"] else f"from the {where}"
    return f"removed the patched copy {copy} {said}: restore never writes originals there"


def _content_now(path: Path) -> str | None:
    """The sha256 of the regular file at path (not followed); None when nothing is there; a word that
    is no sha256 for anything else (a symlink, a folder), which matches no row's content."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    except OSError:
        return "not a regular file" if os.path.lexists(path) else None
    try:
        return sha256_fd(fd) if stat.S_ISREG(os.fstat(fd).st_mode) else "not a regular file"
    finally:
        os.close(fd)


def _displace(
    ctx: AppContext, dataset: str | None, path: Path, kept: list[tuple[Path, Path]]
) -> str | Literal[True]:
    """The user's file at path kept aside (daemon.protect.displaced) before --force replaces it, added to
    kept (path, its copy); what vault.restore may replace: exactly the bytes kept, anything for a link."""
    copy, sha = keep_aside(ctx, dataset, path)
    kept.append((path, copy))
    return True if sha is None else sha


def _pending_as_patched(ctx: AppContext, path: Path, row: dict[str, Any]) -> dict[str, Any]:
    """A pending row (ppd was killed between replacing the file and recording it) read as patched
    when the file in place carries this installation's seal naming the row's original: restore then
    puts the original back. Before, it said "state is pending" and left the patched file, exit 0.
    A file without that seal (the original, never replaced) keeps the pending row: nothing to do."""
    sealed = _row_from_marker(ctx, path)
    if sealed is None or sealed["original_sha256"] != row["original_sha256"]:
        return row
    return {**row, "state": FileState.PATCHED, "poisoned_sha256": sealed["poisoned_sha256"]}


def _row_from_marker(ctx: AppContext, path: Path) -> dict[str, Any] | None:
    """A row for ppd's output found without a row of its path (_row_by_provenance), or None."""
    return _row_by_provenance(ctx, path)[0]


def _restored_unrecorded(ctx: AppContext, path: Path) -> dict[str, Any] | None:
    """A row for a file that holds the original of a patched row whose file is gone from its path, patched
    in place: a restore by seal killed after its rename, before its rows (the renamed file then had no
    seal and no row, and a diff review's next restore called it "no ppd provenance marker", so `ppd
    poison` patched it again). Read as that output, it is recorded restored; None for anything else."""
    sha = _content_now(path)
    rows = [r for r in (ctx.store.find_original(sha) if sha else []) if r["state"] == FileState.PATCHED]
    gone = next((r for r in rows if r["poisoned_sha256"] and gone_from_its_place(ctx, r)), None)
    if gone is None:
        return None
    return {
        "dataset": gone["dataset"], "path": str(path), "state": FileState.PATCHED, "published_path": None,
        "original_sha256": sha, "poisoned_sha256": gone["poisoned_sha256"], "from_marker": True,
    }  # fmt: skip


def _row_by_provenance(ctx: AppContext, path: Path) -> tuple[dict[str, Any] | None, str]:
    """A row for ppd's output found without a row of its path: its seal (verified with this
    installation's key over the file's bytes) and the vault; else its exact bytes, the output a
    patched row of the store records (as `ppd poison` finds it: a seal made with another key, since
    replaced). None with the reason in words: no marker, a marker of another key (`ppd key import`),
    ppd's marker over bytes changed since, or an original not in the vault."""
    from daemon.store.sealkey import SealKeyError
    from poisoner.provenance import has_token, read_seal_and_claim

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None, f"{path} is not in the store and carries no ppd provenance marker"
    try:
        try:
            key, no_key = ctx.seal_key(), None
        except SealKeyError as exc:  # the store's recorded output needs no key: that lookup goes on (a
            key, no_key = None, one_line(exc)  # review: a folder restore stopped midway, no summary)
        seal, claim = read_seal_and_claim(fd_path(fd), key)
        marked = seal is not None or claim is not None or has_token(fd_path(fd))
        sha = sha256_fd(fd)
    finally:
        os.close(fd)
    stored = ctx.store.find_poisoned(sha, moved_first=True, state=FileState.PATCHED, near=path)
    if seal is not None and ctx.vault.has(seal.original_sha256):
        original = seal.original_sha256
    elif stored is not None and stored["original_sha256"] and ctx.vault.has(stored["original_sha256"]):
        original = stored["original_sha256"]
    else:
        return None, _why_not_found(ctx, path, seal, claim, marked, no_key)
    try:
        dataset = dataset_of(ctx.paths.outbox, path)
    except OutsideOutboxError:
        dataset = path.parent.name
    return {
        "dataset": dataset, "path": str(path), "state": FileState.PATCHED, "published_path": None,
        "original_sha256": original, "poisoned_sha256": sha, "from_marker": True,
    }, ""  # fmt: skip


def _why_not_found(
    ctx: AppContext, path: Path, seal: Any, claim: Any, marked: bool, no_key: str | None
) -> str:
    """Why a file with no row of its path has no original to restore, in words that say what to do."""
    if marked and no_key is not None:
        return f"{path} carries a ppd marker, but the seal key that recognises it cannot be read: {no_key}"
    if seal is not None:  # said as what it most likely is: `forget --force` read like vault damage (a review)
        return (f"{path} carries ppd's seal, but its original {seal.original_sha256[:12]} is not in the "
                f"vault {ctx.vault.vault_dir} (forgotten by `ppd dataset forget`, or lost)")  # fmt: skip
    if claim is not None:  # this key's token over other bytes: an edit, or a token copied onto a photo
        return (f"{path} carries ppd's marker, but it changed since ppd patched it (its seal no longer fits "
                "its bytes); not restored")  # fmt: skip
    if marked:  # a review: "carries no ppd provenance marker" for a file sealed before `ppd key import`
        return (f"{path} carries a ppd marker sealed with another key than this installation's: "
                "`ppd key import` the key it was patched with, then restore it")  # fmt: skip
    return f"{path} is not in the store and carries no ppd provenance marker"


def gone_from_its_place(ctx: AppContext, row: dict[str, Any]) -> bool:
    """Whether a patched (or pending) row's file, patched in place, is gone from its path: deleted or
    moved by the user. `ppd restore DATASET` does not make it again (a black-box review: it recreated
    culled photos and duplicated renamed ones); a copy in an --out or publish folder is not such a row."""
    return _copy_outside_the_source(ctx, row) is None and not os.path.lexists(row["path"])
