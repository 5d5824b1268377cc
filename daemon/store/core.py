"""Store: opening (creating, checking, migrating) the provenance store, and the class that puts
its row kinds together."""

from __future__ import annotations

import logging
import sqlite3
import time
from pathlib import Path

from daemon.store.damage import LOST_NOTE, check_pages, lost_message, vault_holds_originals
from daemon.store.datasets import DatasetRows
from daemon.store.errors import StoreError
from daemon.store.event_log import EventRows
from daemon.store.files import FileRows
from daemon.store.schema import migrate
from daemon.store.verification import VerificationRows

log = logging.getLogger("daemon.store")


class Store(FileRows, DatasetRows, EventRows, VerificationRows):
    """Provenance in one SQLite file. Safe to share between threads (one connection each)."""

    def __init__(self, db_path: Path) -> None:
        """Open (creating or migrating) the store at db_path.

        A file that is not a usable database (garbage, truncated, zero pages where pages should
        be) raises StoreDamaged with one line naming the file and `ppd store rebuild`; a store
        that cannot be opened or migrated for another reason raises StoreError (one line)."""
        self._init_connections(db_path)
        self.fresh = False  # True when this open created the schema (no store, or an empty file)
        self.lost_warning: str | None = None  # set by open_or_warn / lost_note()
        try:
            self.db_path.parent.mkdir(parents=True, exist_ok=True)
            if self.db_path.exists() and not self.db_path.is_file():
                raise StoreError(f"the store {self.db_path} is not a regular file")
            if self.db_path.is_file() and self.db_path.stat().st_size > 0:
                check_pages(self.conn, self.db_path)  # before any migration writes into a damaged file
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
            with store._write() as conn:
                conn.execute(
                    "INSERT OR IGNORE INTO store_notes (key, value, created_at) VALUES (?, ?, ?)",
                    (LOST_NOTE, lost_message(store.db_path, vault_dir), time.time()),
                )
        store.lost_warning = store.lost_note()
        if store.lost_warning:
            log.warning(store.lost_warning)
        return store

    def lost_note(self) -> str | None:
        """The 'store was lost' note, if this store was created next to a non-empty vault."""
        row = self._one("SELECT value FROM store_notes WHERE key = ?", (LOST_NOTE,))
        return row["value"] if row else None

    def _migrate(self) -> None:
        with self._write() as conn:
            self.fresh = migrate(conn, self.db_path) == 0

    def schema_version(self) -> int:
        row = self._one("SELECT version FROM schema_version")
        return int(row["version"]) if row else 0

    def file_count(self) -> int:
        """How many file rows the store holds, whatever their dataset or state."""
        row = self._one("SELECT COUNT(*) AS n FROM files")
        return int(row["n"]) if row else 0
