"""The `ppd` command line. Each command group lives in the module named after its stage;
this file only assembles them, so importing it stays light (no pycolmap, no torch)."""

from __future__ import annotations

import logging
import os

import typer

app = typer.Typer(
    name="ppd",
    help="PatchPoison daemon: publish multi-view photos without handing out a free 3D scan.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def _main(verbose: bool = typer.Option(False, "--verbose", "-v", help="Debug logging.")) -> None:
    level = logging.DEBUG if verbose else getattr(logging, os.environ.get("PPD_LOG_LEVEL", "INFO"))
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s %(message)s")


COMMAND_MODULES = (
    "daemon.cli_poison", "daemon.cli_watch", "daemon.cli_demo", "verifier.cli",
    "daemon.cli_auto",  # automatic mode (issue 9)
    "daemon.cli_experiment",  # `ppd experiment`, `ppd report` (issue 7)
)  # fmt: skip


def _modules_for(argv: list[str]) -> tuple[str, ...]:
    """`ppd watch` is the long-lived daemon: it loads only its own command module, which keeps
    the others' imports (and their memory) out of the resident process."""
    if len(argv) > 1 and argv[1] == "watch":
        return ("daemon.cli_watch",)
    return COMMAND_MODULES


def _register() -> None:
    # Each module exposes `register(app)`.
    import importlib
    import sys

    for name in _modules_for(sys.argv):
        importlib.import_module(name).register(app)


_register()

if __name__ == "__main__":
    app()
