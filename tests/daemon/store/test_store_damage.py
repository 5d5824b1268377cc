"""A damaged or lost store on real SQLite files: one line naming the file and `ppd store rebuild`,
never a traceback; a lost store next to a vault of originals is noticed and stays noticed."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

import daemon.store.damage
from daemon.states import FileState
from daemon.store import SCHEMA_VERSION, Store, StoreDamaged, StoreError
from poisoner.spec import PatchSpec

ROOT = Path(__file__).resolve().parents[3]
ROWS = 2000


def _store_with_rows(db: Path, rows: int = ROWS) -> None:
    store = Store(db)
    store.ensure_dataset("d", Path("/r"), PatchSpec())
    with store._write() as conn:
        for i in range(rows):
            conn.execute(
                "INSERT INTO files (dataset, path, state, original_sha256, created_at, updated_at) "
                "VALUES ('d', ?, ?, ?, 1, 1)",
                (f"/r/{i}.jpg", FileState.PATCHED.value, f"{i:064x}"),
            )
    store.close()  # the last connection checkpoints the WAL into the main file
    assert not Path(f"{db}-wal").exists() or Path(f"{db}-wal").stat().st_size == 0


def _assert_one_line_naming(exc: StoreError, db: Path) -> None:
    message = str(exc)
    assert "\n" not in message and str(db) in message
    assert "`ppd store rebuild`" in message


def _vault_with_one_original(folder: Path) -> Path:
    sha = "ab" + "0" * 62
    (folder / "ab").mkdir(parents=True)
    (folder / "ab" / sha).write_bytes(b"an original")
    return folder


def test_zero_length_store_opens_as_a_fresh_store(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    db.write_bytes(b"")
    store = Store(db)
    assert store.fresh and store.schema_version() == SCHEMA_VERSION
    store.close()
    again = Store(db)
    assert not again.fresh
    again.close()


@pytest.mark.parametrize(
    "content", [b"garbage " * 1000, os.urandom(8192), b"SQLite format 3\0" + b"\xff" * 4000]
)
def test_garbage_is_one_line_that_names_the_file(tmp_path: Path, content: bytes) -> None:
    db = tmp_path / "ppd.sqlite3"
    db.write_bytes(content)
    with pytest.raises(StoreDamaged) as caught:
        Store(db)
    _assert_one_line_naming(caught.value, db)
    assert db.read_bytes() == content  # opening a damaged store never rewrites it


@pytest.mark.parametrize("keep", [100, 4096, 0.1, 0.5, 0.9, 0.99])
def test_truncated_store_opens_whole_or_says_damaged(tmp_path: Path, keep: float) -> None:
    db = tmp_path / "ppd.sqlite3"
    _store_with_rows(db)
    data = db.read_bytes()
    cut = keep if isinstance(keep, int) else int(len(data) * keep)
    db.write_bytes(data[:cut])
    try:
        store = Store(db)
    except StoreDamaged as exc:
        _assert_one_line_naming(exc, db)
        return
    # SQLite opened it: then every row it gives back is readable and the pages are sound
    assert store.db.execute("PRAGMA quick_check").fetchall() == [("ok",)]
    assert len(store.files("d")) <= ROWS
    store.close()


def test_half_a_store_is_damaged(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    _store_with_rows(db)
    data = db.read_bytes()
    db.write_bytes(data[: len(data) // 2])
    with pytest.raises(StoreDamaged) as caught:
        Store(db)
    _assert_one_line_naming(caught.value, db)


def test_a_scribbled_page_is_found_at_open(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    _store_with_rows(db)
    with open(db, "r+b") as fh:  # a middle page (not the first: the schema still reads)
        fh.seek(db.stat().st_size // 2 // 4096 * 4096)
        fh.write(os.urandom(4096))
    with pytest.raises(StoreDamaged) as caught:
        Store(db)
    _assert_one_line_naming(caught.value, db)


def _middle_page_of_files(db: Path) -> int:
    """The middle page of the files table (the file's middle page may be an index's, which the queries
    below never read: a column added by a migration moved it there)."""
    conn = sqlite3.connect(db)
    try:
        pages = [p for (p,) in conn.execute("SELECT pageno FROM dbstat WHERE name = 'files' ORDER BY pageno")]
    finally:
        conn.close()
    return pages[len(pages) // 2]


def test_damage_met_after_the_open_is_one_line_too(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Stores above QUICK_CHECK_MAX_BYTES are not page-checked at open: the first query that meets
    the damage says it, in the same one line."""
    db = tmp_path / "ppd.sqlite3"
    _store_with_rows(db)
    with open(db, "r+b") as fh:
        fh.seek((_middle_page_of_files(db) - 1) * 4096)
        fh.write(os.urandom(4096))
    monkeypatch.setattr(daemon.store.damage, "QUICK_CHECK_MAX_BYTES", 0)
    store = Store(db)
    with pytest.raises(StoreDamaged) as caught:
        for i in range(ROWS):
            store.file(f"/r/{i}.jpg")
        store.files("d")
    _assert_one_line_naming(caught.value, db)
    with pytest.raises(StoreDamaged):
        store.record_file("/r/new.jpg", "d", FileState.PENDING)
    store.close()


def test_a_folder_where_the_store_should_be(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    db.mkdir()
    with pytest.raises(StoreError, match="not a regular file") as caught:
        Store(db)
    assert "\n" not in str(caught.value)


KILLED_WRITER = """
import os, signal, sys
from pathlib import Path
from daemon.store import Store
from daemon.states import FileState
from poisoner.spec import PatchSpec
db, first, rows = Path(sys.argv[1]), sys.argv[2] == "first", int(sys.argv[3])
store = Store(db)
store.ensure_dataset("d", Path("/r"), PatchSpec())
if first:
    store.close()  # checkpointed: the schema and the dataset are in the main file
    store = Store(db)
store.db.execute("PRAGMA wal_autocheckpoint = 0")  # nothing more reaches the main file
for i in range(rows):
    store.record_file(f"/r/{i}.jpg", "d", FileState.PATCHED, original_sha256=f"{i:064x}")
os.kill(os.getpid(), signal.SIGKILL)
"""


def _killed_writer(db: Path, *, checkpoint_first: bool, rows: int = 50) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = [sys.executable, "-c", KILLED_WRITER, str(db), "first" if checkpoint_first else "-", str(rows)]
    done = subprocess.run(args, env=env, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == -signal.SIGKILL, done.stderr
    assert Path(f"{db}-wal").stat().st_size > 0  # the rows are in the WAL only


def test_a_kill_keeps_every_committed_row_when_the_wal_survives(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    _killed_writer(db, checkpoint_first=True)
    store = Store(db)
    assert store.counts("d")[FileState.PATCHED] == 50
    store.close()


@pytest.mark.parametrize("checkpoint_first", [True, False], ids=["schema-checkpointed", "all-in-wal"])
def test_wal_and_shm_deleted_after_a_kill(tmp_path: Path, checkpoint_first: bool) -> None:
    """The rows that lived only in the WAL are gone (SQLite cannot know them); the store opens
    sound, and when nothing but an empty file is left while the vault holds originals, the loss
    is noticed."""
    db = tmp_path / "ppd.sqlite3"
    vault = _vault_with_one_original(tmp_path / "vault")
    _killed_writer(db, checkpoint_first=checkpoint_first)
    Path(f"{db}-wal").unlink()
    Path(f"{db}-shm").unlink(missing_ok=True)
    store = Store.open_or_warn(db, vault)
    assert store.db.execute("PRAGMA quick_check").fetchall() == [("ok",)]
    assert store.schema_version() == SCHEMA_VERSION
    if checkpoint_first:
        assert [d["name"] for d in store.datasets()] == ["d"] and store.files("d") == []
        assert not store.fresh and store.lost_warning is None
    else:
        assert store.fresh and store.datasets() == []
        assert store.lost_warning is not None and "`ppd store rebuild`" in store.lost_warning
    store.close()


def test_a_missing_store_next_to_a_vault_of_originals_is_noticed_until_rebuilt(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    vault = _vault_with_one_original(tmp_path / "vault")
    store = Store.open_or_warn(db, vault)
    assert store.fresh
    warning = store.lost_warning
    assert warning is not None and "\n" not in warning
    assert str(db) in warning and str(vault) in warning and "`ppd store rebuild`" in warning
    store.close()
    again = Store.open_or_warn(db, vault)  # a restarted daemon keeps saying it
    assert not again.fresh and again.lost_warning == warning
    again.close()
    plain = Store(db)
    assert plain.lost_note() == warning
    plain.close()


def test_a_new_store_with_an_empty_vault_is_not_a_lost_one(tmp_path: Path) -> None:
    (tmp_path / "vault" / "specs").mkdir(parents=True)  # specs alone are not originals
    (tmp_path / "vault" / "specs" / "abc.json").write_text("{}")
    store = Store.open_or_warn(tmp_path / "ppd.sqlite3", tmp_path / "vault")
    assert store.fresh and store.lost_warning is None and store.lost_note() is None
    store.close()


def test_an_old_store_opened_next_to_a_vault_is_not_lost(tmp_path: Path) -> None:
    db = tmp_path / "ppd.sqlite3"
    _store_with_rows(db, rows=3)
    vault = _vault_with_one_original(tmp_path / "vault")
    store = Store.open_or_warn(db, vault)
    assert not store.fresh and store.lost_warning is None
    store.close()
    conn = sqlite3.connect(db)
    assert conn.execute("SELECT COUNT(*) FROM store_notes").fetchone()[0] == 0
    conn.close()
