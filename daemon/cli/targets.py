"""What `ppd verify X` and `ppd report X` mean by X: a dataset name, or a folder, and which
dataset a folder is when `ppd poison` patched it (the store knows its rows and originals).

A name that is both a dataset and a folder here is taken as the dataset, and the command says so
and names the explicit form for the other (`--folder PATH`, `--dataset NAME`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


class TargetError(ValueError):
    """X names nothing usable; the message is one line that says what to give instead."""


@dataclass(frozen=True)
class Target:
    dataset: str | None  # the daemon dataset to use, or None for a plain folder
    folder: Path | None  # the folder given, when one was
    note: str | None = None  # one line for the user: what X was taken as, and why


def dataset_for_folder(store: Any, folder: Path) -> str | None:
    """The dataset whose folder this is: its root (patched in place) or the folder its patched
    copies were written to (`--out`), or None. The newest match wins when several do."""
    folder = folder.expanduser().absolute()
    for row in store.datasets():
        if row["root"] and Path(row["root"]).absolute() == folder:
            return row["name"]
    best: tuple[int, str] | None = None
    for row in store.datasets():
        paths = [Path(r.get("published_path") or r["path"]) for r in store.files(row["name"])]
        inside = sum(1 for p in paths if p.is_relative_to(folder))
        if inside and (best is None or inside > best[0]):
            best = (inside, row["name"])
    return None if best is None else best[1]


def resolve_target(
    store: Any, target: str | None, *, dataset: str | None = None, folder: Path | None = None
) -> Target:
    """X (or the explicit --dataset / --folder) as a dataset or a folder."""
    given = [x for x in (target, dataset, folder) if x is not None]
    if len(given) != 1:
        raise TargetError("give one of: DATASET or FOLDER, --dataset NAME, --folder PATH")
    if dataset is not None:
        if store.dataset(dataset) is None:
            raise TargetError(f"no dataset {dataset!r} in the store (see `ppd status`)")
        return Target(dataset, None)
    if folder is not None:
        if not folder.is_dir():
            raise TargetError(f"{folder} is not a folder")
        name = dataset_for_folder(store, folder)
        note = f"{folder} is dataset {name!r} (patched by ppd)" if name else None
        return Target(name, folder.absolute(), note)
    assert target is not None
    path = Path(target).expanduser()
    is_dataset = store.dataset(target) is not None
    if is_dataset and path.is_dir():
        owner = dataset_for_folder(store, path)
        if owner == target:
            return Target(target, path.absolute())
        note = (
            f"{target!r} is both a dataset and a folder here: took the dataset "
            f"(use --folder {path} for the folder)"
        )
        return Target(target, None, note)
    if is_dataset:
        return Target(target, None)
    if path.is_dir():
        name = dataset_for_folder(store, path)
        note = (
            f"{path} is dataset {name!r} (patched by ppd; --dataset {name} says the same)" if name else None
        )
        return Target(name, path.absolute(), note)
    raise TargetError(f"no dataset {target!r} in the store, and no folder of that name (see `ppd status`)")
