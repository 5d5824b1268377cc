"""Photos and videos under names ppd does not patch: hidden files, files in hidden folders, editors'
backups, partial downloads (poisoner.media.unpatched_name). The daemon leaves them, as their writers
are not done with them (a browser renames its `.part` once complete, an editor writes a hidden
temporary), but a sync publishes them all the same (rsync -a, Syncthing, Nextcloud copy dot-files and
`.bak` files): `ppd status` counts and names them, and `--check` fails on them (a black-box review:
five full-size JPEGs sat unmarked in the outbox while `--check` passed).

Cheap, as `ppd status` must be: the walk goes by names; only a file whose name ppd does not patch is
opened, for its first SNIFF_BYTES (poisoner.media.content_under_any_name), never decoded; at most
SNIFF_BUDGET of them per walk. ppd's own temporaries (poisoner.atomic.is_temp_name) are not counted.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from poisoner.atomic import is_temp_name
from poisoner.media import IMAGE, UNPROTECTED, VIDEO, content_under_any_name, read_head, unpatched_name

# Files opened per walk at most (a `.git` or a thumbnail cache holds thousands): what is found by then
# is said; a folder past it is unusual enough that the count is a lower bound.
SNIFF_BUDGET = 5000
# Entries looked at inside hidden folders per walk at most: a `.git`, a cache or a `.Trash` can hold
# hundreds of thousands, which status walked whole on every call (a diff review: 0.6 s warm, 2.3 s cold
# for 400 000); past it no hidden folder is entered, and what was found is a lower bound, as above.
HIDDEN_WALK_BUDGET = 20_000
WORDS = "under names ppd does not patch (hidden, backup or partial)"
NAME_PREFIX = "a name ppd does not patch"  # a skipped outcome's reason begins so (`ppd poison`)
KIND_WORDS = {IMAGE: "a photo", VIDEO: "a video", UNPROTECTED: "a photo or video"}


def unpatched_name_reason(name: str, hidden_folder: bool, head: bytes) -> str | None:
    """`a name ppd does not patch: editor backup, a photo by its content` for a photo or video whose
    name (or a folder above it, hidden_folder) ppd does not patch; None for any other file (ppd's own
    temporaries, a sidecar, a name ppd patches). head: the file's first bytes."""
    why = "in a hidden folder" if hidden_folder else unpatched_name(name)
    if why is None or is_temp_name(name):
        return None
    kind = content_under_any_name(name, head)
    return None if kind is None else f"{NAME_PREFIX}: {why}, {KIND_WORDS[kind]} by its content"


def unpatched_media(folder: Path, skip: Iterable[Path] = (), *, loose: bool = True) -> list[Path]:
    """The photos and videos under folder whose names (or a folder's between) ppd does not patch,
    sorted. skip: folders left out (other datasets', subject masks); loose=False: not the files right in
    folder (another count has them). No symlink followed, ppd's temporaries left out."""
    folder = Path(folder).absolute()
    skipped = {Path(s).absolute() for s in skip}
    found: list[Path] = []
    budget, hidden_budget = SNIFF_BUDGET, HIDDEN_WALK_BUDGET
    for dirpath, dirnames, filenames in os.walk(folder):
        here = Path(dirpath)
        hidden = any(part.startswith(".") for part in here.relative_to(folder).parts)
        if hidden and hidden_budget <= 0:  # spent: no hidden folder looked at any more (ordinary ones are)
            dirnames[:] = []
            continue
        if hidden:
            hidden_budget -= len(filenames) + len(dirnames)
        dirnames[:] = sorted(d for d in dirnames if here / d not in skipped)
        if here == folder and not loose:
            continue
        for name in filenames:
            if not (hidden or unpatched_name(name)) or is_temp_name(name) or budget <= 0:
                continue
            path = here / name
            budget -= 1
            if not path.is_symlink() and unpatched_name_reason(name, hidden, read_head(path)):
                found.append(path)
    return sorted(found)


def outbox_unpatched(outbox: Path, roots: Iterable[str | Path], skip: Iterable[Path] = ()) -> list[Path]:
    """Such files in the outbox that no dataset counts: in its hidden and unclaimed first-level folders
    (a dataset's folder counts its own), and its loose files when no dataset has the outbox as its
    folder. roots: the datasets' folders; skip: folders left out besides (ppd's data folder)."""
    box = Path(os.path.realpath(outbox))
    if not box.is_dir():
        return []
    known = {Path(os.path.realpath(root)) for root in roots}
    inside = [k for k in known if k != box and k.is_relative_to(box)]
    return unpatched_media(box, [*inside, *skip], loose=box not in known)


def unpatched_line(paths: Sequence[str | Path], where: str, most: int = 5) -> str:
    """`3 photo(s) or video(s) under names ppd does not patch (...), NOT protected: .IMG_1.jpg, ...:
    rename them or move them out of WHERE`."""
    shown = ", ".join(Path(p).name for p in paths[:most]) + (", ..." if len(paths) > most else "")
    return (f"{len(paths)} photo(s) or video(s) {WORDS}, NOT protected: {shown}: rename them or move them "
            f"out of {where}")  # fmt: skip
