"""Telling a damaged or lost store apart from a sound one, in one line that names the way out."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from daemon.store.errors import StoreDamaged

# PRAGMA quick_check reads every page (~0.75 s for a 100 MB store of 200k files); above this size
# the open skips it and damage is reported by the first query that meets it (same one line).
QUICK_CHECK_MAX_BYTES = 64 << 20
SQLITE_CORRUPT, SQLITE_NOTADB = 11, 26
LOST_NOTE = "lost"  # store_notes key: the store was created empty next to a vault of originals


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


def check_pages(conn: sqlite3.Connection, db_path: Path) -> None:
    """Every page readable (PRAGMA quick_check) for stores up to QUICK_CHECK_MAX_BYTES."""
    if db_path.stat().st_size > QUICK_CHECK_MAX_BYTES:
        return
    rows = conn.execute("PRAGMA quick_check(1)").fetchall()
    if rows != [("ok",)]:
        raise StoreDamaged(damaged_message(db_path, str(rows[0][0]).splitlines()[0]))


def lost_message(db_path: Path, vault_dir: Path) -> str:
    return (
        f"the store {db_path} is new but the vault {vault_dir} already holds originals: "
        "the earlier store was lost; run `ppd store rebuild` to recover their rows from the vault "
        "and the patched files' seals"
    )


def vault_holds_originals(vault_dir: Path) -> bool:
    """Whether the vault folder holds at least one kept original (without creating anything)."""
    return any(len(p.name) == 64 for p in Path(vault_dir).glob("??/*"))
