"""The event log: one row for each thing ppd did, written in the same transaction as the rows
it changed."""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path
from typing import Any

from daemon.store.connection import StoreBase


def insert_event(
    conn: sqlite3.Connection, dataset: str | None, path: str | None, kind: str, detail: dict[str, Any]
) -> None:
    """Add an event inside the caller's transaction."""
    conn.execute(
        "INSERT INTO events (ts, dataset, path, kind, detail) VALUES (?, ?, ?, ?, ?)",
        (time.time(), dataset, path, kind, json.dumps(detail, default=str, sort_keys=True)),
    )


class EventRows(StoreBase):
    def add_event(
        self, dataset: str | None, path: Path | str | None, kind: str, detail: dict[str, Any]
    ) -> None:
        with self._write() as conn:
            insert_event(conn, dataset, str(path) if path is not None else None, kind, detail)

    def last_event(self, path: Path | str, kind: str) -> dict[str, Any] | None:
        """The newest event of this kind for path (detail parsed), or None."""
        rows = self._rows(
            "SELECT * FROM events WHERE path = ? AND kind = ? ORDER BY id DESC LIMIT 1", (str(path), kind)
        )
        for row in rows:
            row["detail"] = json.loads(row["detail"]) if row["detail"] else {}
        return rows[0] if rows else None

    def events(self, dataset: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        """Newest first; detail parsed."""
        if dataset is None:
            rows = self._rows("SELECT * FROM events ORDER BY id DESC LIMIT ?", (limit,))
        else:
            rows = self._rows(
                "SELECT * FROM events WHERE dataset = ? ORDER BY id DESC LIMIT ?", (dataset, limit)
            )
        for row in rows:
            row["detail"] = json.loads(row["detail"]) if row["detail"] else {}
        return rows

    def patched_place_notes(self, dataset: str) -> list[str | None]:
        """For each file of the dataset patched now, the place note of the run that patched it (its
        newest 'patched' event: daemon.protect.job.report_detail), None where the mark found a free
        place or the event says nothing of it (a corner design, a video, an older ppd)."""
        rows = self._rows(
            "SELECT e.path, e.detail FROM events e JOIN files f ON f.path = e.path AND f.state = 'patched' "
            "WHERE e.dataset = ? AND f.dataset = ? AND e.kind = 'patched' ORDER BY e.id",
            (dataset, dataset),
        )
        newest = {row["path"]: json.loads(row["detail"]) if row["detail"] else {} for row in rows}
        return [(detail.get("place") or {}).get("note") for detail in newest.values()]

    def mark_detail(self, path: Path | str) -> dict[str, Any]:
        """What ppd recorded of the mark the file at path (a row's path) carries now: the detail of its
        newest 'patched' or 'reprotected' event (daemon.protect.job.report_detail: "place", "placement");
        {} when there is none."""
        rows = self._rows(
            "SELECT detail FROM events WHERE path = ? AND kind IN ('patched', 'reprotected') "
            "ORDER BY id DESC LIMIT 1",
            (str(path),),
        )
        return json.loads(rows[0]["detail"]) if rows and rows[0]["detail"] else {}
