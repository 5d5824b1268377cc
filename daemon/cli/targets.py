"""What a command means by the dataset it is given: one resolver for `restore`, `report`, `verify`,
`status`, `preview` and `auto` (and `experiment`'s folders), from any working folder.

X may be
- a dataset name (the store knows it);
- a dataset's folder, relative to the working folder or absolute: the folder `ppd poison` patched
  in place, or the one its patched copies went to (`--out`);
- a verification folder (one holding report.json, e.g. DATA/runs/DATASET/RUN): the dataset whose
  runs it holds, if any;
- any other folder (commands that can use a plain folder say so; the others say what to give).

When two readings are possible (a dataset name that is also an unrelated folder here, a
verification folder of a dataset) the dataset is taken and the command says so, naming the
explicit form for the other reading (`--folder PATH`, `--dataset NAME`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.cli.errors import warning
from poisoner.errors import ExitStatus, PpdError

REPORT_FILE = "report.json"  # what a verification or experiment folder holds (verifier.html_report)


class TargetError(PpdError, ValueError):
    """X names nothing usable; the message is one line that says what to give instead."""

    exit_status = ExitStatus.USAGE


@dataclass(frozen=True)
class Target:
    dataset: str | None  # the daemon dataset to use, or None for a plain folder
    folder: Path | None  # the folder given, when one was (absolute)
    note: str | None = None  # one line for the user: what X was taken as, and why
    took_dataset_over_folder: bool = False  # the note is a warning: the folder reading was set aside


def _absolute(path: Path) -> Path:
    """Absolute and normalised ('..' and '.' folded) without following symlinks: how the store
    records a dataset's root."""
    return Path(os.path.abspath(path.expanduser()))


def user_path(path: Path | str) -> Path:
    """A path as given, the way the store records paths: absolute, '.' and '..' folded (`ppd poison
    ../shoot` patches the files of /home/me/shoot, not of /home/me/work/../shoot, which no dataset
    root contains). Where a '..' follows a symlink the kernel goes elsewhere than the folded path,
    so such a path is refused, never guessed. '~' is the shell's to expand: a folder named `~`
    (`./~/photos`) is that folder, not the home one."""
    if str(path) == "":
        from daemon.cli.coerce import EMPTY_PATH  # what the option parser says of an empty path

        raise TargetError(EMPTY_PATH)
    given = Path(path).absolute()
    folded = Path(os.path.normpath(given))
    if folded != given and ".." in given.parts and not _same_place(given, folded):
        raise TargetError(
            f"{path}: a '..' in it follows a symlink, so it reads another folder than it names; "
            "give the path without '..'"
        )
    return folded


def _same_place(a: Path, b: Path) -> bool:
    """a and b name one file or folder (or neither exists, so nothing is read through them)."""
    if os.path.lexists(a) != os.path.lexists(b):
        return False
    try:
        return not os.path.lexists(a) or os.path.samefile(a, b)
    except OSError:
        return False


def same_folder(a: Path, b: Path) -> bool:
    if _absolute(a) == _absolute(b):
        return True
    try:
        return a.resolve() == b.resolve()  # one of them reached through a symlink
    except OSError:
        return False


def dataset_for_folder(store: Any, folder: Path) -> str | None:
    """The dataset whose folder this is: its root (patched in place) or the folder its patched
    copies were written to (`--out`), or None. The newest match wins when several do."""
    folder = _absolute(folder)
    for row in store.datasets():
        if row["root"] and same_folder(Path(row["root"]), folder):
            return row["name"]
    holding: list[tuple[int, str]] = []
    for row in store.datasets():
        paths = [_absolute(Path(r.get("published_path") or r["path"])) for r in store.files(row["name"])]
        if inside := sum(1 for p in paths if p.is_relative_to(folder)):
            holding.append((inside, row["name"]))
    if len(holding) > 1:  # a parent of several datasets: one of them was taken, the others left (a review)
        names = ", ".join(name for _, name in sorted(holding, key=lambda h: h[1]))
        raise TargetError(f"{folder} holds files of several datasets ({names}): name one (see `ppd status`)")
    return holding[0][1] if holding else None


def dataset_for_verification_folder(store: Any, folder: Path) -> str | None:
    """The dataset a verification folder (report.json inside) belongs to: the one whose recorded
    runs' model folders lie in it, or None (a folder `ppd verify --clean` or `experiment` wrote)."""
    if not (folder / REPORT_FILE).is_file():
        return None
    folder = _absolute(folder)
    for row in store.datasets():
        for run in store.verification_runs(row["name"], limit=1000):
            model = run.get("model_dir")
            if model and _absolute(Path(model)).is_relative_to(folder):
                return row["name"]
    return None


def _folder_target(store: Any, path: Path, explicit: bool) -> Target:
    folder = user_path(path)
    name = dataset_for_folder(store, folder)
    if name is not None:
        same = "" if explicit else f"; --dataset {name} says the same"
        return Target(name, folder, f"{path} is dataset {name!r} (patched by ppd{same})")
    name = dataset_for_verification_folder(store, folder)
    if name is not None:
        return Target(
            name, folder,
            f"{path} is a verification of dataset {name!r}: took the dataset (--folder {path}: this run)",
            took_dataset_over_folder=True,
        )  # fmt: skip
    return Target(None, folder)


def stored_name(store: Any, name: str) -> str:
    """The store's spelling of a dataset name typed in another Unicode form: a folder copied from a Mac
    names it in NFD ("e" + a combining accent), a keyboard types NFC, and `ppd status Café` found no
    dataset (a black-box review). name itself when it is stored, or no stored name matches."""
    import unicodedata

    if store.dataset(name) is not None:
        return name
    wanted = unicodedata.normalize("NFC", name)
    same = [row["name"] for row in store.datasets() if unicodedata.normalize("NFC", row["name"]) == wanted]
    return same[0] if len(same) == 1 else name


def resolve_target(
    store: Any, target: str | None, *, dataset: str | None = None, folder: Path | None = None
) -> Target:
    """X (or the explicit --dataset / --folder) as a dataset or a folder."""
    given = [x for x in (target, dataset, folder) if x is not None]
    if len(given) != 1:
        raise TargetError("give one of: DATASET or FOLDER, --dataset NAME, --folder PATH")
    if target == "" or dataset == "":  # Path("") is '.': `ppd restore "$SHOOT"` with SHOOT unset
        raise TargetError("an empty dataset or folder (an unset variable in a script?); give a name or path")
    if dataset is not None:
        dataset = stored_name(store, dataset)
        if store.dataset(dataset) is None:
            raise TargetError(f"no dataset {dataset!r} in the store (see `ppd status`)")
        return Target(dataset, None)
    if folder is not None:
        if not folder.expanduser().is_dir():
            raise TargetError(f"{folder} is not a folder")
        name = dataset_for_folder(store, folder)  # explicit: never a verification's dataset
        note = f"{folder} is dataset {name!r} (patched by ppd)" if name else None
        return Target(name, user_path(folder.expanduser()), note)
    assert target is not None
    path = Path(target).expanduser()
    target = stored_name(store, target) if not path.exists() else target
    is_dataset = store.dataset(target) is not None
    if is_dataset and path.is_dir():
        reading = _folder_target(store, path, explicit=False)
        if reading.dataset == target:  # the dataset's own folder: one reading
            return Target(target, reading.folder)
        note = (
            f"{target!r} is both a dataset and a folder here: took the dataset "
            f"(use --folder {path} for the folder)"
        )
        return Target(target, None, note, took_dataset_over_folder=True)
    if is_dataset:
        return Target(target, None)
    if path.is_dir():
        return _folder_target(store, path, explicit=False)
    if path.exists():
        raise TargetError(f"{target} is a file, not a dataset or a folder")
    raise TargetError(f"no dataset {target!r} in the store, and no folder of that name (see `ppd status`)")


def say_note(chosen: Target, console: Any) -> None:
    """The resolver's note: a warning when a reading was set aside, else a plain line."""
    if chosen.note is None:
        return
    if chosen.took_dataset_over_folder:
        warning(chosen.note)
    else:
        console.print(chosen.note, markup=False, highlight=False)


def dataset_or_die(store: Any, target: str | None, console: Any, what: str) -> str:
    """For commands that work on datasets only (restore, status, auto --show): the dataset X names,
    its note said, or a one-line TargetError naming what to give."""
    chosen = resolve_target(store, target)
    say_note(chosen, console)
    if chosen.dataset is None:
        raise TargetError(f"{chosen.folder} is not a folder ppd patched; {what}")
    return chosen.dataset
