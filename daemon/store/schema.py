"""The store's schema: ordered migrations, and applying them inside one write transaction.

`schema_version` holds how many migrations have been applied (docs/STORE.md).
"""

from __future__ import annotations

import logging
import sqlite3
from pathlib import Path

from daemon.store.damage import is_corruption
from daemon.store.errors import StoreError, StoreTooNew

log = logging.getLogger("daemon.store")

# Ordered migrations: index i brings the schema from version i to i + 1. Never edit one that
# has shipped; append a new one.
MIGRATIONS: tuple[str, ...] = (
    """
    CREATE TABLE specs (
        id TEXT PRIMARY KEY,               -- PatchSpec.spec_id (content hash)
        json TEXT NOT NULL,
        version INTEGER NOT NULL,
        created_at REAL NOT NULL
    );
    CREATE TABLE datasets (
        name TEXT PRIMARY KEY,
        root TEXT NOT NULL,
        spec_id TEXT REFERENCES specs(id),
        created_at REAL NOT NULL,
        publish_dir TEXT
    );
    CREATE TABLE files (
        id INTEGER PRIMARY KEY,
        dataset TEXT NOT NULL REFERENCES datasets(name),
        path TEXT NOT NULL UNIQUE,
        state TEXT NOT NULL CHECK (state IN
            ('pending', 'protected', 'skipped', 'failed', 'restored', 'removed')),
        original_sha256 TEXT,
        poisoned_sha256 TEXT,
        spec_id TEXT,
        tool_version TEXT,
        size INTEGER,
        mtime_ns INTEGER,
        created_at REAL NOT NULL,
        updated_at REAL NOT NULL,
        error TEXT
    );
    CREATE INDEX files_dataset_state ON files(dataset, state);
    CREATE INDEX files_poisoned_sha ON files(poisoned_sha256);
    CREATE TABLE events (
        id INTEGER PRIMARY KEY,
        ts REAL NOT NULL,
        dataset TEXT,
        path TEXT,
        kind TEXT NOT NULL,
        detail TEXT                         -- JSON
    );
    CREATE INDEX events_dataset_ts ON events(dataset, ts);
    CREATE TABLE verification_runs (
        id INTEGER PRIMARY KEY,
        dataset TEXT NOT NULL,
        profile TEXT NOT NULL,
        verdict TEXT NOT NULL,
        metrics TEXT NOT NULL,              -- JSON
        started_at REAL NOT NULL,
        finished_at REAL NOT NULL,
        model_dir TEXT,
        error TEXT
    );
    CREATE INDEX verification_runs_dataset ON verification_runs(dataset, finished_at);
    """,
    # 2: where a protected file was moved to when the dataset has a publish_dir.
    "ALTER TABLE files ADD COLUMN published_path TEXT;",
    # 3: automatic mode's decisions (docs/AUTO.md): which candidate a dataset runs and why.
    """
    CREATE TABLE auto_decisions (
        id INTEGER PRIMARY KEY,
        dataset TEXT NOT NULL,
        decided_at REAL NOT NULL,
        candidate TEXT,                     -- ladder candidate name, NULL when none qualifies
        spec_id TEXT REFERENCES specs(id),
        reason TEXT NOT NULL,
        evidence TEXT NOT NULL,             -- JSON
        trigger TEXT NOT NULL CHECK (trigger IN ('interim', 'preflight', 'escalation', 'manual'))
    );
    CREATE INDEX auto_decisions_dataset ON auto_decisions(dataset, decided_at);
    """,
    # 4: one vocabulary of states (daemon/states.py): a file ppd wrote its mark into is 'patched'
    # (was 'protected'), and a file moved out of the outbox because it could not be patched is
    # 'quarantined'. SQLite cannot alter a CHECK constraint, so the table is rebuilt (same
    # columns, same ids); the migration runs inside migrate()'s one transaction. The literal
    # states here are history: never generate them from FileState.
    """
    CREATE TABLE files_v4 (
        id INTEGER PRIMARY KEY,
        dataset TEXT NOT NULL REFERENCES datasets(name),
        path TEXT NOT NULL UNIQUE,
        state TEXT NOT NULL CHECK (state IN
            ('pending', 'patched', 'skipped', 'failed', 'restored', 'removed', 'quarantined')),
        original_sha256 TEXT,
        poisoned_sha256 TEXT,
        spec_id TEXT,
        tool_version TEXT,
        size INTEGER,
        mtime_ns INTEGER,
        created_at REAL NOT NULL,
        updated_at REAL NOT NULL,
        error TEXT,
        published_path TEXT
    );
    INSERT INTO files_v4 (id, dataset, path, state, original_sha256, poisoned_sha256, spec_id,
        tool_version, size, mtime_ns, created_at, updated_at, error, published_path)
    SELECT id, dataset, path, CASE state WHEN 'protected' THEN 'patched' ELSE state END,
        original_sha256, poisoned_sha256, spec_id, tool_version, size, mtime_ns, created_at,
        updated_at, error, published_path
    FROM files;
    DROP TABLE files;
    ALTER TABLE files_v4 RENAME TO files;
    CREATE INDEX files_dataset_state ON files(dataset, state);
    CREATE INDEX files_poisoned_sha ON files(poisoned_sha256);
    CREATE INDEX files_original_sha ON files(original_sha256);
    UPDATE events SET kind = 'patched' WHERE kind = 'protected';
    """,
    # 5: notes the store keeps about itself; 'lost' says it was created empty next to a vault that
    # already held originals (the earlier store was lost), until `ppd store rebuild` replaces it.
    """
    CREATE TABLE store_notes (
        key TEXT PRIMARY KEY,
        value TEXT NOT NULL,
        created_at REAL NOT NULL
    );
    """,
    # 6 (issue 25): the dataset's subject-mask folder, remembered so that a later `ppd poison --force`
    # or the daemon keeps the mark off the subject without the flag being repeated.
    "ALTER TABLE datasets ADD COLUMN subject_masks TEXT;",
    # 7: the original's modification time, which restore gives back: two files with the same bytes
    # share one vault blob, whose date is the first one kept (a black-box review: restore gave the
    # second file the first one's date). NULL: unknown, the blob's date is used.
    "ALTER TABLE files ADD COLUMN original_mtime_ns INTEGER;",
    # 8: the originals a dataset's files held before their current ones (a photo edited and patched
    # again under its name): no row names them, yet they stay in the vault (`ppd restore` of a copy
    # published before the edit needs one), and `ppd dataset forget` must find them (a diff review:
    # they stayed for good).
    """
    CREATE TABLE earlier_originals (
        dataset TEXT NOT NULL,
        sha256 TEXT NOT NULL,
        replaced_at REAL NOT NULL,
        PRIMARY KEY (dataset, sha256)
    );
    CREATE INDEX earlier_originals_sha ON earlier_originals(sha256);
    """,
    # 9: 1 when the file's bytes (poisoned_sha256) are ppd's output saved again by another program (a
    # tagger's keywords, a re-encode): its picture carries ppd's mark, its bytes are the creator's, and
    # `ppd restore` keeps them (refused without --force, set aside with it). A black-box review: restore
    # wrote the original over the rated file and kept no copy.
    "ALTER TABLE files ADD COLUMN resaved INTEGER;",
    # 10: the original the path held when another file was saved over ppd's patched photo and patched as
    # a new one (an edit of the marked photo, or another photo): the current original may carry ppd's
    # mark, and this is the photo from before, which `ppd restore` names (the review's F1).
    "ALTER TABLE files ADD COLUMN saved_over TEXT;",
)
SCHEMA_VERSION = len(MIGRATIONS)
AUTO_TRIGGERS = ("interim", "preflight", "escalation", "manual")  # auto_decisions.trigger's CHECK


def migrate(conn: sqlite3.Connection, db_path: Path) -> int:
    """Bring the schema up to SCHEMA_VERSION inside the caller's transaction; returns the version
    found (0: a new store). A newer store, or a migration that fails, raises StoreError (the
    caller's rollback leaves the file as it was); damage propagates as the sqlite3 error."""
    conn.execute("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)")
    row = conn.execute("SELECT version FROM schema_version").fetchone()
    current = row[0] if row else 0
    if row is None:
        conn.execute("INSERT INTO schema_version (version) VALUES (0)")
    if current > SCHEMA_VERSION:  # after a downgrade: said as such, with the way forward (a black-box review)
        raise StoreTooNew(
            f"the store {db_path} was made by a newer ppd (schema version {current}; this ppd knows up to "
            f"{SCHEMA_VERSION}): upgrade ppd to open it (`pipx upgrade patchpoison`, or `pipx install "
            "--force` with the newer ppd's wheel)"
        )
    for index in range(current, SCHEMA_VERSION):
        _apply(conn, db_path, index)
        conn.execute("UPDATE schema_version SET version = ?", (index + 1,))
        log.debug("store migrated", extra={"db": str(db_path), "version": index + 1})
    return current


def _apply(conn: sqlite3.Connection, db_path: Path, index: int) -> None:
    # executescript would COMMIT the caller's transaction; run statement by statement.
    for statement in split_sql(MIGRATIONS[index]):
        try:
            conn.execute(statement)
        except sqlite3.Error as exc:
            if is_corruption(exc):
                raise
            raise StoreError(
                f"cannot migrate the store {db_path} to schema version {index + 1} "
                f"({str(exc).splitlines()[0]}); it is left as it was"
            ) from None


def split_sql(script: str) -> list[str]:
    """Statements of a migration script (ours contain no ';' inside literals)."""
    statements = []
    for chunk in script.split(";"):
        lines = [line.split("--", 1)[0] for line in chunk.splitlines()]
        text = "\n".join(lines).strip()
        if text:
            statements.append(text)
    return statements
