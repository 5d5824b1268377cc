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
    for name, row in stored_datasets(Path(paths.db_path)).items():  # none yet or broken: what it gives
        trees.append((f"the folder of dataset {name!r}", Path(row["root"])))
        if row.get("publish_dir"):
            trees.append((f"the publish folder of dataset {name!r}", Path(row["publish_dir"])))
    trees += [("the folder of the photos", Path(folder)) for folder in photo_folders]
    for words, folder in trees:
        if published_with(folder.resolve(), where):
            return f"{words} {folder}"
    return None


def in_data_folder(file: Path, paths: AppPaths) -> bool:
    """Whether FILE would be written inside ppd's data folder (symlinks followed), by the rule of
    daemon.paths.published_with (a home folder counts for itself alone)."""
    from daemon.paths import published_with

    return published_with(Path(paths.data_dir).resolve(), _folder_of(file))


def _folder_of(file: Path) -> Path:
    """The folder FILE would be written in, resolved: where it would really land."""
    return Path(os.path.abspath(file.expanduser())).parent.resolve()
