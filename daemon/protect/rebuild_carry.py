"""What `ppd store rebuild` (rebuild.py) carries over from the old store besides its datasets and specs.

rebuild.py's trust model: a row is written for what the files and the vault prove, never for what
the old store merely says. A black-box review found a rebuild dropping two things the walk cannot
find, so every restored file became "not patched yet" (and `ppd poison` patched it again without
--force) and the verification history was gone. They come back only where that holds:

- restored rows (the user's decision to keep an original unpatched): carried when the file at the
  row's path is a regular file whose sha256 is the row's original and the vault holds that original
  intact. The bytes prove it is the original ppd gave back; a row whose file changed is dropped,
  and counted (its file now counts as not patched).
- verification runs of the datasets the new store has, with the old events that date each dataset's
  pixel changes (patched, restored, ...): a verdict stays current, or history, as the old store
  judged it. Carried only when both tables read whole: runs without the events that outdate them
  would claim a verdict the old store no longer held; then they are dropped and counted.

- the originals of the datasets' files' earlier versions (a photo edited and patched again: `ppd
  restore` of a copy published before the edit needs its first original, and `ppd dataset forget`
  finds it by this row): carried when the vault holds it intact and the new store has the dataset.

- patched rows the walk did not find by their seal (sealed with a key no longer installed: after `ppd
  key new` a rebuild emptied a sound store and the originals were out of ppd's reach; a black-box
  review): carried when the file at the row's path (or its publish copy) holds exactly the bytes the
  row records as ppd's output and the vault holds its original intact. The bytes prove it.

It also counts, per dataset, the old store's patched rows the walk did not find again: a dataset
whose files share their originals with another's leaves no unreferenced original behind, so the
summary's vault count said nothing of it (the same review).
"""

from __future__ import annotations

import collections
import contextlib
import os
import sqlite3
import stat
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon.fsops import sha256_fd
from daemon.states import FileState
from daemon.store import Store


@dataclass
class OldHistory:
    """What the old store says beyond its datasets and specs (read-only; see the module's doc)."""

    patched: dict[str, str] = field(default_factory=dict)  # row path -> dataset
    patched_rows: list[dict[str, Any]] = field(default_factory=list)
    restored: list[dict[str, Any]] = field(default_factory=list)
    runs: list[dict[str, Any]] = field(default_factory=list)
    pixel_events: list[dict[str, Any]] = field(default_factory=list)
    history_whole: bool = False  # runs and events both read without an error
    earlier: list[tuple[str, str, float]] = field(default_factory=list)  # earlier_originals rows


def open_read_only(store_path: Path) -> sqlite3.Connection | None:
    """The old store, read-only, or None when there is none to read (what it still gives is read)."""
    if not store_path.is_file():
        return None
    try:
        return sqlite3.connect(f"file:{store_path}?mode=ro", uri=True)
    except sqlite3.Error:
        return None


def read_old_history(store_path: Path) -> OldHistory:
    """The old store's patched and restored rows, verification runs and pixel-change events; damage
    ends a table's reading (what was read of the file rows is kept; runs need both tables whole)."""
    from daemon.store.verification import PIXEL_EVENTS

    old = OldHistory()
    if (conn := open_read_only(store_path)) is None:
        return old
    conn.row_factory = sqlite3.Row
    try:
        with contextlib.suppress(sqlite3.Error):
            for row in conn.execute("SELECT * FROM files WHERE state IN (?, ?)",
                                    (FileState.PATCHED.value, FileState.RESTORED.value)):  # fmt: skip
                if row["state"] == FileState.PATCHED.value:
                    old.patched[str(row["path"])] = str(row["dataset"])
                    old.patched_rows.append(dict(row))
                else:
                    old.restored.append(dict(row))
        with contextlib.suppress(sqlite3.Error):  # none before schema version 8
            query = "SELECT dataset, sha256, replaced_at FROM earlier_originals ORDER BY rowid"
            old.earlier = [(str(d), str(sha), float(t)) for d, sha, t in conn.execute(query)]
        try:
            old.runs = [dict(r) for r in conn.execute("SELECT * FROM verification_runs ORDER BY id")]
            kinds = ", ".join("?" for _ in PIXEL_EVENTS)
            old.pixel_events = [dict(r) for r in conn.execute(
                f"SELECT ts, dataset, path, kind, detail FROM events WHERE kind IN ({kinds}) ORDER BY id",
                PIXEL_EVENTS)]  # fmt: skip
            old.history_whole = True
        except sqlite3.Error:
            old.runs, old.pixel_events = [], []
    finally:
        conn.close()
    return old


@dataclass
class Carried:
    """What the new store gets from the old one, and what it leaves out (for the summary)."""

    restored: list[tuple[str, str, dict[str, Any]]] = field(default_factory=list)  # (path, dataset, fields)
    patched: list[tuple[str, str, dict[str, Any]]] = field(default_factory=list)  # by their recorded bytes
    restored_changed: int = 0  # restored rows whose file no longer holds the original
    runs: list[dict[str, Any]] = field(default_factory=list)
    pixel_events: list[dict[str, Any]] = field(default_factory=list)
    runs_dropped: int = 0  # runs left out: the old history could not be read whole
    not_found: dict[str, int] = field(default_factory=dict)  # dataset -> old patched rows not found again
    earlier: list[tuple[str, str, float]] = field(default_factory=list)  # (dataset, sha256, replaced_at)


def carry_saved_over(old: OldHistory, found: dict[str, tuple[str, dict[str, Any]]],
                     intact: Callable[[str], bool]) -> None:  # fmt: skip
    """A row found again by its seal gets the old row's files.saved_over (the photo from before an edit
    of ppd's patched photo) when the old row is of the same path and original and the vault holds that
    photo intact: a rebuild dropped it, and restore then said only "restored" of a picture that may carry
    ppd's mark (a diff review). found: the rebuild's rows, changed in place."""
    for row in old.patched_rows:
        earlier = row.get("saved_over")
        mine = found.get(str(row["path"]))
        if earlier and mine is not None and mine[1]["original_sha256"] == row.get("original_sha256") \
                and intact(str(earlier)):  # fmt: skip
            mine[1]["saved_over"] = earlier


def carry_over(
    old: OldHistory, found: Collection[str], datasets: Collection[str], intact: Callable[[str], bool],
    specs: Collection[str] = (),
) -> Carried:
    """What to carry into a store whose patched rows are `found` (row paths) and whose datasets are
    `datasets`; intact(sha256): the vault holds that original, verified; specs: the specs it holds."""
    carried = Carried()
    for row in old.patched_rows:
        path, output = str(row["path"]), str(row.get("poisoned_sha256") or "")
        if path in found or row["dataset"] not in datasets or row.get("spec_id") not in specs or not output:
            continue
        st = _holds(Path(row.get("published_path") or path), output)
        if st is not None and intact(str(row.get("original_sha256") or "")):
            fields = {k: row.get(k) for k in ("original_sha256", "poisoned_sha256", "original_mtime_ns",
                                              "spec_id", "tool_version", "published_path",
                                              "resaved", "saved_over")}  # fmt: skip
            carried.patched.append((path, str(row["dataset"]), {**fields, "size": st.st_size,
                                                                "mtime_ns": st.st_mtime_ns}))  # fmt: skip
    for row in old.restored:
        path, original = str(row["path"]), str(row.get("original_sha256") or "")
        if path in found or row["dataset"] not in datasets:
            continue
        st = _holds(Path(path), original)
        if st is None or not intact(original):
            carried.restored_changed += 1
            continue
        fields = {"original_sha256": original, "original_mtime_ns": row.get("original_mtime_ns"),
                  "spec_id": row.get("spec_id"), "tool_version": row.get("tool_version"),
                  "size": st.st_size, "mtime_ns": st.st_mtime_ns}  # fmt: skip
        carried.restored.append((path, str(row["dataset"]), fields))
    kept = set(found) | {path for path, _, _ in carried.restored} | {path for path, _, _ in carried.patched}
    missing = collections.Counter(d for path, d in old.patched.items() if path not in kept)
    carried.not_found = dict(sorted(missing.items()))
    if old.history_whole:
        carried.runs = [r for r in old.runs if r["dataset"] in datasets]
        carried.pixel_events = [e for e in old.pixel_events if e["dataset"] in datasets]
    carried.runs_dropped = len(old.runs) - len(carried.runs)
    carried.earlier = [(d, sha, t) for d, sha, t in old.earlier if d in datasets and intact(sha)]
    return carried


def _holds(path: Path, sha256: str) -> os.stat_result | None:
    """path's stat when it is a regular file (not followed through a symlink) whose bytes hash to
    sha256; None otherwise."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        return st if stat.S_ISREG(st.st_mode) and sha256_fd(fd) == sha256 else None
    except OSError:
        return None
    finally:
        os.close(fd)


def write_carried(store: Store, carried: Carried) -> None:
    """The carried rows into the new store (inside the rebuild, before the swap)."""
    store.record_files((path, name, FileState.RESTORED, fields) for path, name, fields in carried.restored)
    store.record_files((path, name, FileState.PATCHED, fields) for path, name, fields in carried.patched)
    store.carry_history(carried.runs, carried.pixel_events)
    store.carry_earlier_originals(carried.earlier)


def summary_notes(carried: Carried) -> Iterable[str]:
    """The summary's notes on what was carried over and what was left out."""
    if carried.restored:
        yield f"{len(carried.restored)} file(s) you restored kept as restored"
    if carried.patched:
        yield (f"{len(carried.patched)} patched file(s) kept by their recorded bytes (their seal is "
               "not this key's: `ppd key import` the one they were patched with, if you have it)")
    if carried.restored_changed:
        yield (f"{carried.restored_changed} restored file(s) no longer hold their original: "
               "they count as not patched")  # fmt: skip
    if carried.runs:
        yield f"{len(carried.runs)} verification run(s) carried over"
    if carried.runs_dropped:
        yield (f"{carried.runs_dropped} verification run(s) dropped (the old store's history could not be "
               "read whole, or names a dataset no longer there)")  # fmt: skip
    if carried.not_found:
        total = sum(carried.not_found.values())
        names = ", ".join(f"{name} ({n})" for name, n in carried.not_found.items())
        yield (f"{total} file(s) the old store listed as patched not found again, in dataset(s) {names} "
               "(moved, deleted or edited since, or in a folder not walked: `ppd store rebuild --force "
               "FOLDER ...`)")  # fmt: skip
