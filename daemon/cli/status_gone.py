"""`ppd status`'s word on the datasets whose folder is gone: deleted, renamed, or moved with the whole
outbox (PPD_OUTBOX set anew), with the one command that follows a moved one; and which photos of the
outbox are such a dataset's patched files, never "NOT protected" (an eighth black-box review, F2: after
the outbox moved, every patched photo was "no dataset holds yet, NOT protected", and the advice, `ppd
poison OUTBOX`, exited 2).

Light at import (`ppd status` loads it).
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.cli.output import console, print_line

if TYPE_CHECKING:
    from daemon.context import AppContext


def moved_words(d: dict[str, Any]) -> str:
    """What a dataset's gone folder may be (its FolderCount.to_dict): moved, where its patched files are
    seen, or moved or deleted; `ppd dataset set --root` moves the dataset there. A black-box review: the
    advice was `ppd poison NEWFOLDER`, which made a second dataset, and was then repeated."""
    folder, name = d["folder"], shlex.quote(d["name"])
    if folder.get("moved_to_dataset"):  # a run made a dataset of it: its files are counted there
        return f"its patched files are in {folder['moved_to']}, now dataset {folder['moved_to_dataset']!r}"
    if folder.get("moved_to"):
        where = shlex.quote(folder["moved_to"])
        return (f"its patched files are in {folder['moved_to']} (moved?): "
                f"`ppd dataset set {name} --root {where}` moves the dataset there")  # fmt: skip
    return (f"moved or deleted? `ppd dataset set {name} --root NEWFOLDER` follows it to where you moved "
            f"it; `ppd dataset forget {name}` forgets a deleted one")  # fmt: skip


def _followable(d: dict[str, Any]) -> bool:
    """A gone folder whose patched files are seen elsewhere, in no other dataset's folder."""
    return bool(d["folder"].get("moved_to")) and not d["folder"].get("moved_to_dataset")


def _with_the_outbox(d: dict[str, Any], outbox: Path) -> bool:
    """A followable dataset seen where the outbox's rule puts it: OUTBOX/NAME (or the outbox itself, for
    its loose files' dataset): the outbox moved, not the folder renamed."""
    from daemon.datasets.dataset import dataset_root

    if not _followable(d):
        return False
    return Path(d["folder"]["moved_to"]) in (dataset_root(outbox, d["name"]), outbox / Path(d["root"]).name)


def print_gone(gone: list[dict[str, Any]], outbox: Path) -> None:
    """One line for the datasets whose folder is gone, one for each whose files are seen moved, and one
    for those that moved with the outbox (with its one command: 30 datasets, one line); a deleted folder
    and a renamed one are not both "hold no file now" (a black-box review). A dataset that never held a
    file (`ppd dataset set NAME` before its folder) is not said to be gone: its folder was never there
    (a fifth black-box review)."""
    waiting = [d for d in gone if not any(d["counts"].values())]
    if waiting:
        print_line(console(), f"not shown: {len(waiting)} dataset(s) set up before their folder, which does "
                              f"not exist yet ({', '.join(d['name'] for d in waiting)}); "
                              "`ppd dataset forget NAME` removes one")  # fmt: skip
    gone = [d for d in gone if d not in waiting]
    with_outbox = [d for d in gone if _with_the_outbox(d, Path(outbox).absolute())]
    if len(with_outbox) < 2:  # one is said as any moved folder is
        with_outbox = []
    gone = [d for d in gone if d not in with_outbox]
    if gone:
        names = ", ".join(d["name"] for d in gone)
        print_line(console(), f"not shown: {len(gone)} dataset(s) whose folder is gone, moved or deleted "
                              f"({names}); `ppd dataset set NAME --root NEWFOLDER` moves one there; "
                              "`ppd dataset forget NAME` forgets a deleted one; "
                              "`ppd status NAME` shows one")  # fmt: skip
    for d in gone:
        if d["folder"].get("moved_to"):
            print_line(console(), f"{d['name']}: folder gone; {moved_words(d)}")
    if with_outbox:
        names = ", ".join(d["name"] for d in with_outbox)
        where = shlex.quote(str(Path(outbox).absolute()))
        print_line(console(), f"{len(with_outbox)} datasets' folders are gone and their patched files are in "
                              f"the outbox {outbox} ({names}): the outbox moved? `ppd poison {where}` moves "
                              "each dataset to its folder there (`ppd watch` does at its start)")  # fmt: skip


def followed_files(ctx: AppContext, report: list[dict[str, Any]], unclaimed: list[Path]) -> list[Path]:
    """unclaimed (the outbox's photos no dataset's folder holds) without those that are a gone folder's
    patched files, seen moved (its rows' relative paths, sizes and times): status names that folder and
    the command that follows it."""
    from daemon.datasets.moved import patched_there

    theirs: set[Path] = set()
    for d in report:
        folder = d.get("folder") or {}
        if _followable(d):
            there = Path(folder["moved_to"])
            mine = [p for p in unclaimed if p.is_relative_to(there)]
            theirs |= patched_there(Path(d["root"]), there, ctx.store.files(d["name"]), mine)
    return [p for p in unclaimed if p not in theirs]
