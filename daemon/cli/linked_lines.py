"""How `ppd poison` and `ppd status` say the photos behind symlinked folders
(daemon.datasets.linked_folders): one phrase, one advice."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from daemon.datasets.linked_folders import LinkedFolder
from daemon.protect.job import shown_path

LINKED_ADVICE = "put the folder itself in place of the link, or run ppd poison on the folder it points to"
SHOWN = 3  # links named in a line, then ", ..."


def linked_phrase(linked: Sequence[LinkedFolder], base: Path | None = None) -> str | None:
    """`3 photo(s) or video(s) in 1 symlinked folder(s) ppd does not follow (day2 -> /x: 3)`, of the
    links that hold any (None: none does), each named from base (its name alone without one)."""
    full = [link for link in linked if link.photos]
    if not full:
        return None
    shown = ", ".join(f"{_name(link.path, base)} -> {link.target}: {link.photos}" for link in full[:SHOWN])
    more = ", ..." if len(full) > SHOWN else ""
    return (f"{sum(link.photos for link in full)} photo(s) or video(s) in {len(full)} symlinked folder(s) "
            f"ppd does not follow ({shown}{more})")  # fmt: skip


def linked_status_line(linked: Sequence[LinkedFolder], base: Path) -> str | None:
    """`ppd status`'s words for them (None: no link holds any), each link named from base."""
    phrase = linked_phrase(linked, base)
    if phrase is None:
        return None
    return (f"{phrase}, NOT protected: a publisher that follows links (a web server, rsync -L) ships them; "
            f"{LINKED_ADVICE}")  # fmt: skip


def _name(path: Path, base: Path | None) -> str:
    if base is not None and path.is_relative_to(base):
        return shown_path(path.relative_to(base))
    return shown_path(Path(path.name)) if base is None else shown_path(path)
