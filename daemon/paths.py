"""Where ppd keeps things: data (store, vault, verification runs), config, cache and the outbox.

Defaults follow the platform's conventions through platformdirs (XDG on Linux):
- data:   user_data_dir("ppd")   e.g. ~/.local/share/ppd   (store, vault, runs; mode 0700)
- config: user_config_dir("ppd") e.g. ~/.config/ppd        (config.toml)
- cache:  user_cache_dir("ppd")  e.g. ~/.cache/ppd
- outbox: ~/PPD Outbox — a visible folder in the home directory, because it is where the
  creator drops photos by hand; it is usually on the same filesystem as the data folder, so
  the vault can keep originals by reflink where the filesystem supports it (no extra disk).

Environment overrides (tests use them): PPD_DATA_DIR, PPD_CONFIG_DIR, PPD_OUTBOX, PPD_CACHE_DIR.
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import platformdirs

from daemon.platform import mounts_of_device
from poisoner.errors import ExitStatus, PpdError

APP_NAME = "ppd"
DEFAULT_OUTBOX_NAME = "PPD Outbox"
VAULT_DIR_NAME = "vault"  # DATA_DIR/vault (the seal key's module looks there too)
EXPERIMENTS_DIR_NAME = "experiments"  # DATA_DIR/experiments/NAME: `ppd experiment`'s default folders
PRIVATE_MODE = 0o700  # the vault holds unpoisoned originals: nobody else may read them


class DataPlaceError(PpdError):
    """ppd's data folder is somewhere the vault's originals would be published or mixed with photos."""

    exit_status = ExitStatus.ENVIRONMENT


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

    def experiment_dir(self, name: str) -> Path:
        """`ppd experiment`'s default folder for a dataset or a folder of that name (its staged
        originals, reconstructions, tables and plots): ppd's own, inside the data folder."""
        return self.data_dir / EXPERIMENTS_DIR_NAME / experiment_name(name)

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
            vault_dir=data_dir / VAULT_DIR_NAME,
            db_path=data_dir / "ppd.sqlite3",
            runs_dir=data_dir / "runs",
            cache_dir=pick("PPD_CACHE_DIR", platformdirs.user_cache_dir(APP_NAME)),
        )

    def ensure(self, published: Iterable[Path] = ()) -> None:
        """Create every folder: data, vault and runs private (0700, tightened if looser); the
        config and cache folders 0700 when ppd creates them, whatever the umask (an existing one
        keeps its mode: the user's choice). The outbox is the user's visible folder: created
        under the umask, as `mkdir -p` would. A data folder where the vault's originals would be
        published, or that is a photo or holds photos, is refused before anything is made (a
        black-box review: PPD_DATA_DIR in the outbox put the originals there; on a photo, made it 0700).
        published: the folders the config publishes to (publish_dir), refused as the outbox is."""
        if why := self.data_dir_problem(published):
            raise DataPlaceError(f"the data folder {self.data_dir} (PPD_DATA_DIR) cannot hold the vault of "
                                 f"originals: {why}")  # fmt: skip
        for private in (self.data_dir, self.vault_dir, self.runs_dir):
            make_private_dir(private)
        for folder in (self.config_dir, self.cache_dir):
            make_dirs_private(folder)
        self.outbox.mkdir(parents=True, exist_ok=True)


    def data_dir_problem(self, published: Iterable[Path] = ()) -> str | None:
        """Why the data folder cannot hold the vault, in words; None when it can."""
        data, outbox = self.data_dir.resolve(), self.outbox.resolve()
        if data.is_relative_to(outbox):
            return f"inside the outbox {self.outbox}, whose files are published"
        for folder in (Path(f).expanduser().resolve() for f in published):
            if data.is_relative_to(folder):
                return f"inside the publish folder {folder}"
            if folder.is_relative_to(data):
                return f"the publish folder {folder} is inside it"
        if data.exists() and not data.is_dir():
            return "not a folder"
        if data.is_dir() and (photo := _a_photo_in(data)) is not None:
            return f"it holds photos or videos ({photo}): not a folder of ppd's own"
        return None


    def publishes_data(self, folder: Path) -> str | None:
        """Why publishing folder (a publish folder, a dataset's folder patched in place) would publish
        ppd's data folder (the vault of originals, the seal key, restore's kept copies) or write into it;
        None when it would not. A home folder counts for itself alone: its subfolders are the user's own
        (the data folder's default, ~/.local/share/ppd, is one). A second black-box review: `dataset set
        --publish-dir` took a folder holding the vault, and data/displaced itself."""
        data, folder = self.data_dir.resolve(), Path(folder).expanduser().resolve()
        if data != folder and published_with(folder, data.parent):
            return f"the data folder {self.data_dir} (vault of originals, seal key) is inside {folder}"
        if folder.is_relative_to(data):
            return f"{folder} is inside ppd's data folder {self.data_dir}"
        return None


    def publish_dir_problem(self, folder: Path, roots: Iterable[tuple[str, Path]] = ()) -> str | None:
        """Why folder cannot be a publish folder (publishes_data, publish_in_outbox, publish_in_datasets
        over roots: (dataset, its folder)); None: it can."""
        return (self.publishes_data(folder) or self.publish_in_outbox(folder)
                or publish_in_datasets(folder, roots))  # fmt: skip

    def publish_in_outbox(self, folder: Path) -> str | None:
        """Why a publish folder inside the outbox is refused: the daemon took the files it published
        there in as a new dataset, which `ppd status` called not patched yet (a black-box review);
        as `--out` inside the dataset is refused. One that holds the outbox is refused too: the
        outbox's waiting, failed and unpatchable originals would be in the published tree (a diff
        review, F3). None when it is apart from it."""
        box, where = self.outbox.resolve(), Path(folder).expanduser().absolute()
        if where.resolve().is_relative_to(box) or where.is_relative_to(self.outbox):
            return f"{where} is inside the outbox {self.outbox}, whose new files ppd patches as a dataset"
        if published_with(where.resolve(), box):
            return f"{where} holds the outbox {self.outbox}, whose originals are not patched yet"
        return None


def publish_in_datasets(folder: Path, roots: Iterable[tuple[str, Path]]) -> str | None:
    """Why a publish folder inside a dataset's folder (or its own) or holding one is refused; None
    when it is apart from every root given ((dataset, folder) pairs). A diff review (F3): with
    `--publish-dir castle/public`, a second `ppd poison castle` took the published files in as
    castle's (their rows 'moved' there), and `ppd restore castle` then wrote the unprotected
    originals into castle/public; a folder holding a dataset's would publish its originals."""
    where = Path(folder).expanduser().absolute()
    real = where.resolve()
    for name, root in roots:
        root = Path(root).expanduser().absolute()
        # a dataset of the home folder holds the files right in it, not its subfolders (published_with)
        if published_with(root.resolve(), real) or published_with(root, where):
            return (f"{where} is inside the folder of dataset {name!r}, {root}: ppd would take the published "
                    "files in as the dataset's, and `ppd restore` would put the originals there")  # fmt: skip
        if published_with(real, root.resolve()):
            return f"{where} holds the folder of dataset {name!r}, {root}, whose originals would be published"
    return None


def published_with(folder: Path, where: Path) -> bool:
    """Whether what lies in the folder `where` is published with `folder` (both resolved): anywhere
    below it, but for a home folder only right in it (its subfolders are the user's own: the data
    folder's default, ~/.local/share/ppd, is one). `ppd key export`, `ppd preview` and the data folder's
    checks share it."""
    return where == folder if folder == Path.home().resolve() else where.is_relative_to(folder)


def experiment_name(name: str) -> str:
    """A dataset's or a folder's name as one safe folder name, one per name: a name the safe form changes
    gets a short hash of itself (`my shoot` and `my_shoot` shared one folder, and forgetting one removed
    the other's experiment: a diff review)."""
    import hashlib

    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "experiment"
    if safe == name and name not in (".", ".."):
        return safe
    return f"{safe}-{hashlib.sha256(name.encode('utf-8', 'surrogateescape')).hexdigest()[:8]}"


def _a_photo_in(folder: Path, depth: int = 3, budget: int = 20_000) -> str | None:
    """A photo or video (any format, protectable or not) within `depth` folders of folder, outside
    ppd's own (vault, runs, experiments, hidden ones), looking at no more than `budget` entries;
    None: none."""
    from poisoner.media import media_class

    # displaced: `ppd restore --force`'s copies; experiments: `ppd experiment`'s plots and staged originals
    # (a black-box review: its tradeoff.png there made every command refuse the data folder)
    own = {"vault", "runs", "attempts", "locks", "displaced", EXPERIMENTS_DIR_NAME}
    for here, dirs, files in os.walk(folder):
        level = len(Path(here).relative_to(folder).parts)
        skipped = own if level == 0 else set()
        dirs[:] = [] if level >= depth else [d for d in dirs if not d.startswith(".") and d not in skipped]
        for name in files:
            if media_class(Path(here, name)) is not None:
                return str(Path(here, name).relative_to(folder))
        budget -= len(files) + len(dirs)
        if budget <= 0:
            break
    return None


SERVICE_UNIT = "ppd.service"  # `ppd service install` writes it into user_unit_dir()


def user_unit_dir(env: Mapping[str, str] | None = None) -> Path:
    """systemd's folder of the user's own units (daemon.watch.service installs ppd's there)."""
    env = os.environ if env is None else env
    base = env.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base).expanduser() / "systemd" / "user"


def make_dirs_private(folder: Path) -> None:
    """mkdir -p where every folder created is 0700 whatever the umask (mkdir's mode is only an
    upper bound, and Python gives created parents 0777 minus the umask); existing ones untouched."""
    folder = Path(folder)
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    for created in reversed(missing):
        try:
            created.mkdir(mode=PRIVATE_MODE)
        except FileExistsError:
            continue  # made meanwhile by another process: its mode is its own
        os.chmod(created, PRIVATE_MODE)


def make_private_dir(folder: Path) -> None:
    """mkdir -p with mode 0700 on every folder created and on the leaf, tightened if it already
    existed looser."""
    make_dirs_private(folder)
    if folder.stat().st_mode & 0o077:
        os.chmod(folder, PRIVATE_MODE)


@dataclass(frozen=True)
class Filesystem:
    """The filesystem a path lives on, as an error message needs it."""

    mount_point: Path
    fs_type: str  # "ext4", "tmpfs", ... ("" when /proc/self/mountinfo cannot be read)
    source: str  # the device or "tmpfs"
    free_bytes: int  # available to this (unprivileged) user

    def describe(self) -> str:
        kind = f"{self.fs_type} " if self.fs_type else ""
        source = f" ({self.source})" if self.source and self.source != self.fs_type else ""
        return f"{kind}filesystem mounted at {self.mount_point}{source}, {self.free_bytes} bytes free"


def filesystem_of(path: Path) -> Filesystem:
    """Which filesystem holds path (its nearest existing ancestor) and how much room is left.

    Mount point and type come from /proc/self/mountinfo (matched by device number, longest
    mount point first, so bind mounts and nested mounts resolve to the right entry); where that
    is not available, the mount point is found by walking up until the device changes."""
    path = Path(path).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    st = os.stat(path)
    vfs = os.statvfs(path)
    free = vfs.f_bavail * vfs.f_frsize
    real = Path(os.path.realpath(path))
    for mount_point, fs_type, source in mounts_of_device(st.st_dev):
        if real == mount_point or mount_point in real.parents:
            return Filesystem(mount_point, fs_type, source, free)
    return Filesystem(_walk_to_mount_point(real, st.st_dev), "", "", free)


def _walk_to_mount_point(path: Path, dev: int) -> Path:
    while path != path.parent:
        parent = path.parent
        try:
            if os.stat(parent).st_dev != dev or not stat.S_ISDIR(os.stat(parent).st_mode):
                return path
        except OSError:
            return path
        path = parent
    return path


def preview_folder(cache_dir: Path, folder: Path) -> Path:
    """Where `ppd preview` caches the pictures of one photo folder's files: previews/FOLDER-HASH in the
    cache folder. By the stem alone, A/0000.jpg's preview was overwritten by B/0000.jpg's (a black-box
    review); the folder's name says whose it is, a hash of its whole path tells apart two folders of one
    name (2024/A, 2025/A). `ppd dataset forget` removes a dataset's (they show its originals)."""
    import hashlib

    folder = Path(os.path.abspath(folder))
    tag = hashlib.sha256(os.fsencode(folder)).hexdigest()[:8]
    return Path(cache_dir) / "previews" / f"{folder.name or 'root'}-{tag}"
