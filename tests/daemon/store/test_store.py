"""The provenance store on a real SQLite file: schema, migrations, concurrency, specs."""

from __future__ import annotations

import os
import sqlite3
import stat
import threading
import time
from pathlib import Path

import pytest

from daemon.states import FileState
from daemon.store import (
    MIGRATIONS,
    SCHEMA_VERSION,
    DatasetSpecLocked,
    PatchedNotFailed,
    Store,
    StoreError,
)
from daemon.store.schema import split_sql
from daemon.verification import auto_mode as daemon_auto
from poisoner.spec import PatchSpec
from verifier.auto_search import LadderEntry

A = LadderEntry("a-small", PatchSpec(patch_size=0.05), "least visible")  # as in test_auto_daemon.py


@pytest.fixture
def store(tmp_path: Path) -> Store:
    s = Store(tmp_path / "ppd.sqlite3")
    yield s
    s.close()


def test_fresh_store_has_schema_and_wal(store: Store) -> None:
    assert store.schema_version() == SCHEMA_VERSION
    tables = set(store.db.table_names())
    assert {"datasets", "specs", "files", "events", "verification_runs", "schema_version"} <= tables
    assert store.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert int(store.db.execute("PRAGMA busy_timeout").fetchone()[0]) >= 1000


def test_reopen_is_idempotent(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    first = Store(db)
    first.ensure_dataset("a", tmp_path, PatchSpec())
    first.close()
    second = Store(db)
    assert second.schema_version() == SCHEMA_VERSION
    assert [d["name"] for d in second.datasets()] == ["a"]
    second.close()


def test_old_database_is_migrated_in_order(tmp_path: Path) -> None:
    db = tmp_path / "old.sqlite3"
    conn = sqlite3.connect(db)
    conn.execute("CREATE TABLE schema_version (version INTEGER NOT NULL)")
    conn.execute("INSERT INTO schema_version VALUES (1)")
    for statement in split_sql(MIGRATIONS[0]):
        conn.execute(statement)
    conn.commit()
    conn.close()
    store = Store(db)
    assert store.schema_version() == SCHEMA_VERSION
    assert "published_path" in store.db["files"].columns_dict
    store.close()


def test_newer_schema_is_refused(tmp_path: Path) -> None:
    db = tmp_path / "new.sqlite3"
    Store(db).close()
    conn = sqlite3.connect(db)
    conn.execute("UPDATE schema_version SET version = ?", (SCHEMA_VERSION + 5,))
    conn.commit()
    conn.close()
    with pytest.raises(StoreError, match="schema version"):
        Store(db)


def test_first_spec_wins_under_concurrency(store: Store, tmp_path: Path) -> None:
    specs = [PatchSpec(seed=i) for i in range(8)]
    got: list[str] = []
    barrier = threading.Barrier(len(specs))

    def first_file(spec: PatchSpec) -> None:
        barrier.wait()
        _, chosen = store.ensure_dataset("shoot", tmp_path, spec)
        got.append(chosen.spec_id)

    threads = [threading.Thread(target=first_file, args=(s,)) for s in specs]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(got) == 8 and len(set(got)) == 1
    assert store.dataset("shoot")["spec_id"] == got[0]


def test_dataset_spec_is_locked_once_files_are_protected(store: Store, tmp_path: Path) -> None:
    store.set_dataset_spec("shoot", PatchSpec(seed=1), root=tmp_path)  # before files: free
    store.set_dataset_spec("shoot", PatchSpec(seed=2))
    assert store.dataset_spec("shoot") == PatchSpec(seed=2)
    store.record_file(tmp_path / "a.png", "shoot", FileState.PATCHED, original_sha256="0" * 64)
    with pytest.raises(DatasetSpecLocked, match="--reprotect"):
        store.set_dataset_spec("shoot", PatchSpec(seed=3))
    assert store.dataset_spec("shoot") == PatchSpec(seed=2)
    store.set_dataset_spec("shoot", PatchSpec(seed=3), allow_protected=True)
    assert store.dataset_spec("shoot") == PatchSpec(seed=3)


def test_record_file_upserts_and_validates(store: Store, tmp_path: Path) -> None:
    store.ensure_dataset("d", tmp_path, PatchSpec())
    path = tmp_path / "x.jpg"
    store.record_file(path, "d", FileState.PENDING, original_sha256="a" * 64, event="pending")
    store.record_file(path, "d", FileState.PATCHED, poisoned_sha256="b" * 64)
    row = store.file(path)
    assert row["state"] == FileState.PATCHED == "patched"
    assert row["original_sha256"] == "a" * 64  # kept from the first write
    assert row["poisoned_sha256"] == "b" * 64
    assert store.find_poisoned("b" * 64)["path"] == str(path)
    assert store.counts("d")[FileState.PATCHED] == 1 and store.counts("d")["files"] == 1
    assert [e["kind"] for e in store.events("d")][0] == "pending"
    with pytest.raises(StoreError):
        store.record_file(path, "d", "bogus")
    with pytest.raises(StoreError):
        store.record_file(path, "d", FileState.FAILED, not_a_column=1)
    with pytest.raises(StoreError, match="unknown file state"):
        store.record_file(path, "d", "protected")  # the old word is not a state any more
    with pytest.raises(StoreError, match="unknown file state"):
        store.files("d", state="protected")  # not an empty list: loud
    assert [r["path"] for r in store.files("d", state=FileState.PATCHED)] == [str(path)]
    assert store.files("d", state="failed") == []


def test_concurrent_writers_lose_nothing(store: Store, tmp_path: Path) -> None:
    store.ensure_dataset("d", tmp_path, PatchSpec())

    def writer(k: int) -> None:
        for i in range(40):
            store.record_file(
                tmp_path / f"{k}-{i}.png", "d", FileState.PATCHED, event="patched", detail={"i": i}
            )

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert store.counts("d")[FileState.PATCHED] == 160
    assert len(store.events("d", limit=1000)) == 160 + 1  # + dataset_created


def test_reader_is_not_blocked_by_a_writer(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    daemon_store, cli_store = Store(db), Store(db)
    daemon_store.ensure_dataset("d", tmp_path, PatchSpec())
    held, release = threading.Event(), threading.Event()

    def long_write() -> None:
        with daemon_store._write() as conn:
            conn.execute("INSERT INTO events (ts, kind) VALUES (?, 'x')", (time.time(),))
            held.set()
            release.wait(10)

    t = threading.Thread(target=long_write)
    t.start()
    assert held.wait(10)
    started = time.monotonic()
    assert [d["name"] for d in cli_store.datasets()] == ["d"]  # WAL: reads while a write is open
    assert time.monotonic() - started < 5.0  # a blocked read would wait for the 10 s release
    release.set()
    t.join()
    daemon_store.close()
    cli_store.close()


def test_verification_runs_newest_first(store: Store) -> None:
    assert store.latest_verification("d") is None
    ids = [
        store.add_verification_run("d", "default", v, {"f5": i / 10}, 100.0 + i, 110.0 + i, None, None)
        for i, v in enumerate(["protected", "weak", "not_protected"])
    ]
    runs = store.verification_runs("d")
    assert [r["id"] for r in runs] == ids[::-1]
    latest = store.latest_verification("d")
    assert latest["verdict"] == "not_protected" and latest["metrics"] == {"f5": 0.2}
    assert len(store.verification_runs("d", limit=2)) == 2
    assert store.verification_runs("other") == []


# ---- migration 4: one vocabulary of states -------------------------------------------------------
def _version_3_store(db: Path) -> None:
    """A store exactly as schema version 3 wrote it (the shipped migrations 1-3, never edited),
    holding rows in every old state, a published file and old 'protected' events."""
    conn = sqlite3.connect(db)
    conn.execute("CREATE TABLE schema_version (version INTEGER NOT NULL)")
    conn.execute("INSERT INTO schema_version VALUES (3)")
    for migration in MIGRATIONS[:3]:
        for statement in split_sql(migration):
            conn.execute(statement)
    conn.execute("INSERT INTO specs VALUES ('s1', '{}', 1, 1.0)")
    conn.execute("INSERT INTO datasets VALUES ('d', '/root', 's1', 1.0, NULL)")
    old_states = ("pending", "protected", "skipped", "failed", "restored", "removed")
    for i, state in enumerate(old_states):
        conn.execute(
            "INSERT INTO files (id, dataset, path, state, original_sha256, poisoned_sha256, spec_id, "
            "tool_version, size, mtime_ns, created_at, updated_at, error, published_path) "
            "VALUES (?, 'd', ?, ?, ?, ?, 's1', 'ppd 0.1.0', ?, ?, 1.0, 2.0, ?, ?)",
            (10 + i, f"/root/{state}.jpg", state, f"{i:064x}", f"{i + 100:064x}", 1000 + i, 5 + i,
             "why" if state == "failed" else None, "/pub/x.jpg" if state == "protected" else None),
        )  # fmt: skip
    conn.execute(
        "INSERT INTO events (ts, dataset, path, kind, detail) VALUES (1.0, 'd', 'p', 'protected', '{}')"
    )
    conn.execute(
        "INSERT INTO events (ts, dataset, path, kind, detail) VALUES (2.0, 'd', 'p', 'reprotected', '{}')"
    )
    with pytest.raises(sqlite3.IntegrityError):  # the old constraint, really
        conn.execute("INSERT INTO files (dataset, path, state, created_at, updated_at) "
                     "VALUES ('d', '/q', 'quarantined', 1, 1)")  # fmt: skip
    conn.commit()
    conn.close()


def test_version_3_store_is_migrated_to_the_one_vocabulary(tmp_path: Path) -> None:
    db = tmp_path / "v3.sqlite3"
    _version_3_store(db)
    before = sqlite3.connect(db)
    old_rows = [list(r) for r in before.execute("SELECT * FROM files ORDER BY id")]
    before.close()
    store = Store(db)
    assert store.schema_version() == SCHEMA_VERSION >= 4
    rows = store.files("d")
    assert {r["path"]: r["state"] for r in rows} == {
        "/root/pending.jpg": FileState.PENDING, "/root/protected.jpg": FileState.PATCHED,
        "/root/skipped.jpg": FileState.SKIPPED, "/root/failed.jpg": FileState.FAILED,
        "/root/restored.jpg": FileState.RESTORED, "/root/removed.jpg": FileState.REMOVED,
    }  # fmt: skip
    # every other column, ids included, came through unchanged
    new_rows = [list(r) for r in store.db.execute("SELECT * FROM files ORDER BY id").fetchall()]
    state_column = 3
    added = len(new_rows[0]) - len(old_rows[0])  # later migrations' columns: NULL
    # (original_mtime_ns, resaved, saved_over)
    assert added == 3 and all(r[-added:] == [None] * added for r in new_rows)
    new_rows = [r[:-added] for r in new_rows]
    for old, new in zip(old_rows, new_rows, strict=True):
        assert old[:state_column] + old[state_column + 1 :] == new[:state_column] + new[state_column + 1 :]
    assert store.file("/root/protected.jpg")["published_path"] == "/pub/x.jpg"
    assert sorted(e["kind"] for e in store.events("d")) == ["patched", "reprotected"]
    indexes = {r[0] for r in store.db.execute("SELECT name FROM sqlite_master WHERE type = 'index'")}
    assert {"files_dataset_state", "files_poisoned_sha", "files_original_sha"} <= indexes
    store.record_file("/root/q.jpg", "d", FileState.QUARANTINED, error="could not be decoded")
    assert store.counts("d")[FileState.QUARANTINED] == 1 and store.counts("d")["files"] == 7
    with pytest.raises(sqlite3.IntegrityError):  # the new constraint refuses the old word
        store.db.execute("UPDATE files SET state = 'protected' WHERE path = '/root/q.jpg'")
    assert store.find_poisoned(f"{101:064x}")["state"] == FileState.PATCHED
    assert [r["path"] for r in store.find_original(f"{1:064x}")] == ["/root/protected.jpg"]
    store.close()


def test_the_files_check_constraint_admits_exactly_the_file_states(store: Store, tmp_path: Path) -> None:
    store.ensure_dataset("d", tmp_path, PatchSpec())
    for state in FileState:
        store.record_file(tmp_path / f"{state}.jpg", "d", state)
    assert store.counts("d") == {**{s.value: 1 for s in FileState}, "files": len(FileState)}
    with pytest.raises(sqlite3.IntegrityError):
        store.db.execute("UPDATE files SET state = 'bogus'")


def test_a_failed_migration_leaves_the_old_store_whole(tmp_path: Path) -> None:
    """The migration is one transaction: a statement that fails halfway rolls it all back."""
    db = tmp_path / "v3.sqlite3"
    _version_3_store(db)
    conn = sqlite3.connect(db)
    conn.execute("CREATE TABLE files_v4 (x)")  # in the way of the rebuilt table
    conn.commit()
    conn.close()
    with pytest.raises(StoreError, match=r"cannot migrate the store .* to schema version 4 .*left as it was"):
        Store(db)
    conn = sqlite3.connect(db)
    assert conn.execute("SELECT version FROM schema_version").fetchone()[0] == 3
    assert conn.execute("SELECT COUNT(*) FROM files WHERE state = 'protected'").fetchone()[0] == 1
    assert conn.execute("SELECT COUNT(*) FROM events WHERE kind = 'protected'").fetchone()[0] == 1
    assert conn.execute("SELECT COUNT(*) FROM files").fetchone()[0] == 6
    conn.close()


def test_a_row_that_breaks_its_own_constraint_is_damage(tmp_path: Path) -> None:
    db = tmp_path / "v3.sqlite3"
    _version_3_store(db)
    conn = sqlite3.connect(db)
    conn.execute("PRAGMA ignore_check_constraints = ON")
    conn.execute("UPDATE files SET state = 'weird' WHERE id = 10")
    conn.commit()
    conn.close()
    with pytest.raises(StoreError, match="is damaged .*CHECK constraint.*`ppd store rebuild`"):
        Store(db)


# ---- a patched file is never recorded as failed ---------------------------------------------------
def test_failed_does_not_overwrite_a_patched_row_whose_file_is_the_patched_output(
    store: Store, tmp_path: Path
) -> None:
    store.ensure_dataset("d", tmp_path, PatchSpec())
    path = tmp_path / "a.jpg"
    store.record_file(path, "d", FileState.PATCHED, original_sha256="a" * 64, poisoned_sha256="b" * 64)
    with pytest.raises(PatchedNotFailed, match="patched output") as caught:
        store.record_file(
            path, "d", FileState.FAILED, error="lock lost", current_sha256="b" * 64, event="failed"
        )
    assert isinstance(caught.value, StoreError) and "\n" not in str(caught.value)
    row = store.file(path)
    assert row["state"] == FileState.PATCHED and row["error"] is None
    assert [e["kind"] for e in store.events("d")] == ["dataset_created"]  # the event rolled back too
    # the file is not (or no longer) the patched output: failed is recorded
    store.record_file(path, "d", FileState.FAILED, error="changed", current_sha256="c" * 64)
    assert store.file(path)["state"] == FileState.FAILED


def test_failed_without_current_sha_or_over_other_states_is_recorded(store: Store, tmp_path: Path) -> None:
    store.ensure_dataset("d", tmp_path, PatchSpec())
    patched, pending = tmp_path / "a.jpg", tmp_path / "b.jpg"
    store.record_file(patched, "d", FileState.PATCHED, poisoned_sha256="b" * 64)
    store.record_file(patched, "d", FileState.FAILED, error="the caller does not know the content")
    assert store.file(patched)["state"] == FileState.FAILED
    store.record_file(pending, "d", FileState.PENDING, poisoned_sha256="b" * 64)
    store.record_file(pending, "d", FileState.FAILED, error="x", current_sha256="b" * 64)
    assert store.file(pending)["state"] == FileState.FAILED


def test_record_files_writes_many_rows_in_one_transaction(store: Store, tmp_path: Path) -> None:
    store.ensure_dataset("d", tmp_path, PatchSpec())
    rows = [
        (tmp_path / f"{i}.jpg", "d", FileState.PATCHED, {"poisoned_sha256": f"{i:064x}"}) for i in range(50)
    ]
    assert store.record_files(rows) == 50
    assert store.counts("d")[FileState.PATCHED] == 50
    bad = [*rows[:3], (tmp_path / "x.jpg", "d", FileState.PATCHED, {"not_a_column": 1})]
    with pytest.raises(StoreError, match="not_a_column"):
        store.record_files(bad)
    with pytest.raises(sqlite3.IntegrityError):  # one bad row: none of the batch is written
        store.record_files(
            [(tmp_path / "new.jpg", "d", FileState.PATCHED, {}), (tmp_path / "y.jpg", "nope", "patched", {})]
        )
    assert store.file(tmp_path / "new.jpg") is None


# ---- automatic mode's decisions, and the files' modes (moved from test_auto_daemon.py) -------------
def test_auto_decisions_table_and_methods(tmp_path: Path) -> None:
    store = Store(tmp_path / "ppd.sqlite3")
    try:
        assert store.schema_version() == SCHEMA_VERSION
        assert store.latest_auto_decision("trip") is None
        first = store.add_auto_decision("trip", "a-small", A.spec, "because", {"x": 1}, "preflight")
        none_left = {"failed": ["a-small"]}
        store.add_auto_decision("trip", None, None, daemon_auto.NO_CANDIDATE, none_left, "escalation")
        rows = store.auto_decisions("trip")
        assert [r["trigger"] for r in rows] == ["escalation", "preflight"]
        assert rows[1]["id"] == first and rows[1]["spec_id"] == A.spec.spec_id
        assert rows[1]["evidence"] == {"x": 1}
        assert store.get_spec(A.spec.spec_id) == A.spec  # the spec is stored with the decision
        assert rows[0]["candidate"] is None and rows[0]["evidence"]["failed"] == ["a-small"]
        assert [e["kind"] for e in store.events("trip")][:2] == ["auto_decision", "auto_decision"]
        with pytest.raises(StoreError, match="unknown auto trigger"):
            store.add_auto_decision("trip", "a", A.spec, "r", {}, "whim")
    finally:
        store.close()


def test_store_files_are_owner_only(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    old = os.umask(0o022)  # a umask that would leave the files world-readable
    try:
        store = Store(db)
        store.add_event(None, None, "probe", {})
    finally:
        os.umask(old)
    try:
        for suffix in ("", "-wal", "-shm"):
            path = Path(f"{db}{suffix}")
            assert path.exists(), path
            assert stat.S_IMODE(path.stat().st_mode) == 0o600, (path, oct(path.stat().st_mode))
    finally:
        store.close()


def test_a_row_written_without_an_fsync_is_committed_and_the_next_write_is_durable(tmp_path: Path) -> None:
    """record_file(durable=False) (the protect stages' 'pending' row): committed (another
    connection reads it), written with synchronous=NORMAL, and the connection back at FULL after."""
    store = Store(tmp_path / "ppd.sqlite3")
    other = Store(tmp_path / "ppd.sqlite3")
    try:
        store.ensure_dataset("shoot", tmp_path, PatchSpec())
        a = tmp_path / "a.jpg"
        store.record_file(a, "shoot", FileState.PENDING, original_sha256="0" * 64, durable=False)
        assert other.file(a)["state"] == FileState.PENDING
        assert store.conn.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
        with pytest.raises(StoreError):
            store.record_file(tmp_path / "b.jpg", "shoot", "no-such-state", durable=False)
        assert store.conn.execute("PRAGMA synchronous").fetchone()[0] == 2
    finally:
        store.close()
        other.close()


def test_a_known_dataset_costs_no_write_transaction(tmp_path: Path) -> None:
    """ensure_dataset for every file of a dataset writes only for its first: with another
    connection holding SQLite's write lock, a known dataset is still answered (no lock wanted)."""
    store = Store(tmp_path / "ppd.sqlite3")
    other = sqlite3.connect(tmp_path / "ppd.sqlite3", isolation_level=None)
    try:
        store.ensure_dataset("shoot", tmp_path, PatchSpec())
        store.conn.execute("PRAGMA busy_timeout = 100")
        other.execute("BEGIN IMMEDIATE")  # the write lock, held
        row, spec = store.ensure_dataset("shoot", tmp_path, PatchSpec(patch_size=0.1))
        assert row["name"] == "shoot" and spec == PatchSpec()  # the first file's spec stays
        with pytest.raises(sqlite3.OperationalError, match="locked"):  # a new dataset needs the lock
            store.ensure_dataset("other", tmp_path, PatchSpec())
    finally:
        other.close()
        store.close()


def test_datasets_come_in_natural_order(store: Store, tmp_path: Path) -> None:
    """`ppd status` listed set 1, set 10, set 11 ... set 19, set 2 (a second black-box review)."""
    for name in ("set 10", "set 2", "set 1", "Alpha", "set 19"):
        store.ensure_dataset(name, tmp_path / name, PatchSpec())
    assert [d["name"] for d in store.datasets()] == ["Alpha", "set 1", "set 2", "set 10", "set 19"]


def test_forget_dataset_removes_its_rows_and_only_the_specs_no_one_else_uses(
    store: Store, tmp_path: Path
) -> None:
    shared, own = PatchSpec(), PatchSpec(patch_size=0.05)
    store.ensure_dataset("a", tmp_path / "a", shared)
    store.ensure_dataset("b", tmp_path / "b", shared)
    store.set_dataset_spec("a", own)  # a's spec now its own; b keeps the shared one
    for name, sha in (("a", "1" * 64), ("a", "2" * 64), ("b", "2" * 64)):
        store.record_file(tmp_path / name / f"{sha[0]}.png", name, FileState.PATCHED, original_sha256=sha,
                          spec_id=store.dataset_spec(name).spec_id, event="patched")  # fmt: skip
    store.add_verification_run("a", "default", "protected", {}, 1.0, 2.0, None, None)
    store.add_auto_decision("a", "x", own, "why", {}, "manual")

    assert store.forget_dataset("a") == 2
    assert store.dataset("a") is None and store.files("a") == [] and store.verification_runs("a") == []
    assert store.events("a") == [] and store.auto_decisions("a") == []
    assert store.pixels_changed_at("a") is None
    with pytest.raises(StoreError):
        store.get_spec(own.spec_id)  # a's alone: gone
    assert store.get_spec(shared.spec_id) == shared  # b's: kept
    assert store.forget_notes() == {"a": ["1" * 64, "2" * 64]}
    assert store.named_originals(["1" * 64, "2" * 64]) == {"2" * 64}  # b's row names it
    store.forget_done("a")
    assert store.forget_notes() == {}
    assert [e["detail"] for e in store.events() if e["kind"] == "dataset_forgotten"] == [
        {"dataset": "a", "files": 2}
    ]
    with pytest.raises(StoreError, match="no dataset 'a'"):
        store.forget_dataset("a")


def test_a_forget_note_left_by_a_crash_joins_the_next_of_its_name(store: Store, tmp_path: Path) -> None:
    """A diff review: a crash before the vault step, then a new dataset of the same name forgotten: its
    note replaced the first (INSERT OR REPLACE), whose originals stayed in the vault, noted nowhere."""
    for sha in ("1" * 64, "2" * 64):  # the first dataset 'a', then a new one of the name
        store.ensure_dataset("a", tmp_path / "a", PatchSpec())
        store.record_file(tmp_path / "a" / f"{sha[0]}.png", "a", FileState.PATCHED, original_sha256=sha,
                          spec_id=store.dataset_spec("a").spec_id, event="patched")  # fmt: skip
        store.forget_dataset("a")  # no forget_done: the crash
    assert store.forget_notes() == {"a": ["1" * 64, "2" * 64]}  # before: {"a": ["2" * 64]}
