"""Where a dataset's verification keeps what outlives one run, and what `ppd status` says of a
running one (issue 30).

- The clean reference: `<runs_dir>/<dataset>/.clean-cache/<content key>/` (features, verified
  databases, round-tripped copies and models of the vault originals; private like the runs), reused
  by the next verification until an original changes; only the latest originals' cache is kept.
- The progress of a running verification: `<runs_dir>/<dataset>/.verifying.json`, written atomically
  by the verification (verifier.progress) and removed when it ends; a file left by a killed process
  is ignored (its pid is gone).

Light at import (`ppd status` imports it): msgspec and the standard library only.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from daemon.paths import AppPaths

CLEAN_CACHE = ".clean-cache"  # dot-names: prune_runs leaves them alone
PROGRESS_FILE = ".verifying.json"


def progress_path(paths: AppPaths, dataset: str) -> Path:
    return Path(paths.runs_dir) / dataset / PROGRESS_FILE


def dataset_run_options(paths: AppPaths, dataset: str) -> dict[str, Any]:
    """The VerifyOptions fields a dataset's verification gets: its clean cache and progress file."""
    return {
        "clean_cache_dir": Path(paths.runs_dir) / dataset / CLEAN_CACHE,
        "clean_cache_keep": 1,  # the originals as they are now; an older cache is stale
        "progress_path": progress_path(paths, dataset),
        "progress_label": dataset,
    }


def running_verification(paths: AppPaths, dataset: str) -> dict[str, Any] | None:
    """The dataset's running verification as `ppd status --json` carries it (None: none running)."""
    from verifier.progress import read_progress, state_to_json

    state = read_progress(progress_path(paths, dataset))
    return None if state is None else state_to_json(state)
