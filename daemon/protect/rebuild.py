"""`ppd store rebuild`: a new store from the vault and the provenance markers in patched files.

Every file ppd patches carries a seal in its own metadata (poisoner.provenance: the spec id and
the original's sha256, encrypted, and a tag over the file's bytes, keyed with this installation's
secret, daemon.store.sealkey). A lost or damaged store is rebuilt by walking the folders where patched
files live (the outbox, the publish folders, the dataset roots the old store still names, and any
folder given), without following symlinks, and recording a `patched` row for each file whose seal
verifies (the key and the bytes) and whose original the vault holds, verified by hash. A copied
seal in another photo, or a patched photo edited since, does not verify and gets no row. Each
dataset gets back its spec from `vault/specs/<spec_id>.json` (Vault.keep_spec), the old store, or
the config when the ids match. Restored rows whose file still holds the original and the verification
history come over from the old store where they can be trusted (rebuild_carry.py).

The old store is never deleted: its files (with -wal/-shm) are renamed to
`<name>.before-rebuild-<UTC time>`. The new store is built under a temporary name and renamed
into place, so a crash mid-rebuild leaves the old store (or its kept-aside copy) and no half
store. Stop `ppd watch` first: a daemon still holding the old store would keep writing to it. Any
other ppd command holds the store lock while it runs, and a rebuild waits for none (daemon.locks).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import sqlite3
import stat
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon.config import Config
from daemon.datasets.dataset import DEFAULT_DATASET, dataset_of, dataset_root
from daemon.fsops import sha256_fd
from daemon.locks import LockHeld, store_alone, watch_running, watching
from daemon.paths import AppPaths
from daemon.platform import fd_path
from daemon.protect import rebuild_carry, rebuild_specs
from daemon.states import FileState
from daemon.store import SQLITE_SUFFIXES, Store, StoreError, StoreTooNew
from daemon.store.sealkey import load_key
from daemon.store.vault import Vault, VaultError
from poisoner.atomic import fsync_dir
from poisoner.errors import ExitStatus
from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

ASIDE_INFIX = ".before-rebuild-"
HEX = frozenset("0123456789abcdef")

MarkerReader = Callable[[Path], Any]  # path -> poisoner.provenance.Seal | None (verified)


class RebuildRefused(StoreError):
    """The store is sound and holds rows; rebuilding it needs force (bad input: exit 2)."""

    exit_status = ExitStatus.USAGE


class RebuildBlocked(RebuildRefused):
    """A daemon is running on this data folder (cannot work here: exit 3)."""

    exit_status = ExitStatus.ENVIRONMENT


@dataclass
class RebuildReport:
    store_path: Path
    before: str = "missing"  # missing | damaged | newer | lost | empty | sound: what the store was
    kept_aside: list[Path] = field(default_factory=list)  # the old store's files, renamed
    folders: list[Path] = field(default_factory=list)  # walked
    files_seen: int = 0  # regular files looked at
    marked: int = 0  # of them, carrying ppd's marker
    recorded: int = 0  # patched rows written
    datasets: dict[str, int] = field(default_factory=dict)  # the new store's datasets: patched rows each
    without_original: list[Path] = field(default_factory=list)  # marked, original not (intact) in the vault
    conflicts: list[Path] = field(default_factory=list)  # a second file for a path already recorded
    symlinks_skipped: int = 0
    specs: dict[str, str] = field(default_factory=dict)  # spec id -> where it was recovered from
    specs_missing: list[str] = field(default_factory=list)
    spec_lost: dict[str, str] = field(default_factory=dict)  # dataset -> its files' spec id, found nowhere
    old_datasets: int = 0  # dataset rows read back from the old store
    unreferenced_originals: int = 0  # vault originals no rebuilt row names
    carried: rebuild_carry.Carried = field(default_factory=rebuild_carry.Carried)  # from the old store

    def summary(self) -> str:
        """One line."""
        text = (
            f"store rebuilt at {self.store_path}: {sum(self.datasets.values())} patched file(s) in "
            f"{len(self.datasets)} "
            f"dataset(s) from {self.marked} marked file(s) of {self.files_seen} looked at"
        )
        notes = []
        if self.without_original:
            notes.append(f"{len(self.without_original)} marked without their original in the vault")
        if self.specs_missing:
            lost = f": dataset(s) {', '.join(sorted(self.spec_lost))}" if self.spec_lost else ""
            notes.append(f"{len(self.specs_missing)} spec(s) not recovered{lost}")
        if self.conflicts:
            notes.append(f"{len(self.conflicts)} duplicate(s) skipped")
        notes.extend(rebuild_carry.summary_notes(self.carried))
        if self.unreferenced_originals:  # photos patched in folders it did not walk (a black-box review:
            # "0 patched file(s)" and nothing said of how to find them)
            notes.append(f"{self.unreferenced_originals} vault original(s) no file names: give the "
                         "folders patched outside the outbox, `ppd store rebuild FOLDER ...`, or, if the "
                         "seal key was lost or replaced since, `ppd key import` the one they were "
                         "patched with first; a `ppd poison` stopped mid-file leaves its files unpatched "
                         "and their originals here too: `ppd poison FOLDER` finishes it")  # fmt: skip
        if notes:
            text += f" ({'; '.join(notes)})"
        if self.kept_aside:
            text += f"; the {self.before} store is kept at {self.kept_aside[0]}"
        return text


@dataclass(frozen=True)
class _Source:
    """A folder to walk and how its files map to store rows."""

    folder: Path
    dataset: str | None  # None: by the outbox layout (dataset_of)
    identity_root: Path | None = None  # publish folder: row path = identity_root / rel
    published: bool = False
    inner: frozenset[str] = frozenset()  # other datasets' roots inside this one (real paths): theirs


@dataclass
class _OldStore:
    datasets: dict[str, dict[str, Any]] = field(default_factory=dict)
    specs: dict[str, str] = field(default_factory=dict)  # id -> json


def rebuild_store(
    paths: AppPaths,
    store_path: Path | None = None,
    *,
    config: Config | None = None,
    folders: Sequence[Path] = (),
    force: bool = False,
    read_marker: MarkerReader | None = None,
) -> RebuildReport:
    """Rebuild the store at store_path (default paths.db_path) from the vault and the markers.

    folders: more folders holding patched files (`ppd poison FOLDER` in place), each one dataset
    named after the folder. A sound store with rows is refused (RebuildRefused) unless force.

    The steps, in order: judge the old store (refuse a sound one), read what it still gives back,
    collect a row for each marked file whose original the vault holds, recover the specs, write
    the new store beside the old one and swap them."""
    if read_marker is None:
        read_marker = _seal_reader(paths)
    store_path = Path(store_path or paths.db_path)
    config = config or Config()
    report = RebuildReport(store_path=store_path)

    if holders := watching(paths.data_dir):  # a daemon would go on writing to the store swapped out
        raise RebuildBlocked(watch_running(holders[0], "rebuild"))
    with contextlib.ExitStack() as held:
        try:  # a `ppd restore` or `ppd poison` committing between the reading and the swap was lost
            held.enter_context(store_alone(paths.data_dir))
        except LockHeld as exc:
            raise RebuildBlocked(str(exc)) from None
        _rebuild(paths, store_path, config, folders, force, read_marker, report)
    log.info(report.summary())
    return report


def _rebuild(
    paths: AppPaths, store_path: Path, config: Config, folders: Sequence[Path], force: bool,
    read_marker: MarkerReader, report: RebuildReport,
) -> None:  # fmt: skip
    """rebuild_store's steps, under the store lock."""
    report.before = _store_condition(store_path, paths.vault_dir, force)
    old = _read_old_store(store_path) if report.before != "missing" else _OldStore()
    history = rebuild_carry.read_old_history(store_path)
    report.old_datasets = len(old.datasets)
    vault = Vault(paths.vault_dir)
    collector = _RowCollector(paths, old, vault, report)
    found = _collect_rows(paths, _sources(paths, config, old, folders), collector, read_marker, report)
    by_dataset: dict[str, list[str]] = collections.defaultdict(list)
    for dataset, fields in found.rows.values():
        by_dataset[dataset].append(fields["spec_id"])
    chosen = _dataset_spec_ids(by_dataset, old)
    stored = [("old store", old.specs), *_kept_aside_specs(store_path)]
    wanted = {s for ids in by_dataset.values() for s in ids} | {s for s in chosen.values() if s}
    specs, report.specs, report.specs_missing = rebuild_specs.recover_specs(vault, wanted, config, stored)
    names = set(chosen)  # the new store's datasets (_fill_new_store)
    report.carried = rebuild_carry.carry_over(history, found.rows.keys(), names, collector.is_intact, specs)
    rebuild_carry.carry_saved_over(history, found.rows, collector.is_intact)
    _write_new_store(store_path, found, by_dataset, chosen, specs, old, report)
    report.recorded = len(found.rows)
    report.datasets = _patched_per_dataset(names, by_dataset, report.carried)
    # a dataset with patched files and no spec refuses new photos (Store.lost_spec): named, exit 1
    report.spec_lost = {n: s for n, s in chosen.items() if s and s not in specs and report.datasets.get(n)}
    referenced = {fields["original_sha256"] for _, fields in found.rows.values()}
    carried = [*report.carried.restored, *report.carried.patched]
    referenced |= {fields["original_sha256"] for _, _, fields in carried}
    referenced |= {sha for _, sha, _ in report.carried.earlier}
    report.unreferenced_originals = len(set(vault.blobs()) - referenced)


def _patched_per_dataset(
    names: set[str], by_dataset: dict[str, list[str]], carried: rebuild_carry.Carried
) -> dict[str, int]:
    """Every dataset of the new store and its patched rows, found by their seal or carried by their
    bytes: the summary said "0 dataset(s)" above a table listing one (a restored dataset, or one
    patched with a key no longer installed; a black-box review)."""
    counts = {name: len(by_dataset.get(name, ())) for name in sorted(names)}
    for _, name, _ in carried.patched:
        counts[name] += 1
    return counts


@dataclass
class _Found:
    """The rows a rebuild will write, and where each dataset lives."""

    rows: dict[str, tuple[str, dict[str, Any]]] = field(default_factory=dict)  # row path -> (dataset, fields)
    roots: dict[str, Path] = field(default_factory=dict)
    publish_dirs: dict[str, Path] = field(default_factory=dict)


def _collect_rows(
    paths: AppPaths, sources: list[_Source], collector: _RowCollector, read_marker: MarkerReader,
    report: RebuildReport,
) -> _Found:  # fmt: skip
    """Walk the sources in order (an earlier source's row wins a conflict) and keep a patched row
    for every marked file whose original is intact in the vault."""
    skip_dirs = {os.path.realpath(p) for p in (paths.vault_dir, paths.data_dir)}
    seen_inodes: set[tuple[int, int]] = set()
    for source in sources:
        if not source.folder.is_dir():
            continue
        report.folders.append(source.folder)
        for path in _walk(source.folder, skip_dirs | source.inner, report):
            looked = _marked_file(path, read_marker, seen_inodes)
            if looked is None:
                continue
            report.files_seen += looked[0]
            if looked[1] is not None:
                report.marked += 1
                collector.keep(source, path, *looked[1])
    return collector.found


@dataclass
class _RowCollector:
    paths: AppPaths
    old: _OldStore
    vault: Vault
    report: RebuildReport
    found: _Found = field(default_factory=_Found)
    intact: dict[str, bool] = field(default_factory=dict)  # original sha256 -> intact in the vault

    def is_intact(self, original: str) -> bool:
        """Whether the vault holds this original, verified by hash (once per original)."""
        if original not in self.intact:
            self.intact[original] = _original_intact(self.vault, original)
        return self.intact[original]

    def keep(self, source: _Source, path: Path, marker: Any, sha: str, st: os.stat_result) -> None:
        """One marked file's row, unless its original is not intact or its path is taken."""
        original = str(marker.original_sha256)
        if not self.is_intact(original):
            self.report.without_original.append(path)
            return
        dataset, identity = _identity(source, self.paths.outbox.absolute(), path)
        if str(identity) in self.found.rows:
            self.report.conflicts.append(path)
            return
        self.found.rows[str(identity)] = (dataset, {
            "original_sha256": original, "poisoned_sha256": sha, "spec_id": str(marker.spec_id),
            "tool_version": getattr(marker, "tool", None), "size": st.st_size, "mtime_ns": st.st_mtime_ns,
            "error": None, "published_path": str(path) if source.published else None,
        })  # fmt: skip
        self.found.roots.setdefault(dataset, _root_of(source, dataset, self.paths.outbox, self.old))
        if source.published:
            self.found.publish_dirs.setdefault(dataset, source.folder)


def _seal_reader(paths: AppPaths) -> MarkerReader:
    """read_seal with this installation's key; without a key no file can be recognised."""
    from poisoner.provenance import read_seal

    key = load_key(paths.data_dir, create=False)
    if key is None:
        log.warning("no seal key in %s: no patched file can be recognised", paths.data_dir)
    return lambda path: read_seal(path, key)


# ---- the old store -----------------------------------------------------------------------------------
def _store_condition(store_path: Path, vault_dir: Path, force: bool) -> str:
    if not any(Path(f"{store_path}{s}").exists() for s in SQLITE_SUFFIXES):
        return "missing"
    try:
        store = Store(store_path)
    except StoreTooNew as exc:  # not damaged: a rebuild would drop what it cannot recover (a review)
        if not force:
            raise RebuildBlocked(
                f"{exc}; `ppd store rebuild` leaves a newer store alone: `--force` replaces it all the same "
                "(kept aside; its history, failed and skipped files are not rebuilt)"
            ) from None
        return "newer"
    except StoreError:
        return "damaged"
    try:
        if store.lost_note():
            return "lost"
        count = store.file_count()
    except StoreError:
        return "damaged"
    finally:
        store.close()
    if count == 0:
        return "empty"
    if not force:
        raise RebuildRefused(
            f"the store {store_path} is sound and holds {count} file row(s); "
            "`ppd store rebuild --force` replaces it (the current one is kept aside)"
        )
    return "sound"


def stored_datasets(store_path: Path) -> dict[str, dict[str, Any]]:
    """The store's datasets (root, spec_id, publish_dir), read-only, whatever state it is in (none
    yet, damaged: what can be read): for a command that must not make or lock the store."""
    return _read_old_store(store_path).datasets


def _read_old_store(store_path: Path) -> _OldStore:
    """Whatever the old store still gives back of its datasets and specs (read-only; any damage
    simply ends the reading)."""
    old = _OldStore()
    if (conn := rebuild_carry.open_read_only(store_path)) is None:
        return old
    try:
        with contextlib.suppress(sqlite3.Error):
            for spec_id, text in conn.execute("SELECT id, json FROM specs"):
                old.specs[str(spec_id)] = str(text)
        with contextlib.suppress(sqlite3.Error):
            for name, root, spec_id, publish_dir in conn.execute(
                "SELECT name, root, spec_id, publish_dir FROM datasets"
            ):
                old.datasets[str(name)] = {"root": root, "spec_id": spec_id, "publish_dir": publish_dir}
    finally:
        conn.close()
    return old


# ---- walking ---------------------------------------------------------------------------------------
def _sources(paths: AppPaths, config: Config, old: _OldStore, folders: Sequence[Path]) -> list[_Source]:
    """The outbox first (its rows win a conflict), then publish folders, old roots, given folders."""
    outbox = paths.outbox.absolute()
    sources = [_Source(outbox, None)]
    publish: dict[str, Path] = {}
    names = set(old.datasets) | set(config.datasets)
    if config.publish_dir is not None and config.publish_dir.is_dir():
        names |= {p.name for p in config.publish_dir.iterdir() if p.is_dir() and not p.is_symlink()}
    for name in sorted(names):
        stored = old.datasets.get(name, {}).get("publish_dir")
        target = Path(stored) if stored else config.publish_dir_for(name)
        if target is not None:
            publish[name] = target.absolute()
    for name, folder in sorted(publish.items()):
        root = old.datasets.get(name, {}).get("root")
        sources.append(_Source(folder, name, Path(root) if root else dataset_root(outbox, name), True))
    roots = {name: Path(info["root"]).absolute() for name, info in old.datasets.items() if info.get("root")}
    for name, root in sorted(roots.items()):
        if root != outbox and not root.is_relative_to(outbox):
            # a dataset patched inside another's folder (`ppd poison album/zoo --dataset zoo`) keeps
            # its files: the outer walk leaves its folder to its own source
            inside = [r for r in roots.values() if r != root and r.is_relative_to(root)]
            inner = frozenset(os.path.realpath(r) for r in inside)
            sources.append(_Source(root, name, inner=inner))
    taken = dict(roots)  # name -> root: a given folder is its own dataset, never merged into another
    for folder in folders:
        folder = Path(folder).expanduser().absolute()
        name = _free_name(folder.name or DEFAULT_DATASET, folder, taken)
        taken[name] = folder
        sources.append(_Source(folder, name))
    return sources


def _free_name(name: str, folder: Path, taken: dict[str, Path]) -> str:
    """name, or name-2, name-3...: the first not taken by another folder. A backup copy `bk/castle`
    rebuilt beside `sh/castle` became dataset castle's files outside its folder, which `ppd restore
    castle` then deleted as --out copies (a second black-box review)."""
    candidate, n = name, 1
    while candidate in taken and taken[candidate] != folder:
        n += 1
        candidate = f"{name}-{n}"
    return candidate


def _walk(top: Path, skip_dirs: set[str], report: RebuildReport) -> Iterator[Path]:
    """Regular, non-hidden files under top; symlinks (files and folders) are counted, not followed."""
    for folder, dirs, files in os.walk(top, followlinks=False):
        keep = []
        for name in dirs:
            full = os.path.join(folder, name)
            if os.path.islink(full):
                report.symlinks_skipped += 1
            elif not name.startswith(".") and os.path.realpath(full) not in skip_dirs:
                keep.append(name)
        dirs[:] = sorted(keep)
        for name in sorted(files):
            if name.startswith("."):  # dot-files and ppd's own .ppd-tmp-* leftovers
                continue
            path = Path(folder, name)
            if os.path.islink(path):
                report.symlinks_skipped += 1
                continue
            yield path


def _marked_file(
    path: Path, read_marker: MarkerReader, seen: set[tuple[int, int]]
) -> tuple[int, tuple[Any, str, os.stat_result] | None] | None:
    """(1, (marker, sha256, stat)) for a marked regular file, (1, None) for an unmarked one, None
    for something not looked at (vanished, not regular, already seen through another folder).

    The file is opened once with O_NOFOLLOW and read through that descriptor only (the marker via
    /proc/self/fd), so a file swapped for a symlink meanwhile is not followed."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or (st.st_dev, st.st_ino) in seen:
            return None
        seen.add((st.st_dev, st.st_ino))
        by_fd = fd_path(fd)
        marker = read_marker(by_fd if by_fd.exists() else path)
        if marker is None:
            return 1, None
        return 1, (marker, sha256_fd(fd), st)
    finally:
        os.close(fd)


def _original_intact(vault: Vault, sha256: str) -> bool:
    if len(sha256) != 64 or not set(sha256) <= HEX:
        return False
    try:
        return vault.verify(sha256)
    except (OSError, VaultError):
        return False


def _identity(source: _Source, outbox: Path, path: Path) -> tuple[str, Path]:
    """(dataset, the row's path) of a file found under source."""
    if source.dataset is None:
        return dataset_of(outbox, path), path
    if source.published and source.identity_root is not None:
        return source.dataset, source.identity_root / path.relative_to(source.folder)
    return source.dataset, path


def _root_of(source: _Source, dataset: str, outbox: Path, old: _OldStore) -> Path:
    stored = old.datasets.get(dataset, {}).get("root")
    if stored:
        return Path(stored)
    if source.dataset is None or source.published:
        return dataset_root(outbox, dataset)
    return source.folder


# ---- specs and the new store ---------------------------------------------------------------------
def _dataset_spec_ids(by_dataset: dict[str, list[str]], old: _OldStore) -> dict[str, str | None]:
    """Each dataset of the new store and the id of its spec: its markers' most common one, else the
    old store's."""
    chosen: dict[str, str | None] = {}
    for name in sorted(set(by_dataset) | set(old.datasets)):
        ids = by_dataset.get(name, [])
        most = collections.Counter(ids).most_common(1)
        chosen[name] = most[0][0] if most else old.datasets[name].get("spec_id")
    return chosen


def _kept_aside_specs(store_path: Path) -> list[tuple[str, dict[str, str]]]:
    """The specs of the stores earlier rebuilds kept aside, the newest first: one rebuilt before ppd
    kept specs in the vault lost them, and the store it replaced may hold them."""
    asides = [p for p in store_path.parent.glob(f"{store_path.name}{ASIDE_INFIX}*")
              if not p.name.endswith(("-wal", "-shm"))]  # fmt: skip
    return [("a store kept aside", _read_old_store(p).specs) for p in sorted(asides, reverse=True)]


def _write_new_store(
    store_path: Path,
    found: _Found,
    by_dataset: dict[str, list[str]],
    chosen: dict[str, str | None],
    specs: dict[str, PatchSpec],
    old: _OldStore,
    report: RebuildReport,
) -> None:
    """Build the new store under a temporary name, keep the old one aside, rename the new one in."""
    tmp = store_path.with_name(f".{store_path.name}.rebuilding-{os.getpid()}")
    for suffix in SQLITE_SUFFIXES:
        Path(f"{tmp}{suffix}").unlink(missing_ok=True)
    store = Store(tmp)
    try:
        _fill_new_store(store, store_path, found, by_dataset, chosen, specs, old)
        rebuild_carry.write_carried(store, report.carried)
        store.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        store.conn.execute("PRAGMA journal_mode = DELETE")  # one self-contained file to rename
    finally:
        store.close()
    _keep_aside(store_path, report)
    os.replace(tmp, store_path)
    fsync_dir(store_path.parent)
    check = Store(store_path)  # reopen: WAL mode, permissions, and a proof it opens
    check.close()


def _fill_new_store(
    store: Store,
    store_path: Path,
    found: _Found,
    by_dataset: dict[str, list[str]],
    chosen: dict[str, str | None],
    specs: dict[str, PatchSpec],
    old: _OldStore,
) -> None:
    """Datasets (each with its spec, _dataset_spec_ids: none when not recovered), every recovered spec,
    the file rows."""
    for name, spec_id in chosen.items():
        ids = by_dataset.get(name, [])
        info = old.datasets.get(name, {})
        publish = info.get("publish_dir") or found.publish_dirs.get(name)
        root = Path(info.get("root") or found.roots.get(name) or store_path.parent)
        store.add_dataset(
            name, root, specs.get(spec_id or ""), Path(publish) if publish else None, event="rebuilt",
            detail={"files": len(ids), "spec_id_from_markers": spec_id},
        )  # fmt: skip
    for spec in specs.values():
        store.ensure_spec(spec)  # a file's own spec (a dataset mid re-protect) resolves too
    store.record_files(
        (path, dataset, FileState.PATCHED, fields) for path, (dataset, fields) in found.rows.items()
    )


def _keep_aside(store_path: Path, report: RebuildReport) -> None:
    """Rename the old store's files (with -wal/-shm) to `<name>.before-rebuild-<UTC time>`."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    aside = store_path.with_name(f"{store_path.name}{ASIDE_INFIX}{stamp}")
    n = 1
    while any(Path(f"{aside}{s}").exists() for s in SQLITE_SUFFIXES):
        n += 1
        aside = store_path.with_name(f"{store_path.name}{ASIDE_INFIX}{stamp}-{n}")
    for suffix in SQLITE_SUFFIXES:
        current = Path(f"{store_path}{suffix}")
        if current.exists():
            os.replace(current, Path(f"{aside}{suffix}"))
            report.kept_aside.append(Path(f"{aside}{suffix}"))
