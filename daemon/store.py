"""The provenance store: one SQLite file (WAL) that says, for every file ppd has seen, what it
did, with which patch, and what the original was.

Concurrency: the daemon's worker threads and a `ppd status` in another process use it at the
same time. sqlite3 connections are not shareable across threads, so each thread gets its own
connection (thread-local), in autocommit mode; every write that spans statements runs in a
`BEGIN IMMEDIATE` transaction, which takes the write lock up front so SQLite's busy_timeout
applies (a deferred read-then-write transaction can fail with SQLITE_BUSY without waiting).
WAL lets readers proceed while one writer writes.

Schema changes are ordered migrations; `schema_version` holds how many have been applied.
See docs/STORE.md.
"""

from __future__ import annotations

import contextlib
import json
import logging
import sqlite3
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.states import FileState
from poisoner.spec import PatchSpec

if TYPE_CHECKING:
    import sqlite_utils

log = logging.getLogger(__name__)

FILE_STATES: tuple[FileState, ...] = tuple(FileState)
BUSY_TIMEOUT_MS = 30_000

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
    # columns, same ids); the migration runs inside _migrate's one transaction. The literal
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
)
AUTO_TRIGGERS = ("interim", "preflight", "escalation", "manual")
DB_FILE_MODE = 0o600  # provenance names every original: owner only
SCHEMA_VERSION = len(MIGRATIONS)
# PRAGMA quick_check reads every page (~0.75 s for a 100 MB store of 200k files); above this size
# the open skips it and damage is reported by the first query that meets it (same one line).
QUICK_CHECK_MAX_BYTES = 64 << 20
SQLITE_CORRUPT, SQLITE_NOTADB = 11, 26
LOST_NOTE = "lost"


class StoreError(RuntimeError):
    """A store operation that cannot be done as asked (message = one line)."""


class StoreDamaged(StoreError):
    """The store file is not a usable SQLite database; `ppd store rebuild` rebuilds it."""


def damaged_message(db_path: Path, reason: str) -> str:
    return (
        f"the store {db_path} is damaged ({reason}); run `ppd store rebuild` to rebuild it from the vault "
        "and the patched files' markers (it keeps the damaged file aside)"
    )


def is_corruption(exc: sqlite3.Error) -> bool:
    """SQLITE_CORRUPT / SQLITE_NOTADB (and their extended codes): the file itself is bad."""
    code = getattr(exc, "sqlite_errorcode", None)
    if code is not None:
        return code & 0xFF in (SQLITE_CORRUPT, SQLITE_NOTADB)
    text = str(exc)
    return "malformed" in text or "not a database" in text


def vault_holds_originals(vault_dir: Path) -> bool:
    """Whether the vault folder holds at least one kept original (without creating anything)."""
    return any(len(p.name) == 64 for p in Path(vault_dir).glob("??/*"))


class PatchedNotFailed(StoreError):
    """A FAILED was about to overwrite a PATCHED row whose file is, in fact, the patched output."""


class DatasetSpecLocked(StoreError):
    """The dataset already has patched files under its spec; changing it needs --reprotect."""


class Store:
    """Provenance in one SQLite file. Safe to share between threads (one connection each)."""

    def __init__(self, db_path: Path) -> None:
        """Open (creating or migrating) the store at db_path.

        A file that is not a usable database (garbage, truncated, zero pages where pages should
        be) raises StoreDamaged with one line naming the file and `ppd store rebuild`; a store
        that cannot be opened or migrated for another reason raises StoreError (one line)."""
        self.db_path = Path(db_path)
        self._local = threading.local()
        self._all_conns: list[sqlite3.Connection] = []
        self._conns_lock = threading.Lock()
        self.fresh = False  # True when this open created the schema (no store, or an empty file)
        self.lost_warning: str | None = None  # set by open_or_warn / lost_note()
        try:
            self.db_path.parent.mkdir(parents=True, exist_ok=True)
            if self.db_path.exists() and not self.db_path.is_file():
                raise StoreError(f"the store {self.db_path} is not a regular file")
            if self.db_path.is_file() and self.db_path.stat().st_size > 0:
                self._check_pages()  # before any migration writes into a damaged file
            self._migrate()
        except sqlite3.Error as exc:
            self.close()
            raise self._error(exc, "cannot open") from None
        except OSError as exc:
            self.close()
            raise StoreError(f"cannot open the store {self.db_path}: {exc.strerror or exc}") from None
        except StoreError:
            self.close()
            raise
        self._restrict_permissions()

    @classmethod
    def open_or_warn(cls, db_path: Path, vault_dir: Path) -> Store:
        """Open the store; when it is new (missing or empty) while the vault already holds
        originals, the earlier store was lost: record that in the store, log one warning, and
        set `lost_warning`. The note stays (every later open sets `lost_warning` again) until
        `ppd store rebuild` replaces the store, so a restarted daemon keeps saying it."""
        store = cls(db_path)
        if store.fresh and vault_holds_originals(vault_dir):
            message = (
                f"the store {store.db_path} is new but the vault {vault_dir} already holds originals: "
                "the earlier store was lost; run `ppd store rebuild` to recover their rows from the vault "
                "and the patched files' markers"
            )
            with store._write() as conn:
                conn.execute(
                    "INSERT OR IGNORE INTO store_notes (key, value, created_at) VALUES (?, ?, ?)",
                    (LOST_NOTE, message, time.time()),
                )
        store.lost_warning = store.lost_note()
        if store.lost_warning:
            log.warning(store.lost_warning)
        return store

    def lost_note(self) -> str | None:
        """The 'store was lost' note, if this store was created next to a non-empty vault."""
        row = self._one("SELECT value FROM store_notes WHERE key = ?", (LOST_NOTE,))
        return row["value"] if row else None

    def _check_pages(self) -> None:
        """Every page readable (PRAGMA quick_check) for stores up to QUICK_CHECK_MAX_BYTES."""
        if self.db_path.stat().st_size > QUICK_CHECK_MAX_BYTES:
            return
        rows = self.db.conn.execute("PRAGMA quick_check(1)").fetchall()
        if rows != [("ok",)]:
            raise StoreDamaged(damaged_message(self.db_path, str(rows[0][0]).splitlines()[0]))

    def _error(self, exc: sqlite3.Error, doing: str) -> StoreError:
        """One line for an SQLite error: damage names `ppd store rebuild`, the rest says what."""
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if is_corruption(exc):
            return StoreDamaged(damaged_message(self.db_path, text))
        return StoreError(f"{doing} the store {self.db_path}: {text}")

    # ---- connections ----------------------------------------------------------------------
    @property
    def db(self) -> sqlite_utils.Database:
        """This thread's connection."""
        db = getattr(self._local, "db", None)
        if db is None:
            conn = sqlite3.connect(self.db_path, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None)
            with self._conns_lock:  # registered first, so close() reaches it even if a pragma fails
                self._all_conns.append(conn)
            conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
            conn.execute("PRAGMA journal_mode = WAL")
            conn.execute("PRAGMA synchronous = FULL")  # a committed row survives a power cut
            conn.execute("PRAGMA foreign_keys = ON")
            import sqlite_utils  # ~200 ms and 20 MB (it loads numpy): only once the store is opened

            db = sqlite_utils.Database(conn)
            self._local.db = db
        return db

    def _restrict_permissions(self) -> None:
        """The database and its WAL/shared-memory files readable by their owner only.

        Why: SQLite creates them with the umask's mode (often 0644), and the store lists every
        original's path and hash. The -wal/-shm files exist once a connection is open (the
        migration opened one), so all three are checked here; files owned by someone else are
        left alone (chmod would fail) and logged."""
        for suffix in ("", "-wal", "-shm"):
            path = Path(f"{self.db_path}{suffix}")
            try:
                if path.exists() and (path.stat().st_mode & 0o777) != DB_FILE_MODE:
                    path.chmod(DB_FILE_MODE)
            except OSError as exc:
                log.warning("cannot restrict store file mode", extra={"path": str(path), "error": str(exc)})

    def close(self) -> None:
        """Close every thread's connection (call once the threads are done)."""
        with self._conns_lock:
            for conn in self._all_conns:
                with contextlib.suppress(sqlite3.Error):
                    conn.close()
            self._all_conns.clear()
        self._local = threading.local()

    @contextlib.contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        """A write transaction that holds SQLite's write lock from its first statement.

        Damage met inside it becomes StoreDamaged (one line), whatever the statement."""
        with self._damage_as_store_error():
            conn = self.db.conn
            conn.execute("BEGIN IMMEDIATE")
            try:
                yield conn
            except BaseException:
                with contextlib.suppress(sqlite3.Error):  # a damaged file may refuse even this
                    conn.execute("ROLLBACK")
                raise
            conn.execute("COMMIT")

    @contextlib.contextmanager
    def _damage_as_store_error(self) -> Iterator[None]:
        try:
            yield
        except sqlite3.DatabaseError as exc:
            if is_corruption(exc):
                raise StoreDamaged(damaged_message(self.db_path, str(exc).splitlines()[0])) from None
            raise

    def _rows(self, sql: str, params: tuple[Any, ...] | dict[str, Any] = ()) -> list[dict[str, Any]]:
        with self._damage_as_store_error():
            return list(self.db.query(sql, params))

    def _one(self, sql: str, params: tuple[Any, ...] | dict[str, Any] = ()) -> dict[str, Any] | None:
        rows = self._rows(sql, params)
        return rows[0] if rows else None

    # ---- schema ---------------------------------------------------------------------------
    def _migrate(self) -> None:
        with self._write() as conn:
            conn.execute("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)")
            row = conn.execute("SELECT version FROM schema_version").fetchone()
            current = row[0] if row else 0
            if row is None:
                conn.execute("INSERT INTO schema_version (version) VALUES (0)")
            if current > SCHEMA_VERSION:
                raise StoreError(
                    f"{self.db_path} has schema version {current}; this ppd knows up to {SCHEMA_VERSION}"
                )
            self.fresh = current == 0
            for index in range(current, SCHEMA_VERSION):
                # executescript would COMMIT our transaction; run statement by statement.
                for statement in _split_sql(MIGRATIONS[index]):
                    try:
                        conn.execute(statement)
                    except sqlite3.Error as exc:
                        if is_corruption(exc):
                            raise
                        raise StoreError(
                            f"cannot migrate the store {self.db_path} to schema version {index + 1} "
                            f"({str(exc).splitlines()[0]}); it is left as it was"
                        ) from None
                conn.execute("UPDATE schema_version SET version = ?", (index + 1,))
                log.debug("store migrated", extra={"db": str(self.db_path), "version": index + 1})

    def schema_version(self) -> int:
        row = self._one("SELECT version FROM schema_version")
        return int(row["version"]) if row else 0

    # ---- specs ----------------------------------------------------------------------------
    def ensure_spec(self, spec: PatchSpec) -> str:
        with self._write() as conn:
            return self._ensure_spec(conn, spec)

    @staticmethod
    def _ensure_spec(conn: sqlite3.Connection, spec: PatchSpec) -> str:
        conn.execute(
            "INSERT OR IGNORE INTO specs (id, json, version, created_at) VALUES (?, ?, ?, ?)",
            (spec.spec_id, spec.to_json(), spec.version, time.time()),
        )
        return spec.spec_id

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
        with self._write() as conn:
            row = conn.execute("SELECT spec_id FROM datasets WHERE name = ?", (name,)).fetchone()
            if row is None:
                self._ensure_spec(conn, spec)
                conn.execute(
                    "INSERT INTO datasets (name, root, spec_id, created_at, publish_dir) "
                    "VALUES (?, ?, ?, ?, ?)",
                    (name, str(root), spec.spec_id, time.time(), str(publish_dir) if publish_dir else None),
                )
                self._event(conn, name, None, "dataset_created", {"root": str(root), "spec_id": spec.spec_id})
            elif row[0] is None:
                self._ensure_spec(conn, spec)
                conn.execute("UPDATE datasets SET spec_id = ? WHERE name = ?", (spec.spec_id, name))
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
            spec_id = self._ensure_spec(conn, spec) if spec is not None else None
            conn.execute(
                "INSERT INTO datasets (name, root, spec_id, created_at, publish_dir) VALUES (?, ?, ?, ?, ?)",
                (name, str(root), spec_id, time.time(), str(publish_dir) if publish_dir else None),
            )
            self._event(conn, name, None, event, {"root": str(root), "spec_id": spec_id, **(detail or {})})
        return True

    def dataset(self, name: str) -> dict[str, Any] | None:
        return self._one("SELECT * FROM datasets WHERE name = ?", (name,))

    def datasets(self) -> list[dict[str, Any]]:
        return self._rows("SELECT * FROM datasets ORDER BY name")

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
            self._ensure_spec(conn, spec)
            if row is None:
                if root is None:
                    raise StoreError(f"no dataset {name!r}; give its root folder")
                conn.execute(
                    "INSERT INTO datasets (name, root, spec_id, created_at) VALUES (?, ?, ?, ?)",
                    (name, str(root), spec.spec_id, time.time()),
                )
            elif row[0] != spec.spec_id:
                patched = conn.execute(
                    "SELECT COUNT(*) FROM files WHERE dataset = ? AND state IN (?, ?)",
                    (name, FileState.PATCHED, FileState.PENDING),
                ).fetchone()[0]
                if patched and not allow_protected:
                    raise DatasetSpecLocked(
                        f"dataset {name!r} has {patched} patched file(s) under spec {row[0]}; "
                        f"changing it needs a re-protect from the vault "
                        f"(ppd dataset set {name} ... --reprotect)"
                    )
                conn.execute("UPDATE datasets SET spec_id = ? WHERE name = ?", (spec.spec_id, name))
            self._event(
                conn, name, None, "spec_set", {"spec_id": spec.spec_id, "previous": row[0] if row else None}
            )

    def set_dataset_publish_dir(self, name: str, publish_dir: Path | None) -> None:
        with self._write() as conn:
            conn.execute(
                "UPDATE datasets SET publish_dir = ? WHERE name = ?",
                (str(publish_dir) if publish_dir else None, name),
            )

    # ---- files ----------------------------------------------------------------------------
    def file(self, path: Path | str) -> dict[str, Any] | None:
        return self._one("SELECT * FROM files WHERE path = ?", (str(path),))

    def files(self, dataset: str, state: FileState | str | None = None) -> list[dict[str, Any]]:
        """A dataset's rows by path; an unknown state raises StoreError (an old word such as
        'protected' would otherwise match nothing, silently)."""
        if state is None:
            return self._rows("SELECT * FROM files WHERE dataset = ? ORDER BY path", (dataset,))
        return self._rows(
            "SELECT * FROM files WHERE dataset = ? AND state = ? ORDER BY path",
            (dataset, _file_state(state).value),
        )

    def find_poisoned(self, sha256: str) -> dict[str, Any] | None:
        """A row whose patched output has this content (ppd's own output, anywhere)."""
        return self._one("SELECT * FROM files WHERE poisoned_sha256 = ? LIMIT 1", (sha256,))

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
        **fields: Any,
    ) -> None:
        """Insert or update the row for path (and optionally log an event), in one transaction.

        current_sha256, when the caller knows the file's content now: a FAILED for a row that
        is PATCHED with exactly that content as its poisoned_sha256 is refused (StoreError), in
        the same transaction as the write. The file *is* ppd's patched output; recording it as
        failed would make `ppd restore` skip it and a later run patch it twice."""
        state = _file_state(state)
        _check_fields(fields)
        with self._write() as conn:
            self._upsert_file(conn, path, dataset, state, fields, current_sha256)
            if event:
                self._event(conn, dataset, str(path), event, detail or {})

    def record_files(self, rows: Iterable[tuple[Path | str, str, FileState | str, dict[str, Any]]]) -> int:
        """Insert or update many (path, dataset, state, fields) rows in one transaction (one
        fsync, not one per row: a rebuild writes thousands); returns how many."""
        checked = []
        for path, dataset, state, fields in rows:
            _check_fields(fields)
            checked.append((path, dataset, _file_state(state), fields))
        with self._write() as conn:
            for path, dataset, state, fields in checked:
                self._upsert_file(conn, path, dataset, state, fields, None)
        return len(checked)

    def _upsert_file(
        self,
        conn: sqlite3.Connection,
        path: Path | str,
        dataset: str,
        state: FileState,
        fields: dict[str, Any],
        current_sha256: str | None,
    ) -> None:
        if state is FileState.FAILED and current_sha256 is not None:
            row = conn.execute(
                "SELECT state, poisoned_sha256 FROM files WHERE path = ?", (str(path),)
            ).fetchone()
            if row is not None and row[0] == FileState.PATCHED and row[1] == current_sha256:
                raise PatchedNotFailed(
                    f"{path} is ppd's patched output (sha256 {current_sha256[:12]}); "
                    "not recording it as failed, its row stays patched"
                )
        now = time.time()
        values = {"dataset": dataset, "state": state.value, "updated_at": now, **fields}
        columns = ", ".join(values)
        marks = ", ".join("?" for _ in values)
        updates = ", ".join(f"{c} = excluded.{c}" for c in values)
        conn.execute(
            f"INSERT INTO files (path, created_at, {columns}) VALUES (?, ?, {marks}) "
            f"ON CONFLICT(path) DO UPDATE SET {updates}",
            (str(path), now, *values.values()),
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

    # ---- events ---------------------------------------------------------------------------
    def add_event(
        self, dataset: str | None, path: Path | str | None, kind: str, detail: dict[str, Any]
    ) -> None:
        with self._write() as conn:
            self._event(conn, dataset, str(path) if path is not None else None, kind, detail)

    @staticmethod
    def _event(
        conn: sqlite3.Connection, dataset: str | None, path: str | None, kind: str, detail: dict[str, Any]
    ) -> None:
        conn.execute(
            "INSERT INTO events (ts, dataset, path, kind, detail) VALUES (?, ?, ?, ?, ?)",
            (time.time(), dataset, path, kind, json.dumps(detail, default=str, sort_keys=True)),
        )

    def events(self, dataset: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        if dataset is None:
            rows = self._rows("SELECT * FROM events ORDER BY id DESC LIMIT ?", (limit,))
        else:
            rows = self._rows(
                "SELECT * FROM events WHERE dataset = ? ORDER BY id DESC LIMIT ?", (dataset, limit)
            )
        for row in rows:
            row["detail"] = json.loads(row["detail"]) if row["detail"] else {}
        return rows

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
            self._event(
                conn,
                dataset,
                None,
                "verification",
                {"run_id": run_id, "profile": profile, "verdict": verdict},
            )
        return run_id

    def verification_runs(self, dataset: str, limit: int = 20) -> list[dict[str, Any]]:
        """Newest first."""
        rows = self._rows(
            "SELECT * FROM verification_runs WHERE dataset = ? ORDER BY finished_at DESC, id DESC LIMIT ?",
            (dataset, limit),
        )
        for row in rows:
            row["metrics"] = json.loads(row["metrics"]) if row["metrics"] else {}
        return rows

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
            spec_id = self._ensure_spec(conn, spec) if spec is not None else None
            cursor = conn.execute(
                "INSERT INTO auto_decisions (dataset, decided_at, candidate, spec_id, reason, evidence, "
                "trigger) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (dataset, time.time(), candidate, spec_id, reason,
                 json.dumps(evidence, default=str, sort_keys=True), trigger),
            )  # fmt: skip
            decision_id = int(cursor.lastrowid or 0)
            self._event(
                conn, dataset, None, "auto_decision",
                {"id": decision_id, "candidate": candidate, "spec_id": spec_id, "trigger": trigger},
            )  # fmt: skip
        return decision_id

    def auto_decisions(self, dataset: str, limit: int = 20) -> list[dict[str, Any]]:
        """Newest first; evidence parsed."""
        rows = self._rows(
            "SELECT * FROM auto_decisions WHERE dataset = ? ORDER BY decided_at DESC, id DESC LIMIT ?",
            (dataset, limit),
        )
        for row in rows:
            row["evidence"] = json.loads(row["evidence"]) if row["evidence"] else {}
        return rows

    def latest_auto_decision(self, dataset: str) -> dict[str, Any] | None:
        rows = self.auto_decisions(dataset, limit=1)
        return rows[0] if rows else None


FILE_FIELDS = frozenset(
    {
        "original_sha256",
        "poisoned_sha256",
        "spec_id",
        "tool_version",
        "size",
        "mtime_ns",
        "error",
        "published_path",
    }
)


def _file_state(state: FileState | str) -> FileState:
    try:
        return FileState(state)
    except ValueError:
        raise StoreError(f"unknown file state {state!r}; one of {', '.join(FILE_STATES)}") from None


def _check_fields(fields: dict[str, Any]) -> None:
    unknown = set(fields) - FILE_FIELDS
    if unknown:
        raise StoreError(f"unknown file field(s): {', '.join(sorted(unknown))}")


def _split_sql(script: str) -> list[str]:
    """Statements of a migration script (ours contain no ';' inside literals)."""
    statements = []
    for chunk in script.split(";"):
        lines = [line.split("--", 1)[0] for line in chunk.splitlines()]
        text = "\n".join(lines).strip()
        if text:
            statements.append(text)
    return statements
