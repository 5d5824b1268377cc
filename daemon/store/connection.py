"""One SQLite connection per thread, write transactions that take the lock up front, and rows as
dicts. The row kinds (files, datasets, events, verification) build on StoreBase.

sqlite3 connections are not shareable across threads, so each thread gets its own, in autocommit
mode; every write that spans statements runs in `BEGIN IMMEDIATE`, which takes the write lock up
front so SQLite's busy_timeout applies (a deferred read-then-write transaction can fail with
SQLITE_BUSY without waiting). WAL lets readers proceed while one writer writes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.store.damage import damaged_message, is_corruption
from daemon.store.errors import StoreDamaged, StoreError

if TYPE_CHECKING:
    import sqlite_utils

log = logging.getLogger("daemon.store")

BUSY_TIMEOUT_MS = 30_000
DB_FILE_MODE = 0o600  # provenance names every original: owner only
SQLITE_SUFFIXES = ("", "-wal", "-shm")  # the database and the files SQLite keeps beside it


class StoreBase:
    """Connections, transactions and row reads shared by the store's row kinds."""

    db_path: Path

    def _init_connections(self, db_path: Path) -> None:
        self.db_path = Path(db_path)
        self._local = threading.local()
        self._all_conns: list[sqlite3.Connection] = []
        self._conns_lock = threading.Lock()
        # Set by the first damage any thread meets: later writes refuse with the same line rather
        # than write more into a file known to be bad (`ppd store rebuild` is the way out).
        self._damage: str | None = None

    @property
    def conn(self) -> sqlite3.Connection:
        """This thread's connection (autocommit, WAL, busy timeout, foreign keys)."""
        conn = getattr(self._local, "conn", None)
        if conn is None:
            conn = sqlite3.connect(self.db_path, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None)
            with self._conns_lock:  # registered first, so close() reaches it even if a pragma fails
                self._all_conns.append(conn)
            conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
            conn.execute("PRAGMA journal_mode = WAL")
            conn.execute("PRAGMA synchronous = FULL")  # a committed row survives a power cut
            conn.execute("PRAGMA foreign_keys = ON")
            self._local.conn = conn
        return conn

    @property
    def db(self) -> sqlite_utils.Database:
        """This thread's connection as a sqlite_utils Database, for callers that want its helpers."""
        db = getattr(self._local, "db", None)
        if db is None:
            # ~140 ms and numpy: imported by whoever asks for it, never by opening or querying the store
            import sqlite_utils

            db = sqlite_utils.Database(self.conn)
            self._local.db = db
        return db

    def _restrict_permissions(self) -> None:
        """The database and its WAL/shared-memory files readable by their owner only.

        Why: SQLite creates them with the umask's mode (often 0644), and the store lists every
        original's path and hash. The -wal/-shm files exist once a connection is open (the
        migration opened one), so all three are checked here; files owned by someone else are
        left alone (chmod would fail) and logged."""
        for suffix in SQLITE_SUFFIXES:
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
    def _write(self, durable: bool = True) -> Iterator[sqlite3.Connection]:
        """A write transaction that holds SQLite's write lock from its first statement.

        durable=False: the commit is appended to the WAL without an fsync (synchronous=NORMAL for
        this transaction only): it survives the process being killed, not a power cut, and the next
        durable commit (or checkpoint) makes it durable too, in order. For a row whose loss at a
        power cut the caller can recover from (the protect stages' 'pending' row).
        Damage met inside it becomes StoreDamaged (one line), whatever the statement."""
        if self._damage is not None:
            raise StoreDamaged(self._damage)
        with self._damage_as_store_error():
            conn = self.conn
            if not durable:
                conn.execute("PRAGMA synchronous = NORMAL")
            try:
                conn.execute("BEGIN IMMEDIATE")
                try:
                    yield conn
                except BaseException:
                    with contextlib.suppress(sqlite3.Error):  # a damaged file may refuse even this
                        conn.execute("ROLLBACK")
                    raise
                conn.execute("COMMIT")
            finally:
                if not durable:
                    with contextlib.suppress(sqlite3.Error):
                        conn.execute("PRAGMA synchronous = FULL")

    @contextlib.contextmanager
    def _damage_as_store_error(self) -> Iterator[None]:
        try:
            yield
        except sqlite3.DatabaseError as exc:
            if is_corruption(exc):
                self._damage = damaged_message(self.db_path, str(exc).splitlines()[0])
                raise StoreDamaged(self._damage) from None
            raise

    def _error(self, exc: sqlite3.Error, doing: str) -> StoreError:
        """One line for an SQLite error: damage names `ppd store rebuild`, the rest says what."""
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if is_corruption(exc):
            return StoreDamaged(damaged_message(self.db_path, text))
        if _disk_full(self.db_path.parent):  # SQLite says "disk I/O error", which reads as failing hardware
            return StoreError(f"{doing} the store {self.db_path}: the disk holding it is full; free space, "
                              "then run the same command again")  # fmt: skip
        return StoreError(f"{doing} the store {self.db_path}: {text}")

    def _rows(self, sql: str, params: tuple[Any, ...] | dict[str, Any] = ()) -> list[dict[str, Any]]:
        """Every row of a query as {column: value} (what sqlite_utils' query gives, without it)."""
        with self._damage_as_store_error():
            try:
                cursor = self.conn.execute(sql, params)
            except UnicodeEncodeError:  # a path that is not valid UTF-8 (daemon.fsops.storable):
                if sql.lstrip().upper().startswith("SELECT"):  # no row can hold it, none matches
                    return []
                raise StoreError("a file name that is not valid UTF-8 cannot be recorded") from None
            keys = [d[0] for d in cursor.description]
            return [dict(zip(keys, row, strict=True)) for row in cursor]

    def _one(self, sql: str, params: tuple[Any, ...] | dict[str, Any] = ()) -> dict[str, Any] | None:
        rows = self._rows(sql, params)
        return rows[0] if rows else None


def _disk_full(folder: Path) -> bool:
    """Whether the filesystem holding folder has no block left for this user (a black-box review)."""
    try:
        return os.statvfs(folder).f_bavail == 0
    except OSError:
        return False
