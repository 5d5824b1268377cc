"""Symlinked folders: ppd never follows a link (it would patch files outside the folder it was given,
and a link swapped meanwhile could send it anywhere), so the photos and videos reached through one stay
as they are, while a publisher that follows links (a web server, `rsync -L`, `cp -L`) ships them all
the same. `ppd poison` names them, `ppd status` counts them (`--check` fails on them), `ppd watch` warns
of each link once (a black-box review: status and the daemon never said a word of them). One mechanism:
where they are (linked_folders_under), what each holds (linked_folders), said one way
(daemon.cli.linked_lines).

Cheap, as `ppd status` must be: the walk for links goes by names (no file opened); the folders behind
them are walked as daemon.datasets.unpatched_names walks a hidden folder, for at most HIDDEN_WALK_BUDGET
entries and SNIFF_BUDGET files opened (a file named as no format is judged by its first bytes:
poisoner.media.media_class); past either, the count is a lower bound.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.datasets.unpatched_names import HIDDEN_WALK_BUDGET, SNIFF_BUDGET
from poisoner.media import IMAGE, UNPROTECTED, VIDEO, judged_by_content, media_class

PHOTO_CLASSES = (IMAGE, VIDEO, UNPROTECTED)  # a publisher ships a GIF or a raw file as well


@dataclass(frozen=True)
class LinkedFolder:
    """A symlink to a folder, and the photos and videos reached through it."""

    path: Path  # the link
    target: str  # what it points to, as written (os.readlink); "?" when replaced meanwhile
    photos: int  # photos and videos in the folder it points to and below (hidden ones left out)

    def to_dict(self) -> dict[str, Any]:
        return {"path": str(self.path), "target": self.target, "photos": self.photos}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LinkedFolder:
        return cls(Path(d["path"]), str(d["target"]), int(d["photos"]))


class _Budget:
    """What one call may still look at: entries walked, files opened."""

    def __init__(self) -> None:
        self.entries, self.sniffs = HIDDEN_WALK_BUDGET, SNIFF_BUDGET


def linked_folders(links: Iterable[Path], own: Sequence[Path] = ()) -> list[LinkedFolder]:
    """Each symlinked folder with the photos and videos reached through it. own: folders whose files
    are counted where they are (the outbox): a link into one of them ships nothing unmarked of its own,
    and is left out."""
    homes = [Path(os.path.realpath(p)) for p in own]
    budget = _Budget()
    found = []
    for link in links:
        real = Path(os.path.realpath(link))
        if any(real.is_relative_to(home) for home in homes):
            continue
        found.append(LinkedFolder(Path(link), _target(Path(link)), _photos_in(Path(link), budget)))
    return found


def linked_folders_under(
    folder: Path, skip: Iterable[Path] = (), own: Sequence[Path] = ()
) -> list[LinkedFolder]:
    """The symlinks to folders under folder (hidden folders and those of skip not entered, no link
    followed), with their photos (linked_folders); folder itself is never one."""
    skipped = {Path(s).absolute() for s in skip}
    links: list[Path] = []
    for dirpath, dirnames, _files in os.walk(Path(folder).absolute()):
        here = Path(dirpath)
        kept = sorted(d for d in dirnames if not d.startswith(".") and here / d not in skipped)
        links += [here / d for d in kept if os.path.islink(here / d)]
        dirnames[:] = [d for d in kept if here / d not in links]  # os.walk does not enter them either
    return linked_folders(links, own)


def _photos_in(folder: Path, budget: _Budget) -> int:
    """The photos and videos in folder and below (hidden ones left out, no symlink followed below it)."""
    found = 0
    for here, dirs, files in os.walk(folder):
        if budget.entries <= 0:
            break
        budget.entries -= len(files) + len(dirs)
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        for name in files:
            if name.startswith("."):
                continue
            if judged_by_content(name):  # opened for its first bytes: counted against the budget
                if budget.sniffs <= 0:
                    continue
                budget.sniffs -= 1
            found += media_class(Path(here, name)) in PHOTO_CLASSES
    return found


def _target(path: Path) -> str:
    try:
        return os.readlink(path)
    except OSError:  # replaced meanwhile: the line still names the link
        return "?"


class LinkWarnings:
    """The links the daemon has warned of: each (link, target) once per run, at its start's catch-up or
    when it appears, from any worker thread."""

    def __init__(self) -> None:
        self._said: set[tuple[Path, str]] = set()
        self._lock = threading.Lock()

    def new(self, links: Iterable[LinkedFolder]) -> list[LinkedFolder]:
        """The links not warned of yet, now taken as warned of."""
        with self._lock:
            fresh = [link for link in links if (link.path, link.target) not in self._said]
            self._said.update((link.path, link.target) for link in fresh)
        return fresh
