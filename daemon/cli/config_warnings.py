"""The warnings `ppd status` and `ppd config show` give about a dataset's settings: a subject-mask folder
that is not there now (config.toml's or the one remembered with the dataset: its files wait for it), and
a `[datasets.NAME]` table of config.toml that names no dataset (a typo's settings reach no dataset).

Light at import (`ppd status` loads it).
"""

from __future__ import annotations

import contextlib
import sqlite3
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from daemon.config import Config
    from daemon.context import AppContext
    from daemon.paths import AppPaths


def status_warnings(ctx: AppContext, shown: list[str]) -> list[str]:
    """A missing mask folder of the datasets shown, and of one with no file patched yet (its
    config's); then config.toml's [datasets.NAME] tables that name no dataset."""
    from daemon.datasets.dataset import unknown_config_datasets
    from daemon.datasets.subject_masks import missing_masks

    known = [d["name"] for d in ctx.store.datasets()]
    lines = [line for name, line in missing_masks(ctx).items() if name in shown or name not in known]
    return lines + unknown_config_datasets(ctx.config.datasets, known, ctx.paths.outbox)


def config_warnings(paths: AppPaths, config: Config) -> list[str]:
    """config.toml's [datasets.NAME] tables that name no dataset, for `ppd config show`: the store is
    only read (the command makes nothing, and shows the config with no store or a damaged one)."""
    from daemon.datasets.dataset import unknown_config_datasets

    if not config.datasets or (stored := _stored_names(paths)) is None:
        return []
    return unknown_config_datasets(config.datasets, stored, paths.outbox)


def _stored_names(paths: AppPaths) -> list[str] | None:
    """The store's dataset names, read-only (none when there is no store yet); None when it cannot be
    read (damaged: which names it holds is not known, so nothing is said)."""
    from daemon.protect.rebuild_carry import open_read_only

    if not paths.db_path.exists():
        return []
    conn = open_read_only(paths.db_path)
    if conn is None:
        return None
    with contextlib.closing(conn):
        try:
            return [str(row[0]) for row in conn.execute("SELECT name FROM datasets")]
        except sqlite3.Error:
            return None
