"""An SfM child's working files in its model folder: their names, and what is removed of them once
the child is gone (verifier.sfm runs each profile's side in a child process; a timeout, a cancel
or a crash kills it before its own clean-up).

Each child's result file is named anew by mkstemp (`RESULT_PREFIX` + a token); its working files
carry the same token, so removing one child's leftovers never touches another's: two verifications
of the same originals map the cached clean side in one folder. The working database's name does
not start with poisoner.atomic's TEMP_PREFIX: a file so named is one that a stale-temporary sweep
may delete once it is 10 s old and unlocked, and this one lives as long as a mapping.
"""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

RESULT_PREFIX = ".ppd-tmp-sfm-"  # the child's result file, named anew for each child: its token
KEPT_DATABASE = "database.db"  # SfmJob.keep_database: the mapper's input, beside its model
MAP_TEMP_PREFIX = ".ppd-tmp-map-"  # the mapper's temporary folder (a folder: no sweep removes it)


def job_token(result_path: str) -> str:
    """The part of the child's result file name that is this child's alone (mkstemp's)."""
    return Path(result_path).stem.removeprefix(RESULT_PREFIX) if result_path else ""


def work_db_path(model_dir: str | Path, result_path: str) -> Path:
    """The child's working copy of the verified database, in its model folder."""
    return Path(model_dir) / f"work-{job_token(result_path)}.db"


def map_temp_prefix(result_path: str) -> str:
    """The prefix of the mapper's temporary folder, in the model folder."""
    return f"{MAP_TEMP_PREFIX}{job_token(result_path)}-"


def remove_child_leftovers(model_dir: str | Path, result_path: str) -> None:
    """What the child of this result file leaves in its model folder when it is killed before its
    own clean-up: its copy of the verified database (SQLite's -wal and -shm with it) and the mapper's
    temporary folder. Never an output: a finished child has removed or renamed them (KEPT_DATABASE);
    called after every child, once it is gone."""
    work_db = work_db_path(model_dir, result_path)
    for suffix in ("", "-wal", "-shm", "-journal"):
        with contextlib.suppress(FileNotFoundError):
            work_db.with_name(work_db.name + suffix).unlink()
    for folder in Path(model_dir).glob(map_temp_prefix(result_path) + "*"):
        shutil.rmtree(folder, ignore_errors=True)
