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


def _register() -> None:
    # Each module exposes `register(app)`; a module that is not there yet is skipped.
    import importlib

    for name in ("daemon.cli_poison", "daemon.cli_watch", "daemon.cli_demo", "verifier.cli"):
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        module.register(app)


_register()

if __name__ == "__main__":
    app()
