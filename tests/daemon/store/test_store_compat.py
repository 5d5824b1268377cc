"""A store written by an earlier ppd opens with this one: the shipped migrations are unchanged, a
store built by running them plainly (sqlite3 alone, no ppd code) and filled with rows the way ppd
writes them reads back through Store's methods value for value, and what Store writes is what
that schema holds."""

from __future__ import annotations

import hashlib
import json
import sqlite3
from pathlib import Path

import pytest

from daemon.states import FileState
from daemon.store import LOST_NOTE, MIGRATIONS, SCHEMA_VERSION, Store
from poisoner.spec import PatchSpec

# sha256 of each migration script as shipped (schema versions 1 to 5: the plain store below). A
# migration that has shipped is never edited (stores in the field have run it); new ones are appended.
SHIPPED_MIGRATIONS = (
    "85088ebe6fdf6e664fe0482ba5b6b3e57564e0f914f059f57c6612aaff1f9116",
    "dadd321630d13e95b489562f0ce396b6be46e0f474aa95b80e89743ef7dbe7cd",
    "73927d0888531ceb9a5b62d4aaf7aaf66219f5bc82be8c9e3d836164b697ae21",
    "f48ec9c30ab293dae2c684bd0ad2bb34f7540ce6e8e843c0d7f9e1acd8d5665c",
    "3e811e7875babfd685557d59ee71f260e4880fc7ef76fb9691d51726c29184fd",
)
# the ones shipped since (6: subject_masks, 7: original_mtime_ns, 8: earlier_originals), never edited either
LATER_MIGRATIONS = (
    "855a8668ba38e28ff13967877e31547f670810183b80e0ed9b357327aa542003",
    "883b5591fa2e7fce858f92db598d56b65077626f7fa2a8f3c3e6395e4b1c569e",
    "b3e0b706c6c3f32c8038b16e3bf29312f281668e1448877ea1dd96f067cc918d",
)
SPEC = PatchSpec(seed=7)
AUTO_SPEC = PatchSpec(seed=8)


def _plain_store(db: Path, versions: int = len(SHIPPED_MIGRATIONS)) -> sqlite3.Connection:
    """The shipped migrations run by sqlite3 alone, in WAL mode as ppd keeps its store."""
    conn = sqlite3.connect(db, isolation_level=None)
    conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("CREATE TABLE schema_version (version INTEGER NOT NULL)")
    conn.execute("INSERT INTO schema_version (version) VALUES (0)")
    for index in range(versions):
        conn.executescript(MIGRATIONS[index])
        conn.execute("UPDATE schema_version SET version = ?", (index + 1,))
    return conn


def _schema(conn: sqlite3.Connection) -> list[tuple[str, str, str]]:
    """Every table and index with its SQL, comments and spacing aside (ppd runs the statements
    without their comments)."""
    rows = conn.execute("SELECT type, name, sql FROM sqlite_master WHERE name NOT LIKE 'sqlite_%'")
    return sorted((kind, name, _bare(sql)) for kind, name, sql in rows)


def _bare(sql: str) -> str:
    return " ".join(" ".join(line.split("--", 1)[0] for line in sql.splitlines()).split())


def _write_rows(conn: sqlite3.Connection) -> None:
    """One row of every kind, as ppd writes them (JSON with sorted keys, paths as text)."""
    for spec in (SPEC, AUTO_SPEC):
        conn.execute("INSERT INTO specs VALUES (?, ?, ?, 10.0)", (spec.spec_id, spec.to_json(), spec.version))
    conn.execute("INSERT INTO datasets VALUES ('trip', '/o/trip', ?, 11.0, '/pub/trip')", (SPEC.spec_id,))
    conn.execute("INSERT INTO datasets VALUES ('bare', '/o/bare', NULL, 12.0, NULL)")
    conn.execute(
        "INSERT INTO files (id, dataset, path, state, original_sha256, poisoned_sha256, spec_id, "
        "tool_version, size, mtime_ns, created_at, updated_at, error, published_path) "
        "VALUES (5, 'trip', '/o/trip/a.jpg', 'patched', ?, ?, ?, 'ppd 0.1.0', 123, 456, 13.0, 14.0, NULL, ?)",
        ("a" * 64, "b" * 64, SPEC.spec_id, "/pub/trip/a.jpg"),
    )
    conn.execute(
        "INSERT INTO files (id, dataset, path, state, created_at, updated_at, error) "
        "VALUES (6, 'trip', '/o/trip/b.png', 'quarantined', 15.0, 16.0, 'cannot be decoded')"
    )
    conn.execute(
        "INSERT INTO events (ts, dataset, path, kind, detail) "
        "VALUES (17.0, 'trip', '/o/trip/a.jpg', 'patched', ?)",
        (json.dumps({"spec_id": SPEC.spec_id, "ms": 12}, sort_keys=True),),
    )
    conn.execute(
        "INSERT INTO verification_runs (dataset, profile, verdict, metrics, started_at, finished_at, "
        "model_dir, error) VALUES ('trip', 'default', 'protected', ?, 18.0, 19.0, '/runs/1', NULL)",
        (json.dumps({"registered": 3, "views": 24}, sort_keys=True),),
    )
    conn.execute(
        "INSERT INTO auto_decisions (dataset, decided_at, candidate, spec_id, reason, evidence, trigger) "
        "VALUES ('trip', 20.0, 'a-small', ?, 'least visible', ?, 'preflight')",
        (AUTO_SPEC.spec_id, json.dumps({"budget_use": 0.5}, sort_keys=True)),
    )
    conn.execute("INSERT INTO store_notes VALUES (?, 'the earlier store was lost', 21.0)", (LOST_NOTE,))


def test_the_shipped_migrations_are_unchanged() -> None:
    assert len(MIGRATIONS) == SCHEMA_VERSION >= len(SHIPPED_MIGRATIONS)
    digests = tuple(hashlib.sha256(m.encode()).hexdigest() for m in MIGRATIONS)
    assert digests[: len(SHIPPED_MIGRATIONS) + len(LATER_MIGRATIONS)] == SHIPPED_MIGRATIONS + LATER_MIGRATIONS


def test_a_new_store_has_the_schema_the_migrations_make_when_run_plainly(tmp_path: Path) -> None:
    plain = _plain_store(tmp_path / "plain.sqlite3", len(MIGRATIONS))
    store = Store(tmp_path / "ppd.sqlite3")
    try:
        assert _schema(store.conn) == _schema(plain)
        assert store.fresh and store.schema_version() == SCHEMA_VERSION
    finally:
        store.close()
        plain.close()


def test_a_store_written_with_the_shipped_schema_reads_back_through_store(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    conn = _plain_store(db)
    _write_rows(conn)
    conn.close()
    store = Store(db)
    try:
        assert not store.fresh and store.schema_version() == SCHEMA_VERSION
        assert store.get_spec(SPEC.spec_id) == SPEC and store.dataset_spec("trip") == SPEC
        assert store.dataset_spec("bare") is None
        assert store.datasets() == [
            {"name": "bare", "root": "/o/bare", "spec_id": None, "created_at": 12.0, "publish_dir": None,
             "subject_masks": None},
            {"name": "trip", "root": "/o/trip", "spec_id": SPEC.spec_id, "created_at": 11.0,
             "publish_dir": "/pub/trip", "subject_masks": None},
        ]  # fmt: skip
        assert store.file("/o/trip/a.jpg") == {
            "id": 5, "dataset": "trip", "path": "/o/trip/a.jpg", "state": FileState.PATCHED,
            "original_sha256": "a" * 64, "poisoned_sha256": "b" * 64, "spec_id": SPEC.spec_id,
            "tool_version": "ppd 0.1.0", "size": 123, "mtime_ns": 456, "created_at": 13.0, "updated_at": 14.0,
            "error": None, "published_path": "/pub/trip/a.jpg", "original_mtime_ns": None,
            "resaved": None, "saved_over": None,
        }  # fmt: skip
        assert [r["path"] for r in store.files("trip", FileState.QUARANTINED)] == ["/o/trip/b.png"]
        assert store.find_poisoned("b" * 64)["id"] == 5 and [
            r["id"] for r in store.find_original("a" * 64)
        ] == [5]
        assert store.counts("trip") == {
            **{s.value: 0 for s in FileState},
            "patched": 1,
            "quarantined": 1,
            "files": 2,
        }
        [event] = store.events("trip")
        assert (event["kind"], event["path"]) == ("patched", "/o/trip/a.jpg")
        assert event["detail"] == {"spec_id": SPEC.spec_id, "ms": 12}
        run = store.latest_verification("trip")
        assert (run["verdict"], run["model_dir"]) == ("protected", "/runs/1")
        assert run["metrics"] == {"registered": 3, "views": 24}
        decision = store.latest_auto_decision("trip")
        assert (decision["candidate"], decision["spec_id"]) == ("a-small", AUTO_SPEC.spec_id)
        assert (decision["evidence"], decision["trigger"]) == ({"budget_use": 0.5}, "preflight")
        assert store.lost_note() == "the earlier store was lost"
    finally:
        store.close()


def test_what_store_writes_into_an_old_store_is_what_ppd_wrote(tmp_path: Path) -> None:
    """Rows written through Store into a store of the shipped schema, read back with sqlite3 alone."""
    db = tmp_path / "ppd.sqlite3"
    _plain_store(db).close()
    store = Store(db)
    try:
        store.ensure_dataset("trip", Path("/o/trip"), SPEC)
        detail = {"z": 1, "a": 2}
        store.record_file(
            "/o/trip/a.jpg",
            "trip",
            FileState.PATCHED,
            event="patched",
            detail=detail,
            original_sha256="a" * 64,
            size=3,
        )
        store.add_verification_run("trip", "default", "protected", {"b": 1, "a": 2}, 1.0, 2.0, None, None)
        with pytest.raises(sqlite3.IntegrityError):  # the shipped CHECK constraint still holds
            store.conn.execute("UPDATE files SET state = 'protected'")
    finally:
        store.close()
    conn = sqlite3.connect(db)
    try:
        assert conn.execute("SELECT id, json FROM specs").fetchall() == [(SPEC.spec_id, SPEC.to_json())]
        files = conn.execute("SELECT path, state, original_sha256, size FROM files").fetchall()
        assert files == [("/o/trip/a.jpg", "patched", "a" * 64, 3)]
        details = dict(
            conn.execute("SELECT kind, detail FROM events WHERE kind != 'dataset_created'").fetchall()
        )
        assert details["patched"] == '{"a": 2, "z": 1}'  # JSON with sorted keys, as before
        assert json.loads(details["verification"])["verdict"] == "protected"
        assert conn.execute("SELECT metrics FROM verification_runs").fetchone()[0] == '{"a": 2, "b": 1}'
    finally:
        conn.close()
