"""Where ppd keeps things: data (store, vault, verification runs), config, cache and the outbox.

Defaults follow the platform's conventions through platformdirs (XDG on Linux):
- data:   user_data_dir("ppd")   e.g. ~/.local/share/ppd   (store, vault, runs; mode 0700)
- config: user_config_dir("ppd") e.g. ~/.config/ppd        (config.toml)
- cache:  user_cache_dir("ppd")  e.g. ~/.cache/ppd
- outbox: ~/PPD Outbox — a visible folder in the home directory, because it is where the
  creator drops photos by hand; it is usually on the same filesystem as the data folder, so
  the vault can keep originals by hard link (no copy, no extra disk).

Environment overrides (tests use them): PPD_DATA_DIR, PPD_CONFIG_DIR, PPD_OUTBOX, PPD_CACHE_DIR.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import platformdirs

APP_NAME = "ppd"
DEFAULT_OUTBOX_NAME = "PPD Outbox"
PRIVATE_MODE = 0o700  # the vault holds unpoisoned originals: nobody else may read them


@dataclass(frozen=True)
class AppPaths:
    data_dir: Path
    config_dir: Path
    outbox: Path
    vault_dir: Path
    db_path: Path
    runs_dir: Path
    cache_dir: Path

    @property
    def config_file(self) -> Path:
        return self.config_dir / "config.toml"

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> AppPaths:
        """Paths from the environment overrides, else the platform defaults."""
        env = os.environ if env is None else env

        def pick(var: str, default: str | Path) -> Path:
            value = env.get(var)
            return Path(value).expanduser().absolute() if value else Path(default).expanduser().absolute()

        data_dir = pick("PPD_DATA_DIR", platformdirs.user_data_dir(APP_NAME))
        return cls(
            data_dir=data_dir,
            config_dir=pick("PPD_CONFIG_DIR", platformdirs.user_config_dir(APP_NAME)),
            outbox=pick("PPD_OUTBOX", Path.home() / DEFAULT_OUTBOX_NAME),
            vault_dir=data_dir / "vault",
            db_path=data_dir / "ppd.sqlite3",
            runs_dir=data_dir / "runs",
            cache_dir=pick("PPD_CACHE_DIR", platformdirs.user_cache_dir(APP_NAME)),
        )

    def ensure(self) -> None:
        """Create every folder; data, vault and runs are private (0700)."""
        for private in (self.data_dir, self.vault_dir, self.runs_dir):
            make_private_dir(private)
        for folder in (self.config_dir, self.cache_dir, self.outbox):
            folder.mkdir(parents=True, exist_ok=True)


def make_private_dir(folder: Path) -> None:
    """mkdir -p with mode 0700 on the leaf, tightened if it already existed looser."""
    folder.mkdir(parents=True, exist_ok=True, mode=PRIVATE_MODE)
    if folder.stat().st_mode & 0o077:
        os.chmod(folder, PRIVATE_MODE)
