"""The `ppd` command line. Each command group lives in the module named after its stage;
this file only assembles them, so importing it stays light (no pycolmap, no torch)."""

from __future__ import annotations

import typer

from daemon.cli_common import EXIT_CODES_HELP, PpdGroup, setup_logging

app = typer.Typer(
    name="ppd",
    cls=PpdGroup,
    rich_markup_mode=None,
    help="PatchPoison daemon: publish multi-view photos without handing out a free 3D scan.",
    epilog=EXIT_CODES_HELP,
    no_args_is_help=True,
    add_completion=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ppd")
    except PackageNotFoundError:  # run from a checkout: the version pyproject.toml declares
        import tomllib
        from pathlib import Path

        pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
        try:
            return tomllib.loads(pyproject.read_text())["project"]["version"]
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "unknown"


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"ppd {_version()}")
        raise typer.Exit()


@app.callback()
def _main(
    ctx: typer.Context,
    verbose: int = typer.Option(
        0, "--verbose", "-v", count=True, help="Say more: -v names each file, -vv debug logging."
    ),
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    setup_logging(verbose, daemon=ctx.invoked_subcommand == "watch")
    ctx.obj = {"verbose": verbose}


COMMAND_MODULES = (
    "daemon.cli_poison", "daemon.cli_watch", "daemon.cli_demo", "daemon.cli_verify",
    "daemon.cli_auto",  # automatic mode (issue 9)
    "daemon.cli_experiment",  # `ppd experiment`, `ppd report` (issue 7)
    "daemon.cli_store",  # `ppd store check`, `ppd store rebuild`
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
