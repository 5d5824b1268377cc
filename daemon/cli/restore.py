"""`ppd restore DATASET|FILE`: put originals back from the vault."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import typer

from daemon.cli.errors import EXIT_FAILED, die, open_ctx, reason_text
from daemon.cli.output import console, err_console


def restore(
    target: str = typer.Argument(
        ..., help="A dataset (its name, its folder, a verification folder of it) or a patched file."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite even if the file changed since."),
) -> None:
    """Put originals back from the vault (atomic). Files in an --out or publish folder are
    removed there, never replaced by originals. The daemon does not patch restored files again.

    \b
    Examples:
      ppd restore castle                 every patched file of the dataset
      ppd restore ~/shoots/castle        the same, by its folder
      ppd restore ~/shoots/castle/a.jpg  one file
    """
    from daemon.cli.targets import TargetError, dataset_or_die
    from daemon.protect import restore_file
    from daemon.states import FileState

    ctx = open_ctx()
    try:
        as_path = Path(os.path.abspath(Path(target).expanduser()))
        if ctx.store.file(as_path) is not None or (as_path.is_file() and not as_path.is_symlink()):
            # a file: its row, or with no row (a lost store) its seal and the vault (restore_file says
            # "not in the store and carries no ppd provenance marker" for a file ppd never patched)
            paths = [as_path]
        else:
            try:
                name = dataset_or_die(ctx.store, target, console(), "nothing to restore there")
            except TargetError as exc:
                raise die(exc) from None
            paths = [Path(r["path"]) for r in ctx.store.files(name, state=FileState.PATCHED)]
        outcomes = [restore_file(ctx, p, force=force) for p in sorted(set(paths))]
        counts = Counter(o.state for o in outcomes)
        console().print(
            ", ".join(f"{k} {counts.get(k, 0)}" for k in ("restored", "removed", "unchanged", "failed"))
        )
        for o in outcomes:
            if o.state == "failed":
                err_console().print(f"ppd: not restored: {o.path}: {reason_text(o.reason)}", markup=False)
            elif o.state not in ("restored", "unchanged") and o.reason:
                console().print(f"{o.state} {o.path}: {o.reason}", markup=False)
        if counts.get("failed"):
            raise typer.Exit(EXIT_FAILED)
    finally:
        ctx.close()


def register(app: typer.Typer) -> None:
    app.command("restore")(restore)
