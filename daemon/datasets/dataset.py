"""Which dataset a file or folder belongs to: one rule, `attribute`.

In the outbox a dataset is a first-level subfolder: `outbox/shoot-01/a.jpg` and
`outbox/shoot-01/raw/b.jpg` both belong to "shoot-01"; files directly in the outbox form the
dataset "default". Outside the outbox (`ppd poison FOLDER`) a folder is one dataset named after
it, and a file belongs to a dataset named after its parent folder. An explicit name keeps a known
dataset's stored root.
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.datasets.moved import adopt_moved, moved_here
from daemon.datasets.subject_masks import place_corner, record_choice, wants_corner
from poisoner.errors import ExitStatus, PpdError

if TYPE_CHECKING:
    from daemon.context import AppContext
    from poisoner.spec import PatchSpec

DEFAULT_DATASET = "default"


class OutsideOutboxError(PpdError, ValueError):
    """The path is not inside the outbox."""

    exit_status = ExitStatus.USAGE


class DatasetConflict(PpdError, ValueError):
    """An explicit dataset name whose stored root does not hold the target."""

    exit_status = ExitStatus.USAGE


class DatasetNameError(PpdError, ValueError):
    """A dataset name that is not one plain folder name (it names folders: runs, --out copies)."""

    exit_status = ExitStatus.USAGE


def check_name(name: str) -> str:
    """name, when it is one plain folder name: a name with '/' or '..' would put --out copies and
    verification runs outside their folders (`--dataset ../shoot` wrote over the inputs)."""
    if not name or name in (".", "..") or any(c in name for c in "/\\\0") or name.startswith("."):
        raise DatasetNameError(
            f"dataset name {name!r} is not a plain name (no '/' or '\\', not starting with '.'): "
            "give one with --dataset NAME"
        )
    return name


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


def likely_meant(name: str, names: Iterable[str]) -> str | None:
    """The name of names a mistyped one most likely meant ('kitchn': 'kitchen'), or None: what a
    "did you mean" says."""
    near = difflib.get_close_matches(name, sorted(set(names)), n=1, cutoff=0.75)
    return near[0] if near else None


def unknown_config_datasets(datasets: Iterable[str], stored: Iterable[str], outbox: Path) -> list[str]:
    """A line for each of datasets (config.toml's [datasets.NAME] tables) that names no dataset of the
    store and no folder of the outbox: a typo reaches no dataset (`[datasets.kitchn] subject_masks`, and
    'kitchen' was patched without its masks: a seventh black-box review, F5); not an error, as a dataset
    may be configured before its folder exists."""
    known = set(stored)
    outbox = Path(outbox).absolute()
    lines = []
    for name in datasets:
        folder = dataset_root(outbox, name)
        if name in known or folder.is_dir():
            continue
        near = likely_meant(name, known | _outbox_folders(outbox))
        ahead = f"set up before its folder? it applies once {folder} exists, or `ppd poison` is given one"
        why = f"did you mean {near!r}?" if near else f"{ahead} named {name}"
        lines.append(f"config: [datasets.{name}] names no dataset and no folder in the outbox ({why})")
    return lines


def _outbox_folders(outbox: Path) -> set[str]:
    """The names of the outbox's first-level folders (its datasets to be), hidden ones left out."""
    try:
        return {p.name for p in outbox.iterdir() if p.is_dir() and not p.name.startswith(".")}
    except OSError:  # no outbox yet
        return set()


def _refuse_another_outboxs(ctx: AppContext, name: str, root: Path) -> None:
    """DatasetConflict when dataset `name` is stored at another folder that is still there: a folder of
    the same name in a second outbox (PPD_OUTBOX set otherwise) joined the first one's dataset, its root
    moved, and the first folder's photos were called "patched copies" (a fifth black-box review). A
    stored folder that is gone (the outbox moved) is followed, as before."""
    row = ctx.store.dataset(name)
    stored = Path(row["root"]) if row is not None and row["root"] else None
    if stored is None or stored.absolute() == root:
        return
    try:
        same = os.path.samefile(stored, root)
    except OSError:  # one of them is not there: not two folders
        return
    if not same and moved_here(ctx, name, root) is None:  # a folder left empty: followed (a dry run's too)
        raise DatasetConflict(
            f"dataset {name!r} already belongs to {stored} (another outbox's folder of the same name); "
            "rename this folder, or name it with --dataset NAME"
        )


def attribute(
    ctx: AppContext, target: Path, dataset: str | None = None, *, folder: bool | None = None,
    adopt: bool = False,
) -> tuple[str, Path]:  # fmt: skip
    """The dataset name and root folder of target, a file or a folder (given on the command line
    or seen by the daemon).

    - no name, inside the outbox: its outbox dataset (first-level subfolder, or "default");
    - no name, outside: inside a known dataset's folder, that dataset (the innermost); else a folder
      is a dataset named after it, a file one named after its parent;
    - an explicit name: a known dataset keeps its stored root (DatasetConflict when target lies
      outside it); a new one gets the folder itself, or the file's parent folder.

    folder: whether target is a folder; None asks the file system (following a symlink, as a
    folder named on the command line may be one). The daemon says False: a name it sees is a file.
    adopt: a stored dataset of the name found whose folder is gone, and whose patched files are in the
    folder found, moves there (daemon.datasets.moved: the outbox moved); the daemon and `ppd poison` ask.

    >>> attribute(ctx, outbox / "shoot" / "raw" / "a.jpg")   # doctest: +SKIP
    ('shoot', PosixPath('.../outbox/shoot'))
    """
    target = Path(os.path.normpath(Path(target).absolute()))  # "shoot/.." names its parent, not ".."
    is_folder = target.is_dir() if folder is None else folder
    home = target if is_folder else target.parent
    if dataset is not None:  # "" too: refused by check_name, never taken as "no name"
        check_name(dataset)
        row = ctx.store.dataset(dataset)
        if row is None:
            return dataset, home
        stored = Path(row["root"])
        if not target.is_relative_to(stored.absolute()):
            raise DatasetConflict(
                f"dataset {dataset!r} already belongs to {stored}; name this one with --dataset NAME"
            )
        return dataset, stored
    outbox = Path(ctx.paths.outbox).absolute()
    if target.is_relative_to(outbox) and target != outbox:
        name = dataset_of(outbox, target / "x" if is_folder else target)
        root = dataset_root(outbox, name)
        if adopt:  # first: a moved dataset's stored folder may be there still, left empty
            adopt_moved(ctx, name, root)
        _refuse_another_outboxs(ctx, name, root)
        return name, root
    holders = [d for d in ctx.store.datasets() if home.is_relative_to(Path(d["root"]).absolute())]
    if holders:  # a folder whose files a dataset above it already holds is that dataset's (castle/day2)
        holding = {r["dataset"] for r in ctx.store.files_under(home)}  # not any folder below a dataset's
        # root: one photo's ~/Desktop is no shoot. A dataset's own root is its own, rows or none (--out
        # keeps its rows with the copies: `ppd preview` of an original there ignored its remembered masks)
        holders = [d for d in holders if d["name"] in holding or Path(d["root"]).absolute() == home]
    if holders:
        row = max(holders, key=lambda d: len(Path(d["root"]).absolute().parts))  # the innermost
        return row["name"], Path(row["root"])
    name = check_name(home.name or DEFAULT_DATASET)
    if adopt:
        adopt_moved(ctx, name, home)
    return name, home


def innermost_holder(datasets: Sequence[dict[str, Any]], path: Path, prefer: str | None = None) -> str | None:
    """The stored dataset whose folder holds path, the innermost of several (castle/day2's files are
    day2's, as attribute says), prefer on a tie; None: no dataset's. A folder that is the home folder
    holds only the files right in it (its subfolders are the user's own: daemon.cli.published)."""
    path = Path(os.path.normpath(Path(path).absolute()))
    home = Path.home().absolute()
    best: tuple[int, bool, str] | None = None
    for row in datasets:
        root = Path(row["root"]).absolute()
        held = path.parent == root if root == home else path.is_relative_to(root)
        if held:
            key = (len(root.parts), row["name"] == prefer, row["name"])
            best = key if best is None else max(best, key)
    return best[2] if best is not None else None


def ensure_dataset(
    ctx: AppContext,
    dataset: str,
    root: Path,
    spec: PatchSpec | None,
    *,
    sample: Callable[[], Sequence[Path]] | None = None,
    mask_dir: Path | None = None,
) -> PatchSpec:
    """The dataset's one spec; a new dataset gets spec (else the config's) with its first file.

    A new dataset on the config's spec whose mark is corner-bound and whose position the config
    does not set gets its corner now (daemon.datasets.subject_masks.place_corner over `sample()`, the
    files seen first, and mask_dir's masks); the caller's own spec is taken as it is (`ppd poison` chose its
    corner over all the files it was given)."""

    initial = spec or ctx.config.spec_for(dataset)
    placed = None
    if (
        spec is None
        and sample is not None
        and wants_corner(initial, ctx.config.position_set(dataset))
        and ctx.store.dataset_spec(dataset) is None
        and ctx.store.lost_spec(dataset) is None  # refused below: no corner to judge
    ):
        placed = place_corner(initial, sample(), mask_dir)
        initial = placed.spec
    _, stored = ctx.store.ensure_dataset(dataset, root, initial, ctx.config.publish_dir_for(dataset))
    if placed is not None and stored.spec_id == initial.spec_id:  # ours won (not a concurrent first file's)
        record_choice(ctx, dataset, placed.choice, mask_dir)
    return stored


def ensure_dataset_row(
    ctx: AppContext,
    dataset: str,
    root: Path,
    spec: PatchSpec | None,
    *,
    sample: Callable[[], Sequence[Path]] | None = None,
    mask_dir: Path | None = None,
) -> None:
    """The dataset a row is recorded in when no file is patched (ppd's output found in its folder, a
    failure): ensure_dataset, except for a dataset whose spec a rebuild lost, which stays without one
    (no file is patched here, and the config's spec is not the one to take: a black-box review saw a
    rebuilt dataset take it with its next file)."""
    if ctx.store.lost_spec(dataset) is None:
        ensure_dataset(ctx, dataset, root, spec, sample=sample, mask_dir=mask_dir)
