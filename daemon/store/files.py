"""File rows: one per path ppd has seen, with its state, the original's and the patched output's
hashes, and the spec it was patched with."""

from __future__ import annotations

import os
import sqlite3
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from daemon.states import NOT_MOVED_PREFIX, FileState
from daemon.store.connection import StoreBase
from daemon.store.errors import PatchedNotFailed, StoreError
from daemon.store.event_log import insert_event

FILE_STATES: tuple[FileState, ...] = tuple(FileState)
FILE_FIELDS = frozenset(
    {
        "original_sha256",
        "original_mtime_ns",
        "poisoned_sha256",
        "spec_id",
        "tool_version",
        "size",
        "mtime_ns",
        "error",
        "published_path",
        "resaved",
        "saved_over",
    }
)


class FileRows(StoreBase):
    def file(self, path: Path | str) -> dict[str, Any] | None:
        return self._one("SELECT * FROM files WHERE path = ?", (str(path),))

    def files(self, dataset: str, state: FileState | str | None = None) -> list[dict[str, Any]]:
        """A dataset's rows by path; an unknown state raises StoreError (an old word such as
        'protected' would otherwise match nothing, silently)."""
        if state is None:
            return self._rows("SELECT * FROM files WHERE dataset = ? ORDER BY path", (dataset,))
        return self._rows(
            "SELECT * FROM files WHERE dataset = ? AND state = ? ORDER BY path",
            (dataset, file_state(state).value),
        )

    def files_below(self, dataset: str, folder: Path | str, limit: int = -1) -> list[dict[str, Any]]:
        """Up to limit (-1: all) of the dataset's rows whose path lies below folder, by path."""
        below = str(folder).rstrip("/") + "/"
        sql = "SELECT * FROM files WHERE dataset = ? AND path >= ? AND path < ? ORDER BY path LIMIT ?"
        return self._rows(sql, (dataset, below, below[:-1] + "0", limit))

    def files_under(self, folder: Path | str, not_of: str | None = None) -> list[dict[str, Any]]:
        """The path and dataset of every row whose path lies below folder (by path; not_of: leaving
        out that dataset's rows), by path. A range over the path index: '/' + 1 is '0'."""
        below = str(folder).rstrip("/") + "/"
        sql = "SELECT path, dataset FROM files WHERE path >= ? AND path < ?"
        params: tuple[str, ...] = (below, below[:-1] + "0")
        if not_of is not None:
            sql, params = sql + " AND dataset != ?", (*params, not_of)
        return self._rows(sql + " ORDER BY path", params)

    def find_poisoned(
        self, sha256: str, moved_first: bool = False, state: FileState | None = None, near: Path | None = None
    ) -> dict[str, Any] | None:
        """A row whose patched output has this content (ppd's own output, anywhere). moved_first: of
        several (two photos with the same bytes patched alike), one whose file is no longer at its path
        (a file moved or renamed is that one, and keeps that row's original's date), else the first.
        near: the file found; of several gone, the one whose path shares most folders with it (the same
        photo in two shoots, one renamed and the other's folder moved: the rename took the other shoot's
        row, and its own stayed "gone since patched": `ppd restore` then offered to bring back a
        duplicate; a black-box review). state: only rows in that state (a restored or removed row keeps
        its output's hash)."""
        where, params = "poisoned_sha256 = ?", [sha256]
        if state is not None:
            where, params = where + " AND state = ?", [sha256, file_state(state).value]
        if not moved_first:
            return self._one(f"SELECT * FROM files WHERE {where} ORDER BY id LIMIT 1", tuple(params))
        rows = self._rows(f"SELECT * FROM files WHERE {where} ORDER BY id", tuple(params))
        gone = [r for r in rows if not os.path.lexists(r["path"])]
        if near is not None:  # a stable sort: among rows as near, the first recorded
            gone.sort(key=lambda r: -_folders_shared(Path(r["path"]), Path(near)))
        return gone[0] if gone else (rows[0] if rows else None)

    def find_original(self, sha256: str) -> list[dict[str, Any]]:
        """Every row whose original has this content (newest first)."""
        return self._rows(
            "SELECT * FROM files WHERE original_sha256 = ? ORDER BY updated_at DESC, id DESC", (sha256,)
        )

    def record_file(
        self,
        path: Path | str,
        dataset: str,
        state: FileState | str,
        *,
        event: str | None = None,
        detail: dict[str, Any] | None = None,
        current_sha256: str | None = None,
        durable: bool = True,
        **fields: Any,
    ) -> None:
        """Insert or update the row for path (and optionally log an event), in one transaction.

        durable=False: committed without an fsync (StoreBase._write): for a row whose loss at a power
        cut is recovered from elsewhere (the 'pending' row: daemon.protect.stages).

        current_sha256, when the caller knows the file's content now: a FAILED for a row that
        is PATCHED with exactly that content as its poisoned_sha256 is refused (StoreError), in
        the same transaction as the write. The file *is* ppd's patched output; recording it as
        failed would make `ppd restore` skip it and a later run patch it twice."""
        state = file_state(state)
        check_fields(fields)
        with self._write(durable) as conn:
            upsert_file(conn, path, dataset, state, fields, current_sha256)
            if event:
                insert_event(conn, dataset, str(path), event, detail or {})

    def record_files(self, rows: Iterable[tuple[Path | str, str, FileState | str, dict[str, Any]]]) -> int:
        """Insert or update many (path, dataset, state, fields) rows in one transaction (one
        fsync, not one per row: a rebuild writes thousands); returns how many."""
        checked = []
        for path, dataset, state, fields in rows:
            check_fields(fields)
            checked.append((path, dataset, file_state(state), fields))
        with self._write() as conn:
            for path, dataset, state, fields in checked:
                upsert_file(conn, path, dataset, state, fields, None)
        return len(checked)

    def note_not_reprotected(self, path: Path | str, dataset: str, reason: str, spec_id: str) -> None:
        """A patched file a re-protect to spec_id failed on: its row stays patched under its earlier
        spec (its bytes are untouched) and keeps the reason in error, until a run writes it again
        (`ppd status --failed` lists it: a black-box review found the failure said once, then lost)."""
        with self._write() as conn:
            conn.execute(
                "UPDATE files SET error = ? WHERE path = ? AND state = ?",
                (reason, str(path), FileState.PATCHED.value),
            )
            insert_event(conn, dataset, str(path), "reprotect_failed", {"spec_id": spec_id, "reason": reason})

    def not_reprotected(self, dataset: str) -> list[dict[str, Any]]:
        """The dataset's patched rows a re-protect failed on (note_not_reprotected), by path."""
        return self._rows(
            "SELECT * FROM files WHERE dataset = ? AND state = ? AND error IS NOT NULL "
            "AND substr(error, 1, ?) != ? ORDER BY path",
            (dataset, FileState.PATCHED.value, len(NOT_MOVED_PREFIX), NOT_MOVED_PREFIX),
        )

    def not_moved(self, dataset: str) -> list[dict[str, Any]]:
        """The dataset's patched rows whose move to the publish folder failed (daemon.protect.publishing):
        patched, still in the outbox; by path."""
        return self._rows(
            "SELECT * FROM files WHERE dataset = ? AND state = ? AND substr(error, 1, ?) = ? ORDER BY path",
            (dataset, FileState.PATCHED.value, len(NOT_MOVED_PREFIX), NOT_MOVED_PREFIX),
        )

    def counts(self, dataset: str) -> dict[str, int]:
        """Rows per state (keys: every FileState value) and their total under "files"."""
        counts: dict[str, int] = {state.value: 0 for state in FILE_STATES}
        for row in self._rows(
            "SELECT state, COUNT(*) AS n FROM files WHERE dataset = ? GROUP BY state", (dataset,)
        ):
            counts[row["state"]] = row["n"]
        counts["files"] = sum(counts[s] for s in FILE_STATES)
        return counts

    def patched_with_other_spec(self, dataset: str, spec_id: str | None) -> int:
        """How many of the dataset's patched rows carry another spec than spec_id (a re-protect that
        did not finish leaves them). A dataset without a spec (a rebuilt store's that lost it) has none to
        differ from: its files carry the lost one (DatasetRows.lost_spec), and a re-protect they were
        advised would put the config's mark over the creator's design (a black-box review)."""
        if spec_id is None:
            return 0
        row = self._one(
            "SELECT COUNT(*) AS n FROM files WHERE dataset = ? AND state = ? AND spec_id IS NOT ?",
            (dataset, FileState.PATCHED.value, spec_id),
        )
        return int(row["n"]) if row else 0


def upsert_file(
    conn: sqlite3.Connection,
    path: Path | str,
    dataset: str,
    state: FileState,
    fields: dict[str, Any],
    current_sha256: str | None,
) -> None:
    """Insert or update path's row inside the caller's transaction (see FileRows.record_file)."""
    if state is FileState.FAILED and current_sha256 is not None:
        row = conn.execute("SELECT state, poisoned_sha256 FROM files WHERE path = ?", (str(path),)).fetchone()
        if row is not None and row[0] == FileState.PATCHED and row[1] == current_sha256:
            raise PatchedNotFailed(
                f"{path} is ppd's patched output (sha256 {current_sha256[:12]}); "
                "not recording it as failed, its row stays patched"
            )
    now = time.time()
    if fields.get("original_sha256"):
        _keep_earlier_original(conn, path, fields["original_sha256"], now)
    values = {"dataset": dataset, "state": state.value, "updated_at": now, **fields}
    columns = ", ".join(values)
    marks = ", ".join("?" for _ in values)
    updates = ", ".join(f"{c} = excluded.{c}" for c in values)
    if "original_sha256" in fields and "original_mtime_ns" not in fields:
        # the original's date goes with its content: another original (a seal recognised, an edit)
        # must not keep the last one's date, which restore would give it
        updates += (
            ", original_mtime_ns = CASE WHEN files.original_sha256 IS excluded.original_sha256"
            " THEN files.original_mtime_ns END"
        )
    if "original_sha256" in fields and "saved_over" not in fields:  # it too is said of that original
        updates += (
            ", saved_over = CASE WHEN files.original_sha256 IS excluded.original_sha256"
            " THEN files.saved_over END"
        )
    if "poisoned_sha256" in fields and "resaved" not in fields:
        # "saved again by another program" goes with the bytes it was said of: ppd's own new output
        # (patched again, re-protected) is not the creator's
        updates += (
            ", resaved = CASE WHEN files.poisoned_sha256 IS excluded.poisoned_sha256 THEN files.resaved END"
        )
    conn.execute(
        f"INSERT INTO files (path, created_at, {columns}) VALUES (?, ?, {marks}) "
        f"ON CONFLICT(path) DO UPDATE SET {updates}",
        (str(path), now, *values.values()),
    )


def _keep_earlier_original(conn: sqlite3.Connection, path: Path | str, original: str, now: float) -> None:
    """The row's original before this one, when another replaces it (an edit patched again): noted
    under the row's dataset, so that `ppd dataset forget` finds it in the vault (no row names it)."""
    row = conn.execute("SELECT dataset, original_sha256 FROM files WHERE path = ?", (str(path),)).fetchone()
    if row is not None and row[1] is not None and row[1] != original:
        conn.execute(
            "INSERT OR IGNORE INTO earlier_originals (dataset, sha256, replaced_at) VALUES (?, ?, ?)",
            (row[0], row[1], now),
        )


def file_state(state: FileState | str) -> FileState:
    try:
        return FileState(state)
    except ValueError:
        raise StoreError(f"unknown file state {state!r}; one of {', '.join(FILE_STATES)}") from None


def check_fields(fields: dict[str, Any]) -> None:
    """Only the files table's own columns (the column names go into the SQL text)."""
    unknown = set(fields) - FILE_FIELDS
    if unknown:
        raise StoreError(f"unknown file field(s): {', '.join(sorted(unknown))}")


def _folders_shared(a: Path, b: Path) -> int:
    """How many leading folders the two paths' folders have in common."""
    n = 0
    for x, y in zip(a.parent.parts, b.parent.parts, strict=False):
        if x != y:
            break
        n += 1
    return n
