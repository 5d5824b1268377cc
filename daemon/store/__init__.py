"""The provenance store: one SQLite file (WAL) that says, for every file ppd has seen, what it
did, with which patch, and what the original was.

The daemon's worker threads and a `ppd status` in another process use it at the same time (one
connection per thread, write transactions that take the lock up front: connection.py). Schema
changes are ordered migrations (schema.py); see docs/STORE.md.

Modules, by what they hold:
    errors.py        the exceptions (one line each)
    damage.py        a damaged or lost store told apart from a sound one
    schema.py        MIGRATIONS, SCHEMA_VERSION, migrate()
    connection.py    StoreBase: per-thread connections, write transactions, rows as dicts
    events.py        the event log
    datasets.py      specs and datasets
    files.py         file rows and their states
    verification.py  verification runs and automatic mode's decisions
    core.py          Store: opening it, and the row kinds put together
"""

from daemon.store.connection import BUSY_TIMEOUT_MS, DB_FILE_MODE, SQLITE_SUFFIXES
from daemon.store.core import Store
from daemon.store.damage import (
    LOST_NOTE,
    QUICK_CHECK_MAX_BYTES,
    damaged_message,
    is_corruption,
    vault_holds_originals,
)
from daemon.store.errors import (
    DatasetSpecLocked,
    PatchedNotFailed,
    SpecNotRecovered,
    StoreDamaged,
    StoreError,
    StoreTooNew,
)
from daemon.store.files import FILE_FIELDS, FILE_STATES
from daemon.store.schema import AUTO_TRIGGERS, MIGRATIONS, SCHEMA_VERSION

__all__ = [
    "AUTO_TRIGGERS",
    "BUSY_TIMEOUT_MS",
    "DB_FILE_MODE",
    "FILE_FIELDS",
    "FILE_STATES",
    "LOST_NOTE",
    "MIGRATIONS",
    "QUICK_CHECK_MAX_BYTES",
    "SCHEMA_VERSION",
    "SQLITE_SUFFIXES",
    "DatasetSpecLocked",
    "PatchedNotFailed",
    "SpecNotRecovered",
    "Store",
    "StoreDamaged",
    "StoreError",
    "StoreTooNew",
    "damaged_message",
    "is_corruption",
    "vault_holds_originals",
]
