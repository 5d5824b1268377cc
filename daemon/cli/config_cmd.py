"""`ppd config show` (the effective configuration as TOML) and `ppd config path`."""

from __future__ import annotations

import typer

from daemon.cli.errors import die, warning

config_app = typer.Typer(help="Show the configuration or where it lives.", no_args_is_help=True)


@config_app.command("show")
def config_show() -> None:
    """The effective configuration (defaults + config.toml) as TOML."""
    from daemon.cli.config_warnings import config_warnings
    from daemon.config import Config, ConfigError
    from daemon.paths import AppPaths

    paths = AppPaths.from_env()
    try:
        config = Config.load(paths)
    except ConfigError as exc:
        raise die(str(exc)) from None
    typer.echo(f"# {paths.config_file}{'' if config.source else ' (not present: defaults)'}")
    typer.echo(config.to_toml(), nl=False)
    for line in config_warnings(paths, config):  # a misspelt [datasets.NAME] (a seventh black-box review)
        warning(line)


@config_app.command("path")
def config_path() -> None:
    """Where config.toml, the data, the vault and the outbox are."""
    from daemon.paths import AppPaths

    paths = AppPaths.from_env()
    typer.echo(f"config   {paths.config_file}")
    typer.echo(f"data     {paths.data_dir}")
    typer.echo(f"store    {paths.db_path}")
    typer.echo(f"vault    {paths.vault_dir}")
    typer.echo(f"key      {paths.data_dir / 'seal.key'}")
    typer.echo(f"outbox   {paths.outbox}")
    typer.echo(f"cache    {paths.cache_dir}")


def register(app: typer.Typer) -> None:
    app.add_typer(config_app, name="config")
