"""The `ppd` command line: one module per command (or command group), registered here.

Each command module is light at import (typer and the shared option sets); what a command runs
is imported inside it, so `ppd poison --help` and `ppd status` never load numpy, PIL, PyAV,
torch or pycolmap (tests/daemon/cli/test_cli_startup.py checks it).

| module | commands |
|---|---|
| daemon.cli.poison_cmd | `poison` (planning: daemon.cli.planning) |
| daemon.cli.restore_cmd | `restore` |
| daemon.cli.preview_cmd | `preview` |
| daemon.cli.status_cmd | `status` (queries: daemon.cli.status_queries) |
| daemon.cli.dataset_cmd | `dataset show`, `dataset set`, `dataset forget` |
| daemon.cli.config_cmd | `config show`, `config path` |
| daemon.cli.watch_cmd | `watch`, `service install/uninstall/status` |
| daemon.cli.demo_cmd | `demo` |
| daemon.cli.verify_cmd | `verify` (tables: daemon.cli.verify_tables; targets: daemon.cli.targets) |
| daemon.cli.auto_cmd | `auto` |
| daemon.cli.experiment_cmd | `experiment` |
| daemon.cli.report_cmd | `report` |
| daemon.cli.store_cmd | `store check`, `store rebuild` |
| daemon.cli.key_cmd | `key export`, `key import`, `key new` (the seal key, daemon.store.sealkey) |

Shared: daemon.cli.errors (one-line errors, exit codes), daemon.cli.output (consoles, logging),
daemon.cli.options (shared option sets), daemon.cli.group (the top-level group).
"""

from __future__ import annotations

import os
import signal
import sys
from types import FrameType


def _interrupted_while_loading(_signum: int, _frame: FrameType | None) -> None:
    """Ctrl-C while ppd is still loading: nothing was done yet; one line, no traceback."""
    os.write(2, b"ppd: interrupted\n")
    os._exit(130)


# The `ppd` script (or `python -m daemon.cli`), not a test importing the app: a Ctrl-C during the
# imports below ends quietly. PpdGroup.main hands SIGINT back to Python once they are done.
if os.path.basename(sys.argv[0]) in ("ppd", "-m"):
    signal.signal(signal.SIGINT, _interrupted_while_loading)

import typer  # noqa: E402

from daemon.cli.errors import EXIT_CODES_HELP  # noqa: E402
from daemon.cli.group import PpdGroup  # noqa: E402
from daemon.cli.output import setup_logging  # noqa: E402

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


def _print_version(value: bool) -> None:
    if value:
        from daemon.version import ppd_version

        typer.echo(f"ppd {ppd_version()}")
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


COMMAND_MODULES = {
    "poison": "daemon.cli.poison_cmd", "restore": "daemon.cli.restore_cmd",
    "preview": "daemon.cli.preview_cmd", "status": "daemon.cli.status_cmd",
    "dataset": "daemon.cli.dataset_cmd", "config": "daemon.cli.config_cmd",
    "watch": "daemon.cli.watch_cmd", "service": "daemon.cli.watch_cmd", "demo": "daemon.cli.demo_cmd",
    "verify": "daemon.cli.verify_cmd", "auto": "daemon.cli.auto_cmd",
    "experiment": "daemon.cli.experiment_cmd", "report": "daemon.cli.report_cmd",
    "store": "daemon.cli.store_cmd", "key": "daemon.cli.key_cmd",
}  # fmt: skip


def _modules_for(argv: list[str]) -> tuple[str, ...]:
    """`ppd COMMAND ...` loads only that command's module: start-up pays for one command, and
    `ppd watch`, the long-lived daemon, keeps the others' imports (and memory) out of the resident
    process. Anything else (`ppd --help`, `ppd -v status`, an unknown word, tests importing the
    app) loads every command, in the order `ppd --help` lists them."""
    if len(argv) > 1 and argv[1] in COMMAND_MODULES:
        return (COMMAND_MODULES[argv[1]],)
    return tuple(dict.fromkeys(COMMAND_MODULES.values()))


def _register() -> None:
    for name in _modules_for(sys.argv):
        # __import__, not importlib.import_module: `python -X importtime` sees only the former,
        # and tests/daemon/cli/test_cli_startup.py reads what each command imports from it.
        __import__(name, fromlist=["register"]).register(app)


_register()
