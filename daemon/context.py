"""The application's context: where ppd keeps its data, its configuration, the provenance store
and the vault, opened once per process and handed to every stage."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from daemon.config import Config, ConfigError
from daemon.locks import DEFAULT_FILE_WAIT_S, file_lock, release_store, use_store
from daemon.paths import AppPaths
from daemon.store import Store
from daemon.store.vault import Vault


@dataclass
class AppContext:
    paths: AppPaths
    config: Config
    store: Store
    vault: Vault
    lock_wait_s: float = DEFAULT_FILE_WAIT_S  # how long protect/restore wait for another ppd's file lock
    _seal_key: bytes | None = field(default=None, repr=False)
    # the key file it was read from (daemon.store.sealkey.KeyStamp); a pool worker gets its caller's
    key_stamp: tuple[int, int, int] | None = field(default=None, repr=False)
    _store_hold: int | None = field(default=None, repr=False)  # the store lock's fd (daemon.locks)
    # once true, a wait for another ppd process's file lock ends (daemon.locks.WaitLeft): `ppd poison`
    # stopped by Ctrl-C finishes its own files, not one another process works on
    give_up_waits: Callable[[], bool] | None = field(default=None, repr=False)

    def seal_key(self) -> bytes:
        """The installation's seal key (daemon.store.sealkey), created on first use. SealKeyError once
        its file is replaced: a long `ppd poison` or `ppd watch` sealed on with a key no longer on disk
        (a diff review), and a worker started since loaded the new one: two keys in one run."""
        if self._seal_key is None:
            from daemon.store.sealkey import SealKeyError, changed_key_message, key_path, load_key_stamped

            key, stamp = load_key_stamped(self.paths.data_dir)
            if self.key_stamp is not None and stamp != self.key_stamp:
                raise SealKeyError(changed_key_message(key_path(self.paths.data_dir)))
            self._seal_key, self.key_stamp = key, stamp
        else:
            from daemon.store.sealkey import check_key_stamp

            assert self.key_stamp is not None
            check_key_stamp(self.paths.data_dir, self.key_stamp)  # one stat per call (a few µs)
        return self._seal_key

    @classmethod
    def open(cls, paths: AppPaths | None = None, *, store_held: bool = False) -> AppContext:
        """store_held: the caller holds the store lock already, exclusive (daemon.locks.store_alone:
        `ppd dataset forget`); a shared hold of its own would wait on the caller's."""
        paths = paths or AppPaths.from_env()
        config = Config.load(paths)  # reads one file: the publish folders, checked before anything is made
        _check_publish_dirs(config, paths)
        published = [config.publish_dir] + [d.publish_dir for d in config.datasets.values()]
        paths.ensure(published=[p for p in published if p is not None])
        from daemon.store.sealkey import clear_stale_key_temporaries

        clear_stale_key_temporaries(paths.data_dir)  # a killed ppd's copy of the secret key
        # held until close: a `ppd store rebuild` swapping the store meanwhile would lose what this
        # process writes to it (LockHeld while one runs)
        hold = None if store_held else use_store(paths.data_dir)
        try:
            # a new store beside a vault that holds originals: the earlier one was lost; say so
            # (and keep saying it) instead of starting a silent empty store (daemon.store.core)
            store = Store.open_or_warn(paths.db_path, paths.vault_dir)
        except BaseException:
            if hold is not None:
                release_store(paths.data_dir, hold)
            raise
        ctx = cls(paths=paths, config=config, store=store, _store_hold=hold,
                  vault=Vault(paths.vault_dir, config.vault.max_bytes, paths.config_file))  # fmt: skip
        try:
            _check_publish_roots(config, store)  # the dataset folders are the store's
        except BaseException:
            ctx.close()
            raise
        return ctx

    def close(self) -> None:
        try:
            self.store.close()
        finally:
            if self._store_hold is not None:
                hold, self._store_hold = self._store_hold, None
                release_store(self.paths.data_dir, hold)

    @contextlib.contextmanager
    def path_lock(self, path: Path) -> Iterator[None]:
        """One worker at a time on a path, across threads and ppd processes (daemon.locks)."""
        with file_lock(self.paths.data_dir, path, self.lock_wait_s, give_up=self.give_up_waits):
            yield


def _check_publish_dirs(config: Config, paths: AppPaths) -> None:
    """A publish folder inside the outbox is a bad setting (ConfigError: one line naming the key)."""
    where = f"{config.source}: " if config.source else ""
    for key, folder in configured_publish_dirs(config):
        if why := paths.publish_in_outbox(folder):
            raise ConfigError(f"{where}{key}: {why}; choose a folder outside it")


def _check_publish_roots(config: Config, store: Store) -> None:
    """A configured publish folder inside a dataset's folder, or holding one, is a bad setting
    (ConfigError, one line naming the key; daemon.paths.publish_in_datasets): a second `ppd poison`
    took the files published there in as the dataset's, and `ppd restore` put the originals there
    (a diff review, F3). The global publish_dir covers each NAME below it."""
    from daemon.paths import publish_in_datasets

    roots = [(str(row["name"]), Path(row["root"])) for row in store.datasets() if row["root"]]
    if not roots:
        return
    where = f"{config.source}: " if config.source else ""
    for key, folder in configured_publish_dirs(config):
        if why := publish_in_datasets(folder, roots):
            raise ConfigError(f"{where}{key}: {why}; choose a folder outside it")


def configured_publish_dirs(config: Config) -> list[tuple[str, Path]]:
    """(config key, folder) for each publish folder config.toml sets."""
    keys = [("publish_dir", config.publish_dir)]
    keys += [(f"datasets.{name}.publish_dir", o.publish_dir) for name, o in config.datasets.items()]
    return [(key, folder) for key, folder in keys if folder is not None]
