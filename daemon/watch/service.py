"""The systemd user service: render ppd.service with this installation's absolute paths,
install it under $XDG_CONFIG_HOME/systemd/user (default ~/.config/systemd/user), remove it,
report its state.

The unit runs exactly `ppd watch` (Type=notify: ready once the catch-up scan has queued its
work and the inotify watch is in place; WatchdogSec: systemd restarts a daemon that stops
answering). The sandbox is what a user service can take; see docs/DAEMON.md for each line.
MemoryDenyWriteExecute is left out on purpose: the verification children the daemon starts
inherit the sandbox, and torch's oneDNN JIT fails under it ("could not create a primitive",
measured with prctl(PR_SET_MDWE), the same W^X rule), while numpy, Pillow, PyAV and
pycolmap's SIFT work.

The template is package data (daemon/ppd.service.in, read with importlib.resources), so an
installed wheel renders the same unit as a checkout.
`systemd/ppd.service` in the repository is `render_unit(generic_layout())`: the same unit
with systemd specifiers (%h) for a `pip install --user` layout; a test keeps them equal.
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from daemon.paths import SERVICE_UNIT, user_unit_dir

UNIT_NAME = SERVICE_UNIT
DOCS_URL = "https://github.com/patchpoison/ppd/blob/main/docs/DAEMON.md"



def unit_template() -> str:
    """The unit with {placeholders}, shipped as package data (daemon/ppd.service.in): the same
    text from a checkout and from an installed wheel."""
    from importlib.resources import files

    return files("daemon").joinpath("ppd.service.in").read_text(encoding="utf-8")


@dataclass(frozen=True)
class UnitLayout:
    """What varies between installations. Strings are already in systemd syntax."""

    exec_start: Sequence[str]  # argv of `ppd watch`
    read_write: Sequence[str]  # outbox, data, cache (and publish folders, '-'-prefixed: optional)
    environment: Mapping[str, str] = field(default_factory=dict)
    docs: str = DOCS_URL


def quote_word(word: str) -> str:
    """A word for an ExecStart=/ReadWritePaths= line: quoted when it has spaces or quotes;
    '%' doubled (systemd specifier escape) unless it is one of our own specifiers (%h)."""
    if "%" in word and not word.removeprefix("-").startswith("%h"):  # '-': ReadWritePaths' "if it exists"
        word = word.replace("%", "%%")
    if any(c in word for c in " \t\"'\\"):
        return '"' + word.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return word


def render_unit(layout: UnitLayout) -> str:
    env_lines = "".join(
        f"Environment={quote_word(f'{key}={value}')}\n" for key, value in sorted(layout.environment.items())
    )
    return unit_template().format(
        exec_start=" ".join(quote_word(w) for w in layout.exec_start),
        environment=env_lines,
        read_write=" ".join(quote_word(p) for p in layout.read_write),
        docs=layout.docs,
    )


def generic_layout() -> UnitLayout:
    """The repository's systemd/ppd.service: `pip install --user` paths, default folders."""
    return UnitLayout(
        exec_start=("%h/.local/bin/ppd", "watch"),
        read_write=("%h/PPD Outbox", "%h/.local/share/ppd", "%h/.cache/ppd", "-%h/ppd-quarantine"),
        docs=DOCS_URL,
    )


def ppd_executable() -> Path:
    """The `ppd` console script of the running installation (the venv's bin first)."""
    beside = Path(sys.executable).parent / "ppd"
    if beside.is_file() and os.access(beside, os.X_OK):
        return beside.absolute()
    found = shutil.which("ppd")
    if found is None:
        raise FileNotFoundError(
            "cannot find the `ppd` command (install ppd with pip, e.g. `pip install -e .`, first)"
        )
    return Path(found).absolute()


def watch_command(executable: Path | None = None) -> tuple[list[str], dict[str, str]]:
    """argv (and extra environment) that runs `ppd watch` for this installation: the `ppd`
    console script when installed, else this Python with this copy of ppd importable."""
    try:
        exe = executable or ppd_executable()
    except FileNotFoundError:
        from verifier.childenv import child_env

        python = str(Path(sys.executable).absolute())
        extra = {k: v for k, v in child_env({}).items() if k == "PYTHONPATH"}
        return [python, "-m", "daemon.cli", "watch"], extra
    return [str(exe), "watch"], {}


def installed_layout(
    paths: object, config: object | None = None, executable: Path | None = None
) -> UnitLayout:
    """The unit for this installation: absolute paths of its `ppd` and folders.

    The PPD_* folders go into Environment= so the service uses the folders `install` saw,
    even when they came from the environment of the shell that ran it.
    """
    argv, extra_env = watch_command(executable)
    outbox, data, cache, conf = (
        Path(getattr(paths, n)).absolute() for n in ("outbox", "data_dir", "cache_dir", "config_dir")
    )
    read_write = [str(outbox), str(data), str(cache)]
    # where the daemon moves what it cannot patch (ProtectSystem=strict: else read-only, and a broken
    # file stayed in the outbox; `ppd service install` makes the folder, so it is there at start)
    read_write.append("-" + str(quarantine_folder(outbox, config)))
    for publish in _publish_dirs(config, Path(getattr(paths, "db_path", data / "ppd.sqlite3"))):
        read_write.append("-" + str(publish))  # '-': a missing folder does not stop the unit
    return UnitLayout(
        exec_start=argv,
        read_write=read_write,
        environment={
            "PPD_OUTBOX": str(outbox),
            "PPD_DATA_DIR": str(data),
            "PPD_CACHE_DIR": str(cache),
            "PPD_CONFIG_DIR": str(conf),
            "PYTHONUNBUFFERED": "1",
            **extra_env,
        },
        docs=DOCS_URL,  # the docs are not installed with the wheel: the published page
    )


def quarantine_folder(outbox: Path, config: object | None) -> Path:
    """The daemon's quarantine folder for this outbox: the config's, else beside the outbox."""
    where = getattr(config, "quarantine_dir_for", None)
    if where is None:
        return outbox.absolute().parent / "ppd-quarantine"
    return Path(where(outbox)).absolute()


def temporary_folders(layout: UnitLayout) -> list[str]:
    """The unit's paths under /tmp or /var/tmp, its program's first (a ppd installed in a venv under
    /tmp was not warned of: a fifth black-box review), then its writable folders: PrivateTmp=yes gives
    the service a /tmp of its own, where such a path does not exist. The config folder too (only in
    Environment=: the service ran on defaults, its config unseen, unwarned; a seventh review)."""
    paths = [*layout.exec_start[:2], *(p.lstrip("-") for p in layout.read_write)]
    paths += [p for p in (layout.environment.get("PPD_CONFIG_DIR"),) if p is not None and p not in paths]
    return [p for p in paths if p.startswith("/") and (Path(p).is_relative_to("/tmp") or
                                                        Path(p).is_relative_to("/var/tmp"))]  # fmt: skip


def _publish_dirs(config: object | None, store: Path) -> list[Path]:
    """The config's publish folders and every dataset's own, kept in the store (`ppd dataset set NAME
    --publish-dir`: not listed, the sandbox made it read-only, a black-box review), each once; the
    store read read-only (`--print` makes nothing)."""
    from daemon.protect.rebuild import stored_datasets

    dirs = [getattr(config, "publish_dir", None)] if config is not None else []
    dirs += [getattr(o, "publish_dir", None) for o in getattr(config, "datasets", {}).values()]
    dirs += [row.get("publish_dir") for row in stored_datasets(store).values()]
    found = list(dict.fromkeys(Path(d).expanduser().absolute() for d in dirs if d))
    # one inside another listed folder (the config's publish_dir/NAME, kept with the dataset) is writable
    return [d for d in found if not any(d != f and d.is_relative_to(f) for f in found)]


def unit_lacks(folder: Path, unit: Path | None = None) -> bool:
    """Whether ppd.service is installed and does not list folder among its writable ones (ReadWritePaths=):
    the service cannot write there until `ppd service install` is run again."""
    unit = unit or unit_dir() / UNIT_NAME
    try:
        text = unit.read_text(encoding="utf-8")
    except OSError:  # not installed (or unreadable): nothing to say
        return False
    folder = Path(folder).expanduser().absolute()
    for line in text.splitlines():
        if line.startswith("ReadWritePaths="):
            words = shlex.split(line.split("=", 1)[1])
            listed = [Path(w.lstrip("-").replace("%%", "%")) for w in words]
            if any(folder.is_relative_to(p) for p in listed):
                return False
    return True


def unit_dir(env: Mapping[str, str] | None = None) -> Path:
    return user_unit_dir(env)


@dataclass(frozen=True)
class SystemctlResult:
    ran: bool  # False: no systemctl, or no user bus/manager to talk to
    returncode: int
    output: str


def systemctl_user(*args: str, timeout: float = 20.0) -> SystemctlResult:
    """`systemctl --user ARGS`, tolerating a machine without a user manager (containers, ssh
    sessions without lingering): the unit file is still written; the caller says what to run."""
    exe = shutil.which("systemctl")
    if exe is None:
        return SystemctlResult(False, 127, "systemctl not found")
    try:
        proc = subprocess.run([exe, "--user", *args], capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return SystemctlResult(False, 1, str(exc))
    output = (proc.stdout + proc.stderr).strip()
    no_manager = any(
        s in output for s in ("Failed to connect to bus", "No medium found", "$DBUS_SESSION_BUS_ADDRESS")
    )
    return SystemctlResult(not no_manager, proc.returncode, output)


def install_unit(text: str, env: Mapping[str, str] | None = None) -> Path:
    """Write the unit atomically into the user unit folder; returns its path."""
    from poisoner.atomic import atomic_write_bytes

    folder = unit_dir(env)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / UNIT_NAME
    atomic_write_bytes(target, text.encode())
    return target


def restart_reminder(env: Mapping[str, str] | None = None) -> str | None:
    """After a command that needs `ppd watch` stopped (store rebuild, key new/import): where the service
    is installed, a line to start it again; a creator who stopped it as told and forgot left the outbox
    unprotected (a black-box review). None without the unit."""
    if not (unit_dir(env) / UNIT_NAME).is_file():
        return None
    return "if you stopped the ppd service for this, start it again: `systemctl --user start ppd`"


def uninstall_unit(env: Mapping[str, str] | None = None) -> Path | None:
    """Remove the unit file; returns its path, or None when it was not installed."""
    target = unit_dir(env) / UNIT_NAME
    try:
        target.unlink()
    except FileNotFoundError:
        return None
    return target
