"""What was decided and found about a dataset: verification runs (a verdict per profile) and
automatic mode's decisions (docs/AUTO.md)."""

from __future__ import annotations

import json
import time
from typing import Any

from daemon.store.connection import StoreBase
from daemon.store.datasets import insert_spec
from daemon.store.errors import StoreError
from daemon.store.event_log import insert_event
from daemon.store.schema import AUTO_TRIGGERS
from poisoner.spec import PatchSpec

# events that change a dataset's pixels: a verdict measured before the newest of them is history
PIXEL_EVENTS = ("patched", "reprotected", "recovered", "restored")


class VerificationRows(StoreBase):
    # ---- verification runs ----------------------------------------------------------------
    def add_verification_run(
        self,
        dataset: str,
        profile: str,
        verdict: str,
        metrics: dict[str, Any],
        started_at: float,
        finished_at: float,
        model_dir: str | None,
        error: str | None,
    ) -> int:
        with self._write() as conn:
            cursor = conn.execute(
                "INSERT INTO verification_runs (dataset, profile, verdict, metrics, started_at, finished_at, "
                "model_dir, error) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (dataset, profile, verdict, json.dumps(metrics, default=str, sort_keys=True),
                 started_at, finished_at, model_dir, error),
            )  # fmt: skip
            run_id = int(cursor.lastrowid or 0)
            detail = {"run_id": run_id, "profile": profile, "verdict": verdict}
            insert_event(conn, dataset, None, "verification", detail)
        return run_id

    def verification_runs(self, dataset: str, limit: int = 20) -> list[dict[str, Any]]:
        """Newest first; metrics parsed."""
        return self._newest("verification_runs", "finished_at", "metrics", dataset, limit)

    def pixels_changed_at(self, dataset: str) -> float | None:
        """When the dataset's pixels last changed (a file patched, re-patched or restored), or None."""
        kinds = ", ".join("?" for _ in PIXEL_EVENTS)
        rows = self._rows(
            f"SELECT MAX(ts) AS ts FROM events WHERE dataset = ? AND kind IN ({kinds})",
            (dataset, *PIXEL_EVENTS),
        )
        return rows[0]["ts"] if rows and rows[0]["ts"] is not None else None

    def current_verification_runs(self, dataset: str, limit: int = 50) -> list[dict[str, Any]]:
        """The runs that measured the dataset's pixels as they are now (issue 25): those started after
        its last pixel change. Older runs stay in verification_runs (history), never in a verdict."""
        changed = self.pixels_changed_at(dataset)
        runs = self.verification_runs(dataset, limit=limit)
        return runs if changed is None else [r for r in runs if r["started_at"] >= changed]

    def carry_history(self, runs: list[dict[str, Any]], pixel_events: list[dict[str, Any]]) -> None:
        """A rebuilt store's copy of the old store's verification runs (metrics as stored, JSON text)
        and of the events that date its datasets' pixel changes (PIXEL_EVENTS only), with their
        times: current_verification_runs then tells a current verdict from history as the old store
        did (daemon.protect.rebuild_carry)."""
        with self._write() as conn:
            for e in pixel_events:
                if e["kind"] in PIXEL_EVENTS:
                    conn.execute(
                        "INSERT INTO events (ts, dataset, path, kind, detail) VALUES (?, ?, ?, ?, ?)",
                        (e["ts"], e["dataset"], e["path"], e["kind"], e["detail"]),
                    )
            for r in runs:
                conn.execute(
                    "INSERT INTO verification_runs (dataset, profile, verdict, metrics, started_at, "
                    "finished_at, model_dir, error) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                    (r["dataset"], r["profile"], r["verdict"], r["metrics"], r["started_at"],
                     r["finished_at"], r["model_dir"], r["error"]),
                )  # fmt: skip

    def latest_verification(self, dataset: str) -> dict[str, Any] | None:
        runs = self.verification_runs(dataset, limit=1)
        return runs[0] if runs else None

    # ---- automatic mode -------------------------------------------------------------------
    def add_auto_decision(
        self,
        dataset: str,
        candidate: str | None,
        spec: PatchSpec | None,
        reason: str,
        evidence: dict[str, Any],
        trigger: str,
    ) -> int:
        """Record what automatic mode decided for a dataset (and an 'auto_decision' event)."""
        if trigger not in AUTO_TRIGGERS:
            raise StoreError(f"unknown auto trigger {trigger!r}; one of {', '.join(AUTO_TRIGGERS)}")
        with self._write() as conn:
            spec_id = insert_spec(conn, spec) if spec is not None else None
            cursor = conn.execute(
                "INSERT INTO auto_decisions (dataset, decided_at, candidate, spec_id, reason, evidence, "
                "trigger) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (dataset, time.time(), candidate, spec_id, reason,
                 json.dumps(evidence, default=str, sort_keys=True), trigger),
            )  # fmt: skip
            decision_id = int(cursor.lastrowid or 0)
            detail = {"id": decision_id, "candidate": candidate, "spec_id": spec_id, "trigger": trigger}
            insert_event(conn, dataset, None, "auto_decision", detail)
        return decision_id

    def auto_decisions(self, dataset: str, limit: int = 20) -> list[dict[str, Any]]:
        """Newest first; evidence parsed."""
        return self._newest("auto_decisions", "decided_at", "evidence", dataset, limit)

    def latest_auto_decision(self, dataset: str) -> dict[str, Any] | None:
        rows = self.auto_decisions(dataset, limit=1)
        return rows[0] if rows else None

    def _newest(
        self, table: str, time_column: str, json_column: str, dataset: str, limit: int
    ) -> list[dict[str, Any]]:
        """A dataset's newest rows of a table of dated records, their JSON column parsed.

        table and the columns are this module's own literals, never input."""
        rows = self._rows(
            f"SELECT * FROM {table} WHERE dataset = ? ORDER BY {time_column} DESC, id DESC LIMIT ?",
            (dataset, limit),
        )
        for row in rows:
            row[json_column] = json.loads(row[json_column]) if row[json_column] else {}
        return rows
