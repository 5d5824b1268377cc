"""`ppd key export FILE` and `ppd key import FILE`: move the installation's seal key (the secret
that lets ppd recognise its own patched files, daemon.store.sealkey) to a new machine, with the vault;
`ppd key new`: start a new key knowingly when the old one is lost (ppd never does on its own while
the vault holds originals)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from daemon.cli.errors import die, refuse_missing_folder
from daemon.cli.published import in_data_folder, published_folder_holding
from poisoner.errors import ExitStatus

if TYPE_CHECKING:
    from daemon.paths import AppPaths

key_app = typer.Typer(
    help="The seal key: what lets ppd, and only ppd here, recognise the files it patched. Back it up "
    "with the vault (`ppd key export FILE`): without it, files patched here are not recognised once "
    "the store is lost.",
    no_args_is_help=True,
)


@key_app.command("export")
def key_export(
    file: Path = typer.Argument(
        ..., help="Where to write the key (mode 0600; outside ppd's data folder and what is published)."
    ),
    force: bool = typer.Option(False, "--force", help="Replace FILE if it exists."),
) -> None:
    """Write this installation's seal key to FILE (created on first use if there is none yet)."""
    import os

    from daemon.paths import AppPaths
    from daemon.store.sealkey import SealKeyError, load_key

    refuse_missing_folder(file)
    paths = AppPaths.from_env()
    published = published_folder_holding(file, paths)
    if published is not None:
        raise die(f"{file} is inside {published}, whose files are published; the key would go out with your "
                  "photos: write it elsewhere")  # fmt: skip
    if in_data_folder(file, paths):  # a backup there is lost with the folder it backs up
        raise die(f"{file} is inside ppd's data folder {paths.data_dir} (PPD_DATA_DIR), and would be lost "
                  "with it: keep the backup outside ppd's data folder")  # fmt: skip
    try:
        key = load_key(paths.data_dir)
    except (SealKeyError, OSError) as exc:
        raise die(str(exc), ExitStatus.ENVIRONMENT) from None
    assert key is not None
    flags = os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC | (os.O_TRUNC if force else os.O_EXCL)
    try:
        fd = os.open(file, flags, 0o600)
    except FileExistsError:
        raise die(f"{file} exists; not overwriting it (use --force)") from None
    except OSError as exc:
        raise die(f"cannot write {file}: {exc.strerror}", ExitStatus.ENVIRONMENT) from None
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, key.hex().encode() + b"\n")
        os.fsync(fd)
    finally:
        os.close(fd)
    typer.echo(f"seal key written to {file} (keep it private; `ppd key import {file}` on the new machine)")


@key_app.command("import")
def key_import(
    file: Path = typer.Argument(..., help="A key written by `ppd key export`."),
    force: bool = typer.Option(
        False,
        "--force",
        help="Replace a different key already here (files it sealed are then not recognised).",
    ),
) -> None:
    """Make the key in FILE this installation's seal key (before the first run on a new machine)."""
    from daemon.paths import AppPaths
    from daemon.store.sealkey import SealKeyError, install_key, key_path, load_key, parse_key

    paths = AppPaths.from_env()
    try:
        key = parse_key(file.read_bytes()[:4096], file)
        current = load_key(paths.data_dir, create=False)
    except SealKeyError as exc:
        raise die(str(exc)) from None
    except OSError as exc:
        raise die(f"cannot read {exc.filename}: {exc.strerror}") from None
    if current == key:
        typer.echo(f"{key_path(paths.data_dir)} already holds this key")
        return
    # how much the key being replaced sealed, by the seals of the files, said before and after
    sealed = sealed_originals(paths, current, key)
    if current is not None and not force:
        raise die(_refusal(key_path(paths.data_dir), sealed, file))
    with _alone(paths.data_dir, "import the key"):
        where = install_key(paths.data_dir, key, replace=True)
    typer.echo(f"seal key installed at {where}")
    _remind_restart()
    if current is not None and sealed.replaced_up_to:
        typer.echo(f"the key it replaced sealed the patched files of {_replaced_words(sealed)}")
    if sealed.incoming:
        typer.echo(f"the key you installed is the one that sealed the patched files of {sealed.incoming} "
                   "original(s): ppd recognises them by their seal")  # fmt: skip


@dataclass(frozen=True)
class Sealed:
    """Which key sealed the patched files of the vault's originals, as their seals say."""

    replaced: int  # the key being replaced (its seal read in the file)
    incoming: int  # the key being installed
    unread: int  # rows whose file has no seal to read (edited, moved away): either key, or another
    unnamed: int  # originals no row names (a lost or rebuilt store): where their files are is unknown

    @property
    def replaced_up_to(self) -> int:
        return self.replaced + self.unread + self.unnamed


def _refusal(path: Path, sealed: Sealed, file: Path) -> str:
    """The refusal of a different key without --force, with what the key there sealed."""
    if sealed.replaced_up_to:
        return (f"{path} holds a different key, which sealed the patched files of {_originals(sealed)} "
                "in the vault: they would no longer be recognised after a store loss (use --force to replace "
                "it)")  # fmt: skip
    theirs = f" (the key in {file} sealed those of {sealed.incoming} original(s))" if sealed.incoming else ""
    return f"{path} holds a different key, which sealed none of the patched files here{theirs}; " \
        "use --force to replace it"


def _replaced_words(sealed: Sealed) -> str:
    known = "their rows in the store still know them; after a store loss they are not recognised"
    if sealed.unnamed:  # those no row names: recognised by their seal alone, which this key cannot read
        known = (f"the store's rows still know {sealed.replaced + sealed.unread} of them; ppd no longer "
                 "recognises the others")  # fmt: skip
    return f"{_originals(sealed)}: {known}"


def sealed_originals(paths: AppPaths, current: bytes | None, incoming: bytes) -> Sealed:
    """Which key sealed the patched file of each original the store's rows name, read from the seal
    in the file (the rows counted every patched file against the key being replaced, even after the
    key that sealed them was put back: a fourth black-box review); what no seal tells is "unread".
    A run killed mid-file leaves its original in the vault and its file as it was: not sealed (all
    the vault's originals were counted, 19 where 17 were sealed: a third black-box review)."""
    import sqlite3

    from daemon.protect.rebuild_carry import open_read_only
    from poisoner.provenance import sealing_key

    vault = {p.name for p in paths.vault_dir.glob("??/*") if len(p.name) == 64}
    keys = [k for k in (current, incoming) if k is not None]
    by_key: list[set[str]] = [set() for _ in keys]
    unread: set[str] = set()
    named: set[str] = set()
    if (conn := open_read_only(paths.db_path)) is not None:
        try:
            with contextlib.suppress(sqlite3.Error):  # a damaged store tells what it can
                rows = conn.execute(
                    "SELECT path, state, original_sha256, poisoned_sha256 FROM files"
                    " WHERE original_sha256 NOT NULL"
                )
                for path, state, original, patched in rows:
                    named.add(original)
                    if not _sealed_file_may_be_there(state, patched):  # not read: a large store has many
                        continue
                    who = sealing_key(Path(path), keys)
                    if who is not None and who >= 0:
                        by_key[who].add(original)
                    elif who is None and _unread(Path(path), state, original, patched):
                        unread.add(original)
        finally:
            conn.close()
    replaced, incoming_set = (by_key if current is not None else [set(), *by_key])
    return Sealed(len(replaced), len(incoming_set), len(unread - replaced - incoming_set), len(vault - named))


def _sealed_file_may_be_there(state: str, patched: str | None) -> bool:
    """Whether the row's path may hold a file ppd sealed: one patched (not restored since: the original
    is back), one in flight, or one a poison refused (sealed with another key)."""
    from daemon.states import FileState

    if state == FileState.RESTORED:
        return False
    return bool(patched) or state in (FileState.PENDING, FileState.FAILED)


def _unread(path: Path, state: str, original: str, patched: str | None) -> bool:
    """Whether a row whose file shows no seal may have had its file sealed all the same: one patched
    and since edited or moved away; one in flight whose file is no longer its original (the rename
    done, the row not yet)."""
    from daemon.states import FileState

    return bool(patched) or (state == FileState.PENDING and not _never_replaced(path, original))


def _never_replaced(path: Path, original: str) -> bool:
    """Whether a run stopped mid-file left path as it was (its original), or no file there: nothing
    sealed. A file replaced since may be ppd's output, the rename done and the row not yet."""
    from daemon.store.vault import sha256_file

    try:
        return sha256_file(path) == original
    except FileNotFoundError:
        return True
    except OSError:  # unreadable: no one can tell
        return False


def _originals(sealed: Sealed) -> str:
    """"3 original(s)"; "up to 5 original(s) (3 by their seals)" where the seals cannot tell."""
    if sealed.replaced_up_to == sealed.replaced:
        return f"{sealed.replaced} original(s)"
    by_seal = f" ({sealed.replaced} by their seals)" if sealed.replaced else ""
    return f"up to {sealed.replaced_up_to} original(s){by_seal}"


@contextlib.contextmanager
def _alone(data_dir: Path, then: str) -> Iterator[None]:
    """No other ppd process on this data folder while the key changes: a running `ppd watch` or
    `ppd poison` seals with the key it loaded, one no longer on disk (a diff review); refused with one
    line, exit 3."""
    from daemon.locks import LockHeld, store_alone, watch_running, watching

    if holders := watching(data_dir):
        why = " and seals with the key it loaded"
        raise die(watch_running(holders[0], then, why), ExitStatus.ENVIRONMENT)
    try:
        with store_alone(data_dir, "ppd is changing the seal key", then):
            yield
    except LockHeld as exc:
        raise die(exc, ExitStatus.ENVIRONMENT) from None


@key_app.command("new")
def key_new() -> None:
    """Start a new seal key when the old one is lost for good (`ppd key import FILE` brings a saved one
    back instead). Files patched with the old key are then not recognised by their seal: where the store
    still has their rows it knows them by hash; where it was lost too, `ppd poison` would patch them
    again as new photos."""
    from daemon.paths import AppPaths
    from daemon.store.sealkey import SealKeyError, key_path, new_key

    paths = AppPaths.from_env()
    path = key_path(paths.data_dir)
    held = (f"{path} already holds a key; not replacing it "
            "(`ppd key import FILE --force` replaces it with a saved one)")  # fmt: skip
    if path.exists() or path.is_symlink():  # said first: stopping `ppd watch` for this would not help
        raise die(held)
    try:
        with _alone(paths.data_dir, "make the new key"):
            where = new_key(paths.data_dir)
    except FileExistsError:
        raise die(held) from None
    except (SealKeyError, OSError) as exc:
        raise die(f"cannot write {key_path(paths.data_dir)}: {exc}", ExitStatus.ENVIRONMENT) from None
    typer.echo(f"new seal key made at {where}; back it up: `ppd key export FILE`")
    _remind_restart()


def register(app: typer.Typer) -> None:
    app.add_typer(key_app, name="key")


def _remind_restart() -> None:
    from daemon.watch.service import restart_reminder

    if line := restart_reminder():
        typer.echo(line)
