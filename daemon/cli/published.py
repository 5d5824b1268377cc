"""Where a file ppd writes for the user alone (the seal key, a preview showing the clean original)
must not go: among what gets published. One rule for `ppd key export` and `ppd preview`; and where a
backup must not go: ppd's own data folder (`ppd key export`)."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from daemon.paths import AppPaths


def published_folder_holding(file: Path, paths: AppPaths, photo_folders: Iterable[Path] = ()) -> str | None:
    """Where FILE would be written among what is published, in words; None when nowhere: anywhere in
    the outbox, a dataset's publish folder, a dataset's folder (`ppd poison` takes its subfolders too,
    and a sync client uploads them) or one of photo_folders (a folder of photos not patched yet: the
    next `ppd poison` would take FILE for a photo). A root that is the home folder counts for itself
    alone (its subfolders are the user's own). Symlinks followed: what a sync client uploads. The
    datasets come from the store when there is one to read; nothing is made."""
    from daemon.paths import published_with
    from daemon.protect.rebuild import stored_datasets

    where = _folder_of(file)
    trees = [("the outbox", Path(paths.outbox))]
    datasets = stored_datasets(Path(paths.db_path))  # none yet or broken: what it gives
    for name, row in datasets.items():
        trees.append((f"the folder of dataset {name!r}", Path(row["root"])))
        if row.get("publish_dir"):
            trees.append((f"the publish folder of dataset {name!r}", Path(row["publish_dir"])))
    # a privacy review: the key went into an `--out` copies' folder and the config's publish folder
    trees += [(f"the folder of dataset {name!r}'s patched copies (--out)", folder)
              for name, folder in _copies_folders(Path(paths.db_path), datasets)]  # fmt: skip
    trees += [(f"the publish folder {where_set}", folder) for where_set, folder in _configured_publish(paths)]
    trees += [("the folder of the photos", Path(folder)) for folder in photo_folders]
    for words, folder in trees:
        if published_with(folder.resolve(), where):
            return f"{words} {folder}"
    return None


def _copies_folders(db_path: Path, datasets: dict[str, dict]) -> list[tuple[str, Path]]:
    """Each dataset's `--out` copies' folder (OUT/NAME, where `ppd poison --out OUT` writes them): its
    rows outside its own folder, read-only; each copy's folder, and OUT/NAME above it."""
    import sqlite3

    from daemon.protect.rebuild_carry import open_read_only

    if (conn := open_read_only(db_path)) is None:
        return []
    found: dict[tuple[str, Path], None] = {}
    try:
        rows = conn.execute("SELECT dataset, path FROM files WHERE published_path IS NULL").fetchall()
    except sqlite3.Error:
        rows = []
    finally:
        conn.close()
    for name, path in rows:
        root = (datasets.get(name) or {}).get("root")
        if root is None or Path(path).is_relative_to(root):
            continue
        folder = Path(path).parent
        top = next((f for f in (folder, *folder.parents) if f.name == Path(root).name), folder)
        found[(name, top)] = None
    return list(found)


def _configured_publish(paths: AppPaths) -> list[tuple[str, Path]]:
    """The config's publish folders (`publish_dir`, and each dataset's own): where a sync client
    uploads; a config that does not load names none (its command says why)."""
    from daemon.config import Config

    try:
        config = Config.load(paths)
    except Exception:  # a broken config is said by the commands that need it
        return []
    found = [("(publish_dir in the config)", Path(config.publish_dir))] if config.publish_dir else []
    for name, override in config.datasets.items():
        if override.publish_dir:
            found.append((f"of dataset {name!r} (in the config)", Path(override.publish_dir)))
    return found


def in_data_folder(file: Path, paths: AppPaths) -> bool:
    """Whether FILE would be written inside ppd's data folder (symlinks followed), by the rule of
    daemon.paths.published_with (a home folder counts for itself alone)."""
    from daemon.paths import published_with

    return published_with(Path(paths.data_dir).resolve(), _folder_of(file))


def _folder_of(file: Path) -> Path:
    """The folder FILE would be written in, resolved: where it would really land."""
    return Path(os.path.abspath(file.expanduser())).parent.resolve()
