"""Which dataset a file belongs to.

A dataset is a first-level subfolder of the outbox: `outbox/shoot-01/a.jpg` and
`outbox/shoot-01/raw/b.jpg` both belong to "shoot-01". Files directly in the outbox form the
dataset "default". (`ppd poison FOLDER` makes FOLDER one dataset named after it; see
daemon.protect.)
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from daemon.context import AppContext
    from poisoner.spec import PatchSpec

DEFAULT_DATASET = "default"


class OutsideOutboxError(ValueError):
    """The path is not inside the outbox."""


def dataset_of(outbox: Path, path: Path) -> str:
    """The dataset name of path, a file inside outbox (compared without resolving symlinks,
    so a link inside the outbox is attributed by where it sits, and refused later)."""
    try:
        rel = Path(path).absolute().relative_to(Path(outbox).absolute())
    except ValueError:
        raise OutsideOutboxError(f"{path} is not inside the outbox {outbox}") from None
    parts = rel.parts
    if len(parts) <= 1:
        return DEFAULT_DATASET
    return parts[0]


def dataset_root(outbox: Path, dataset: str) -> Path:
    """The folder that holds a dataset of the outbox."""
    return Path(outbox) if dataset == DEFAULT_DATASET else Path(outbox) / dataset


def ensure_dataset(ctx: AppContext, dataset: str, root: Path, spec: PatchSpec | None) -> PatchSpec:
    """The dataset's one spec; a new dataset gets spec (else the config's) with its first file."""
    initial = spec or ctx.config.spec_for(dataset)
    _, stored = ctx.store.ensure_dataset(dataset, root, initial, ctx.config.publish_dir_for(dataset))
    return stored
