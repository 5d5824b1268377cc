"""Specs and datasets: every dataset has one PatchSpec (same patch, same place, every image),
stored once by its content hash."""

from __future__ import annotations

import json
import os
import re
import shlex
import sqlite3
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from daemon.states import FileState
from daemon.store.connection import StoreBase
from daemon.store.errors import DatasetSpecLocked, SpecNotRecovered, StoreError
from daemon.store.event_log import insert_event
from poisoner.spec import PatchSpec

# store_notes key of a forgotten dataset whose originals are still to leave the vault (+ its name)
FORGET_NOTE = "forgetting:"


def insert_spec(conn: sqlite3.Connection, spec: PatchSpec) -> str:
    """Store the spec inside the caller's transaction (once: the id is its content hash)."""
    conn.execute(
        "INSERT OR IGNORE INTO specs (id, json, version, created_at) VALUES (?, ?, ?, ?)",
        (spec.spec_id, spec.to_json(), spec.version, time.time()),
    )
    return spec.spec_id


def _insert_dataset(
    conn: sqlite3.Connection, name: str, root: Path, spec_id: str | None, publish_dir: Path | None
) -> None:
    conn.execute(
        "INSERT INTO datasets (name, root, spec_id, created_at, publish_dir) VALUES (?, ?, ?, ?, ?)",
        (name, str(root), spec_id, time.time(), str(publish_dir) if publish_dir else None),
    )


class DatasetRows(StoreBase):
    # ---- specs ----------------------------------------------------------------------------
    def ensure_spec(self, spec: PatchSpec) -> str:
        with self._write() as conn:
            return insert_spec(conn, spec)

    def get_spec(self, spec_id: str) -> PatchSpec:
        row = self._one("SELECT json FROM specs WHERE id = ?", (spec_id,))
        if row is None:
            raise StoreError(f"no spec {spec_id} in the store")
        return PatchSpec.from_json(row["json"])

    # ---- datasets -------------------------------------------------------------------------
    def ensure_dataset(
        self, name: str, root: Path, spec: PatchSpec, publish_dir: Path | None = None
    ) -> tuple[dict[str, Any], PatchSpec]:
        """The dataset's row and its one spec, creating both if this is its first file.

        Thread-safe: concurrent first files of a new dataset all get the same spec (the first
        writer's), because the insert-or-read runs under SQLite's write lock.
        """
        known = self._one("SELECT spec_id FROM datasets WHERE name = ?", (name,))
        if known is not None and known["spec_id"] is not None:  # every file but a dataset's first: no write
            return self._dataset_and_spec(name)
        with self._write() as conn:
            row = conn.execute("SELECT spec_id FROM datasets WHERE name = ?", (name,)).fetchone()
            if row is None:
                insert_spec(conn, spec)
                _insert_dataset(conn, name, root, spec.spec_id, publish_dir)
                insert_event(
                    conn, name, None, "dataset_created", {"root": str(root), "spec_id": spec.spec_id}
                )
            elif row[0] is None:
                spec_id = _spec_for_unset(conn, name, spec)
                if spec_id == spec.spec_id:
                    insert_spec(conn, spec)
                conn.execute("UPDATE datasets SET spec_id = ? WHERE name = ?", (spec_id, name))
        return self._dataset_and_spec(name)

    def _dataset_and_spec(self, name: str) -> tuple[dict[str, Any], PatchSpec]:
        dataset = self.dataset(name)
        assert dataset is not None
        return dataset, self.get_spec(dataset["spec_id"])

    def add_dataset(
        self,
        name: str,
        root: Path,
        spec: PatchSpec | None,
        publish_dir: Path | None = None,
        *,
        event: str = "dataset_created",
        detail: dict[str, Any] | None = None,
    ) -> bool:
        """Insert a dataset row as it is known (a rebuild may not know its spec: spec None leaves
        spec_id empty). An existing dataset is left as it is; returns whether one was added."""
        with self._write() as conn:
            if conn.execute("SELECT 1 FROM datasets WHERE name = ?", (name,)).fetchone():
                return False
            spec_id = insert_spec(conn, spec) if spec is not None else None
            _insert_dataset(conn, name, root, spec_id, publish_dir)
            insert_event(conn, name, None, event, {"root": str(root), "spec_id": spec_id, **(detail or {})})
        return True

    def dataset(self, name: str) -> dict[str, Any] | None:
        return self._one("SELECT * FROM datasets WHERE name = ?", (name,))

    def datasets(self) -> list[dict[str, Any]]:
        """Every dataset, in natural order: set 2 before set 10 (text order put set 10-19 first)."""
        return sorted(self._rows("SELECT * FROM datasets"), key=lambda row: natural_key(row["name"]))

    def lost_spec(self, name: str) -> str | None:
        """The id of the spec the dataset's patched files carry when the dataset has none and the store
        does not hold it (see _lost_spec_id); None otherwise."""
        with self._damage_as_store_error():
            lost = _lost_spec_id(self.conn, name)
            return lost if lost is not None and not _spec_held(self.conn, lost) else None

    def check_file_spec(self, name: str, spec: PatchSpec) -> None:
        """SpecNotRecovered when a file of the dataset would be refused spec (ensure_dataset; a dry run
        asks, writing nothing)."""
        with self._damage_as_store_error():
            if (row := self.dataset(name)) is not None and row["spec_id"] is None:
                _spec_for_unset(self.conn, name, spec)

    def dataset_spec(self, name: str) -> PatchSpec | None:
        row = self.dataset(name)
        return self.get_spec(row["spec_id"]) if row and row["spec_id"] else None

    def set_dataset_spec(
        self, name: str, spec: PatchSpec, *, root: Path | None = None, allow_protected: bool = False
    ) -> None:
        """Give a dataset a spec. Before any file is patched this is free; afterwards its
        patched files would carry a different patch than new ones, which breaks the method
        (same patch, same place, every image), so it needs allow_protected (the re-protect path)."""
        with self._write() as conn:
            row = conn.execute("SELECT spec_id FROM datasets WHERE name = ?", (name,)).fetchone()
            insert_spec(conn, spec)
            if row is None:
                if root is None:
                    raise StoreError(f"no dataset {name!r}; give its root folder")
                conn.execute(
                    "INSERT INTO datasets (name, root, spec_id, created_at) VALUES (?, ?, ?, ?)",
                    (name, str(root), spec.spec_id, time.time()),
                )
            elif row[0] != spec.spec_id:
                if not allow_protected:
                    _refuse_if_patched(conn, name, row[0], spec.spec_id)
                conn.execute("UPDATE datasets SET spec_id = ? WHERE name = ?", (spec.spec_id, name))
            insert_event(
                conn, name, None, "spec_set", {"spec_id": spec.spec_id, "previous": row[0] if row else None}
            )

    def check_spec_change(self, name: str, spec: PatchSpec) -> None:
        """DatasetSpecLocked when set_dataset_spec(name, spec) would be refused (a dry run asks)."""
        with self._write() as conn:
            row = conn.execute("SELECT spec_id FROM datasets WHERE name = ?", (name,)).fetchone()
            if row is not None and row[0] != spec.spec_id:
                _refuse_if_patched(conn, name, row[0], spec.spec_id)

    def set_dataset_masks(self, name: str, folder: Path | None) -> None:
        """Remember a dataset's subject-mask folder (None: forget it); an event says so when it changes."""
        value = str(folder) if folder is not None else None
        with self._write() as conn:
            row = conn.execute("SELECT subject_masks FROM datasets WHERE name = ?", (name,)).fetchone()
            if row is None or row[0] == value:
                return
            conn.execute("UPDATE datasets SET subject_masks = ? WHERE name = ?", (value, name))
            insert_event(conn, name, None, "subject_masks", {"folder": value, "was": row[0]})

    def dataset_masks(self, name: str) -> Path | None:
        """The subject-mask folder remembered for a dataset, or None."""
        row = self.dataset(name)
        return Path(row["subject_masks"]) if row and row.get("subject_masks") else None

    def move_dataset(self, name: str, old_root: Path, new_root: Path) -> int | None:
        """The dataset's folder moved from old_root to new_root (its whole tree, by the user): the
        dataset's root and its rows below old_root follow it, in one transaction, so they stay inside
        its root (a row outside it reads as an --out copy). A row whose new path another row holds
        stays. A removed row whose file is at its new path as ppd wrote it (size and time) is patched
        again: a running `ppd watch` saw the folder leave (the outbox moved) and recorded its files
        removed. Returns the rows moved; None, nothing done, unless the stored root is still old_root
        (another process moved it first)."""
        old, new = str(old_root), str(new_root)
        below = old.rstrip("/") + "/"
        moved = back = 0
        with self._write() as conn:
            done = conn.execute("UPDATE datasets SET root = ? WHERE name = ? AND root = ?", (new, name, old))
            if done.rowcount != 1:
                return None
            rows = conn.execute(
                "SELECT id, path, state, size, mtime_ns, published_path FROM files "
                "WHERE dataset = ? AND path >= ? AND path < ?",
                (name, below, below[:-1] + "0"),
            ).fetchall()
            for row_id, path, state, size, mtime_ns, published in rows:
                to = str(Path(new) / Path(path).relative_to(old))
                if conn.execute("SELECT 1 FROM files WHERE path = ?", (to,)).fetchone() is not None:
                    continue
                again = state == FileState.REMOVED and not published and _wrote(to, size, mtime_ns)
                state = FileState.PATCHED.value if again else state
                conn.execute("UPDATE files SET path = ?, state = ? WHERE id = ?", (to, state, row_id))
                moved, back = moved + 1, back + again
            detail = {"from": old, "to": new, "rows": moved, "patched_again": back}
            insert_event(conn, name, None, "dataset_moved", detail)
        return moved

    # ---- forgetting (daemon.protect.forgetting) ---------------------------------------------
    def forget_dataset(self, name: str) -> int:
        """Remove the dataset and all the store holds of it, in one transaction: its row, its file rows
        (every state), its verification runs, automatic mode's decisions and events (a later dataset of
        the same name starts clean: no verdict history, no pixel-change date), and its specs where no
        other row uses them. The originals its rows named are noted (FORGET_NOTE) for the vault step,
        which comes after: a crash between them leaves unreferenced originals, never a row without its
        original. Returns the file rows removed; StoreError when there is no such dataset."""
        with self._write() as conn:
            row = conn.execute("SELECT spec_id FROM datasets WHERE name = ?", (name,)).fetchone()
            if row is None:
                raise StoreError(f"no dataset {name!r}")
            originals = sorted(o for (o,) in conn.execute(
                "SELECT original_sha256 FROM files WHERE dataset = ? AND original_sha256 NOT NULL "
                "UNION SELECT sha256 FROM earlier_originals WHERE dataset = ?", (name, name)))  # fmt: skip
            specs = {row[0]} | {s for (s,) in conn.execute(
                "SELECT spec_id FROM files WHERE dataset = ? UNION SELECT spec_id FROM auto_decisions "
                "WHERE dataset = ?", (name, name))}  # fmt: skip
            rows = conn.execute("DELETE FROM files WHERE dataset = ?", (name,)).rowcount
            for table in ("verification_runs", "auto_decisions", "events", "earlier_originals"):  # literals
                conn.execute(f"DELETE FROM {table} WHERE dataset = ?", (name,))
            conn.execute("DELETE FROM datasets WHERE name = ?", (name,))
            for spec_id in specs - {None}:
                _drop_spec_if_unused(conn, spec_id)
            # an earlier forget of the name a crash stopped before its vault step (a new dataset of the
            # name since): its originals join, replaced they would stay in the vault with no note (a review)
            note = FORGET_NOTE + name
            earlier = conn.execute("SELECT value FROM store_notes WHERE key = ?", (note,)).fetchone()
            if earlier is not None:
                originals = sorted(set(originals) | set(json.loads(earlier[0])))
            conn.execute(
                "INSERT OR REPLACE INTO store_notes (key, value, created_at) VALUES (?, ?, ?)",
                (note, json.dumps(originals), time.time()),
            )
            insert_event(conn, None, None, "dataset_forgotten", {"dataset": name, "files": rows})
        return rows

    def forget_notes(self) -> dict[str, list[str]]:
        """The originals of each dataset forgotten whose vault step is not done yet (a crash between
        the two steps leaves its note), by dataset name."""
        rows = self._rows("SELECT key, value FROM store_notes WHERE key LIKE ?", (FORGET_NOTE + "%",))
        return {r["key"][len(FORGET_NOTE) :]: list(json.loads(r["value"])) for r in rows}

    def forget_done(self, name: str) -> None:
        """The vault step of forgetting this dataset is done: its note goes."""
        with self._write() as conn:
            conn.execute("DELETE FROM store_notes WHERE key = ?", (FORGET_NOTE + name,))

    def named_originals(self, originals: Iterable[str]) -> set[str]:
        """Which of these originals a row of the store names (any dataset, any state), or a dataset keeps
        as an earlier version's (a copy published before an edit restores from it)."""
        wanted = list(originals)
        named: set[str] = set()
        for start in range(0, len(wanted), 400):  # SQLite's bound on parameters (999 before 3.32): 2 x 400
            chunk = wanted[start : start + 400]
            marks = ", ".join("?" for _ in chunk)
            sql = (f"SELECT original_sha256 AS o FROM files WHERE original_sha256 IN ({marks}) "
                   f"UNION SELECT sha256 FROM earlier_originals WHERE sha256 IN ({marks})")  # fmt: skip
            rows = self._rows(sql, (*chunk, *chunk))
            named |= {r["o"] for r in rows}
        return named

    def carry_earlier_originals(self, rows: Iterable[tuple[str, str, float]]) -> None:
        """(dataset, sha256, replaced_at) rows of earlier originals, as an old store held them
        (`ppd store rebuild`: daemon.protect.rebuild_carry)."""
        with self._write() as conn:
            conn.executemany(
                "INSERT OR IGNORE INTO earlier_originals (dataset, sha256, replaced_at) VALUES (?, ?, ?)",
                list(rows),
            )

    def set_dataset_publish_dir(self, name: str, publish_dir: Path | None) -> None:
        with self._write() as conn:
            conn.execute(
                "UPDATE datasets SET publish_dir = ? WHERE name = ?",
                (str(publish_dir) if publish_dir else None, name),
            )


def _wrote(path: str, size: int | None, mtime_ns: int | None) -> bool:
    """Whether path holds a file of the size and modification time ppd recorded writing."""
    try:
        st = os.stat(path, follow_symlinks=False)
    except OSError:
        return False
    return size is not None and (st.st_size, st.st_mtime_ns) == (size, mtime_ns)


def _drop_spec_if_unused(conn: sqlite3.Connection, spec_id: str) -> None:
    """Remove a spec no dataset, file row or decision uses any more (its copy in the vault stays)."""
    conn.execute(
        "DELETE FROM specs WHERE id = ? AND NOT EXISTS (SELECT 1 FROM datasets WHERE spec_id = ?)"
        " AND NOT EXISTS (SELECT 1 FROM files WHERE spec_id = ?)"
        " AND NOT EXISTS (SELECT 1 FROM auto_decisions WHERE spec_id = ?)",
        (spec_id, spec_id, spec_id, spec_id),
    )


def _refuse_if_patched(conn: sqlite3.Connection, name: str, spec_id: str | None, new_id: str) -> None:
    """DatasetSpecLocked when the dataset has patched (or pending) files under its current spec; a
    dataset without one (a rebuilt store's) under the spec its files carry, SpecNotRecovered when the
    store lost that one too: new_id equal to it is the spec given back, free."""
    if spec_id is None:
        lost = _lost_spec_id(conn, name)
        if lost is None or lost == new_id:
            return
        if not _spec_held(conn, lost):
            raise SpecNotRecovered(
                f"dataset {name!r}: these flags make spec {new_id}, not {lost}, the spec its patched files "
                "carry, which `ppd store rebuild` did not recover: give the flags it was made with, or "
                f"`ppd dataset set {shlex.quote(name)} FLAGS --reprotect` marks all its files again with them"
            )
        spec_id = lost
    patched = conn.execute(
        "SELECT COUNT(*) FROM files WHERE dataset = ? AND state IN (?, ?)",
        (name, FileState.PATCHED, FileState.PENDING),
    ).fetchone()[0]
    if patched:
        raise DatasetSpecLocked(
            f"dataset {name!r} has {patched} patched file(s) under spec {spec_id}; "
            f"changing it needs a re-protect from the vault "
            f"(ppd dataset set {name} ... --reprotect)"
        )


def _lost_spec_id(conn: sqlite3.Connection, name: str) -> str | None:
    """The spec the dataset's patched (or pending) files carry, the most common one, when the dataset
    itself has none: a `ppd store rebuild` that did not recover it (a seal names only the spec's id, and
    a ppd before this one kept no copy in the vault). A black-box review: such a dataset's next photo
    silently got the config's spec, and status advised re-marking the creator's design with it."""
    row = conn.execute(
        "SELECT f.spec_id FROM files f JOIN datasets d ON d.name = f.dataset WHERE f.dataset = ? AND "
        "d.spec_id IS NULL AND f.spec_id IS NOT NULL AND f.state IN (?, ?) "
        "GROUP BY f.spec_id ORDER BY COUNT(*) DESC, f.spec_id LIMIT 1",
        (name, FileState.PATCHED, FileState.PENDING),
    ).fetchone()
    return str(row[0]) if row is not None else None


def _spec_held(conn: sqlite3.Connection, spec_id: str) -> bool:
    return conn.execute("SELECT 1 FROM specs WHERE id = ?", (spec_id,)).fetchone() is not None


def _spec_for_unset(conn: sqlite3.Connection, name: str, spec: PatchSpec) -> str:
    """The id of the spec a dataset without one takes with a file: the one its patched files carry when
    the store holds it, else spec's; SpecNotRecovered when they carry another, lost one (never two marks
    in one dataset, in silence)."""
    lost = _lost_spec_id(conn, name)
    if lost is not None and lost != spec.spec_id:
        if _spec_held(conn, lost):
            return lost
        raise SpecNotRecovered(f"dataset {name!r}: {spec_not_recovered(name, lost)}; not patched")
    return spec.spec_id


def spec_not_recovered(name: str, spec_id: str) -> str:
    """What a dataset whose spec was lost is, and what gives it back: said by the refused file, `ppd store
    rebuild`, `ppd status` and `ppd dataset show` alike."""
    q = shlex.quote(name)
    return (
        f"spec not recovered: its patched files carry spec {spec_id}, which `ppd store rebuild` found "
        f"nowhere, so its new photos are refused: `ppd dataset set {q}` with the flags it was made with "
        f"(--design, --patch-size, --position, ...) gives it back, or `ppd dataset set {q} --reprotect` "
        "marks all its files again with the config's spec; then `ppd poison` of its folder patches those "
        "refused"
    )


def natural_key(name: str) -> list[tuple[int, int | str]]:
    """A name's sort key with its runs of digits as numbers (case folded)."""
    return [(0, int(part)) if part.isdigit() else (1, part) for part in re.split(r"(\d+)", name.casefold())]
