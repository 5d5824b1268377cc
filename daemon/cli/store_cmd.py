"""`ppd store check` and `ppd store rebuild [FOLDER...]`: the provenance store's health, and a new
store from the vault and the markers in patched files when it was lost or damaged (docs/STORE.md).

Exit status, as `ppd --help` lists it for every command (one line on stderr, `ppd: error: ...`, never a
traceback): 0 = done / sound; 3 = the store is damaged, lost or missing next to originals, or the vault
lost originals (check), or the rebuild cannot be done here (a store made by a newer ppd too, without
--force); 2 = a sound store without --force; 1 = a rebuild that recovered none of the vault's originals,
or a dataset's spec (each named, with what gives it back).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from daemon.cli.errors import die, error
from poisoner.errors import ExitStatus

if TYPE_CHECKING:
    from rich.console import Console

store_app = typer.Typer(
    help="The provenance store: check it, rebuild it from the vault.", no_args_is_help=True
)


@functools.cache
def _console(stderr: bool = False) -> Console:
    from rich.console import Console

    return Console(stderr=stderr, soft_wrap=True, emoji=False)  # names as typed (":x:" stays text)


def _fail(message: str, code: int = ExitStatus.ENVIRONMENT) -> typer.Exit:
    return die(message, code)  # the one error style (a black-box review: `error:` here, exit 1)


@store_app.command("check")
def check() -> None:
    """Say whether the store opens sound, or what to run when it does not."""
    from daemon.paths import AppPaths
    from daemon.store import Store, StoreError, vault_holds_originals

    paths = AppPaths.from_env()
    if not paths.db_path.exists():
        if vault_holds_originals(paths.vault_dir):
            raise _fail(
                f"there is no store at {paths.db_path} but the vault {paths.vault_dir} holds originals; "
                "run `ppd store rebuild`"
            )
        _console().print(
            f"no store at {paths.db_path} yet (ppd creates it with the first file)",
            highlight=False,
            markup=False,
        )
        return
    try:
        store = Store(paths.db_path)  # not open_or_warn: its warning would repeat the error below
    except StoreError as exc:
        raise _fail(str(exc).splitlines()[0]) from None
    try:
        if lost := store.lost_note():
            raise _fail(lost)
        datasets = store.datasets()
        files = sum(store.counts(d["name"])["files"] for d in datasets)
        version = store.schema_version()
        missing = _missing_originals(store, paths.vault_dir, datasets)
    except StoreError as exc:
        raise _fail(str(exc).splitlines()[0]) from None
    finally:
        store.close()
    if missing:  # a black-box review: "sound" while the vault had lost the originals to restore
        raise _fail(f"{len(missing)} patched file(s) have no original in the vault {paths.vault_dir} "
                    f"({missing[0]}{', ...' if len(missing) > 1 else ''}): ppd cannot restore them; "
                    "keep the vault folder with your backups")  # fmt: skip
    _console().print(
        f"store {paths.db_path}: sound (schema {version}), {files} file row(s) in {len(datasets)} dataset(s)",
        highlight=False,
        markup=False,
    )


def _missing_originals(store: Any, vault_dir: Path, datasets: list[dict[str, Any]]) -> list[str]:
    """The patched files whose original is not in the vault (by name: a stat each, no hashing)."""
    from daemon.states import FileState
    from daemon.store.vault import blob_path

    missing = []
    for d in datasets:
        for row in store.files(d["name"], state=FileState.PATCHED):
            sha = row.get("original_sha256")
            if sha and not blob_path(vault_dir, sha).is_file():
                missing.append(row["path"])
    return missing


@store_app.command("rebuild")
def rebuild(
    folders: list[Path] = typer.Argument(
        None, help="More folders holding patched files (`ppd poison FOLDER` in place); one dataset each."
    ),
    force: bool = typer.Option(False, "--force", help="Rebuild a sound store too (it is kept aside)."),
    verbose: bool = typer.Option(
        False, "--verbose", "-v", help="A table per dataset, and every file left out."
    ),
) -> None:
    """Rebuild the store from the vault and the provenance markers in patched files.

    Walks the outbox, the publish folders, the dataset folders the old store still names and the
    FOLDERs given, without following symlinks. The old store is kept aside, never deleted. Stop
    `ppd watch` first."""
    from daemon.config import Config, ConfigError
    from daemon.paths import AppPaths
    from daemon.protect.rebuild import rebuild_store
    from daemon.store import StoreError
    from daemon.store.datasets import spec_not_recovered
    from daemon.store.vault import VaultError

    for folder in folders or []:  # a typo is refused before anything is touched (a black-box review:
        folder = folder.expanduser()  # `--force /no/such/dir` rebuilt the whole store, exit 0)
        if not folder.is_dir():
            what = "not a folder" if folder.exists() else "no such folder"
            raise _fail(f"{folder}: {what}", ExitStatus.USAGE)
    paths = AppPaths.from_env()
    try:
        config = Config.load(paths)
        paths.ensure()
        report = rebuild_store(paths, config=config, folders=folders or [], force=force)
    except (ConfigError, StoreError, VaultError) as exc:  # each with its status (a sound store: 2)
        raise _fail(str(exc).splitlines()[0], exc.exit_status) from None
    except OSError as exc:
        raise _fail(
            f"cannot rebuild the store: {exc.strerror or exc}: {exc.filename or paths.db_path}"
        ) from None
    _console().print(report.summary(), highlight=False, markup=False)
    from daemon.watch.service import restart_reminder

    if line := restart_reminder():  # a rebuild needs the daemon stopped: said how to start it again
        _console().print(line, highlight=False, markup=False)
    if verbose:
        _print_details(paths, report)
    for name, spec_id in sorted(report.spec_lost.items()):  # its next photo would have taken the config's
        error(f"{name}: {spec_not_recovered(name, spec_id)}")  # spec in silence (a black-box review)
    # nothing recovered of what the vault holds: not "done" (a black-box review: a lost seal key, exit 0)
    if report.spec_lost or (
        report.recorded == 0 and not report.carried.patched and report.unreferenced_originals
    ):
        raise typer.Exit(ExitStatus.FAILED)


def _print_details(paths: Any, report: Any) -> None:
    """--verbose: a table per dataset, every file left out, the folders walked."""
    from rich.table import Table

    from daemon.store import Store

    table = Table(title="rebuilt datasets")
    for column in ("dataset", "patched files", "spec", "spec from"):
        table.add_column(column)
    store = Store(paths.db_path)
    try:
        for name in sorted({d["name"] for d in store.datasets()}):
            spec_id = (store.dataset(name) or {}).get("spec_id")
            source = report.specs.get(spec_id, "not recovered") if spec_id else "not recovered"
            table.add_row(name, str(report.datasets.get(name, 0)), spec_id or "—", source)
    finally:
        store.close()
    _console().print(table)
    for label, items in (
        ("marked, original not in the vault", report.without_original),
        ("duplicate, skipped", report.conflicts),
    ):
        for path in items:
            _console().print(f"{label}: {path}", highlight=False, markup=False)
    for spec_id in report.specs_missing:
        _console().print(f"spec not recovered: {spec_id}", highlight=False, markup=False)
    _console().print(
        f"folders walked: {', '.join(str(f) for f in report.folders)}", highlight=False, markup=False
    )


def register(app: typer.Typer) -> None:
    app.add_typer(store_app, name="store")
