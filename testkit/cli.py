"""`ppd` as the CLI tests run it: typer's CliRunner in this process, on the ppd_env folders."""

from __future__ import annotations

from typer.testing import CliRunner

from daemon.cli import app

runner = CliRunner()


def said(*args: str) -> tuple[int, str]:
    """The exit status and output of `ppd ARGS`, its lines joined by single spaces: a sentence reads the
    same at any terminal width."""
    result = runner.invoke(app, list(args))
    return result.exit_code, " ".join(result.output.split())
