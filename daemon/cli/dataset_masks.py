"""`ppd dataset set NAME --subject-masks DIR` / `--no-subject-masks`: the subject-mask folder remembered
with a dataset (issue 25: `ppd poison --subject-masks DIR` keeps it for later runs and the daemon), changed
or dropped. A user whose mask folder was renamed or deleted could only make it again: no command showed,
changed or cleared it (a seventh black-box review, F1). The mask rules stay daemon.datasets.subject_masks'.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from daemon.cli.errors import die

if TYPE_CHECKING:
    from daemon.context import AppContext


def remembered_masks_option() -> Any:
    return typer.Option(
        None, "--subject-masks", metavar="DIR",
        help="Subject masks, one per image (same name; white = subject), remembered with the dataset for "
        "later runs and the daemon, in place of the one it has.",
    )  # fmt: skip


def no_subject_masks_option() -> Any:
    return typer.Option(
        False, "--no-subject-masks", help="Forget the dataset's remembered subject masks: its files patched "
        "from now on get the mark placed without masks.",
    )  # fmt: skip


@dataclass(frozen=True)
class MasksChange:
    """The remembered mask folder a `dataset set` asks for: folder, or None to drop the one remembered."""

    folder: Path | None


def masks_change(ctx: AppContext, name: str, given: Path | None, drop: bool) -> MasksChange | None:
    """The change asked, checked before anything is written (one line, exit 2): a folder that is not a
    readable folder outside the outbox, both options, or a dataset whose config.toml names its masks (that
    one comes first: a remembered one would change nothing). None: no change asked."""
    from daemon.datasets.subject_masks import SubjectMaskError, check_mask_folder, config_key

    if given is None and not drop:
        return None
    if given is not None and drop:
        raise die("--subject-masks and --no-subject-masks: give one of them")
    if (configured := ctx.config.subject_masks_for(name)) is not None:
        raise die(f"{config_key(name)} in config.toml ({configured}) names {name}'s subject masks, and "
                  "comes before a remembered folder: change it there")  # fmt: skip
    if given is None:
        return MasksChange(None)
    try:
        return MasksChange(check_mask_folder(given, ctx.paths.outbox))
    except SubjectMaskError as exc:
        raise die(exc, exc.exit_status) from None


def apply_masks_change(ctx: AppContext, name: str, change: MasksChange, reprotect: bool) -> str:
    """The change made (the dataset's row exists by now); the line saying what it does. reprotect: the
    same command patches the dataset's files again, which then places the marks off the new masks."""
    before = ctx.store.dataset_masks(name)
    ctx.store.set_dataset_masks(name, change.folder)
    if change.folder is None:
        if before is None:
            return f"{name}: no subject masks remembered; nothing changed"
        return (f"{name}: subject masks dropped (they were {before}): files patched from now on get the "
                "mark placed without masks")  # fmt: skip
    line = f"{name}: subject masks from {change.folder}, remembered for later runs and the daemon"
    patched = ctx.store.counts(name).get("patched", 0)
    if patched and not reprotect and before != change.folder:
        line += (f"; its {patched} patched file(s) keep the mark where it was placed: `ppd dataset set "
                 f"{shlex.quote(name)} --reprotect` places it again off these masks")  # fmt: skip
    return line


def masks_show_line(ctx: AppContext, name: str) -> str | None:
    """`ppd dataset show`'s line for the dataset's subject masks: the config's or the remembered folder,
    and whether it is there now; None when it has none."""
    from daemon.datasets.subject_masks import config_key, readable_folder

    configured = ctx.config.subject_masks_for(name)
    folder = configured if configured is not None else ctx.store.dataset_masks(name)
    if folder is None:
        return None
    whose = f"from {config_key(name)} in config.toml" if configured is not None else "remembered"
    there = "" if readable_folder(folder) else " (NOT there now: its files wait for it)"
    return f"subject masks: {folder} ({whose}){there}"
