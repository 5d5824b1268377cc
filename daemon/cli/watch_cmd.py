"""`ppd watch [OUTBOX]` (the daemon, in the foreground: systemd runs exactly this) and
`ppd service install|uninstall|status` (its systemd user unit)."""

from __future__ import annotations

import dataclasses
import logging
import os
import signal
import sys
import time
from pathlib import Path
from types import FrameType

import typer

from daemon.cli.errors import die
from daemon.cli.interrupt import SAME_STOP_S
from daemon.cli.output import err_console
from poisoner.errors import ExitStatus

log = logging.getLogger(__name__)

service_app = typer.Typer(help="The systemd user service that runs `ppd watch`.", no_args_is_help=True)


def _fail(message: str, code: int = 1) -> typer.Exit:  # 1: systemd and tests read it so
    return die(message, code)


def _open_context(outbox: Path | None, seal_key: bool = False, daemon: bool = False):  # -> AppContext
    from daemon.config import ConfigError
    from daemon.context import AppContext
    from daemon.locks import LockHeld
    from daemon.paths import AppPaths
    from daemon.store import StoreError
    from daemon.store.sealkey import SealKeyError

    paths = AppPaths.from_env()
    if outbox is not None:
        paths = dataclasses.replace(paths, outbox=outbox.expanduser().absolute())
        if not paths.outbox.exists() and not paths.outbox.is_symlink():  # a typo is not a new outbox
            raise _fail(f"{paths.outbox} does not exist: make it first, or check its name", ExitStatus.USAGE)
    if paths.outbox.exists() and not paths.outbox.is_dir():  # bad input, before anything is made
        raise _fail(f"{paths.outbox} is a file, not a folder: give the folder to watch", ExitStatus.USAGE)
    try:
        ctx = _open_when_store_free(paths) if daemon else AppContext.open(paths)
    except (ConfigError, StoreError, LockHeld) as exc:  # 2 and 3, as every command: the unit does not
        # restart on them
        raise _fail(str(exc).splitlines()[0], exc.exit_status) from None
    except OSError as exc:
        raise _fail(f"cannot set up ppd's folders: {exc.strerror}: {exc.filename}") from None
    if seal_key:  # made now while the vault is empty; a lost one stops the daemon before it patches
        try:
            ctx.seal_key()
        except SealKeyError as exc:
            ctx.close()
            raise _fail(str(exc), ExitStatus.ENVIRONMENT) from None
    return ctx


STORE_BUSY_POLL_S = 1.0
STORE_BUSY_EXTEND_S = 60  # systemd's start timeout pushed on by this much at each poll


def _open_when_store_free(paths):  # -> daemon.context.AppContext
    """AppContext.open, after waiting out a `ppd store rebuild` or `ppd key new|import`: the daemon's
    job is to be running. It exited 3 instead, which the unit does not restart (RestartPreventExitStatus),
    so a login or a restart during a rebuild left the outbox unwatched until the user noticed (a
    black-box review). Said once; systemd's start timeout is extended while it waits, its status says why."""
    from daemon.context import AppContext
    from daemon.locks import StoreBusy
    from daemon.watch.notify import SystemdNotifier

    notifier: SystemdNotifier | None = None
    while True:
        try:
            return AppContext.open(paths)
        except StoreBusy as exc:
            if notifier is None:
                notifier = SystemdNotifier()
                log.warning("waiting to start: %s", exc.busy, extra={"busy": exc.busy})
            notifier.send(
                f"STATUS=waiting to start: {exc.busy}", f"EXTEND_TIMEOUT_USEC={STORE_BUSY_EXTEND_S * 10**6}"
            )
            time.sleep(STORE_BUSY_POLL_S)


def watch(
    outbox: Path | None = typer.Argument(None, help="Folder to watch (default: $PPD_OUTBOX)."),
    workers: int | None = typer.Option(None, "--workers", "-j", min=1, help="Files protected at once."),
    debounce: float | None = typer.Option(
        None, "--debounce", min=0.0, help="Quiet seconds after a file is closed; config: debounce_seconds."
    ),
    verify: bool | None = typer.Option(
        None, "--verify/--no-verify", help="Schedule SfM verification (config: verification.enabled)."
    ),
    incomplete_wait: float | None = typer.Option(
        None,
        "--incomplete-wait",
        min=0.0,
        help="Seconds an incomplete file must stay unchanged before it is quarantined (its writer may "
        "append more); config: [daemon] incomplete_wait_seconds.",
    ),
) -> None:
    """Watch the outbox and protect every photo or video that lands in it (foreground)."""
    from daemon.datasets.subject_masks import SubjectMaskError, check_config_masks
    from daemon.watch.watcher import DaemonOptions, WatchDaemon

    ctx = _open_context(outbox, seal_key=True, daemon=True)
    try:
        missing = check_config_masks(ctx.config, ctx.paths.outbox)  # one in the outbox would be published
    except SubjectMaskError as exc:
        ctx.close()
        raise _fail(str(exc)) from None
    for line in missing:  # one dataset's state: its files wait, the daemon runs (systemd never restarts 2)
        log.warning("%s", line)
    _warn_if_synced(ctx.paths.outbox)
    options = DaemonOptions.from_config(
        ctx.config, workers=workers, settle_s=debounce, verify=verify, incomplete_wait_s=incomplete_wait
    )
    daemon = WatchDaemon(ctx, options)
    first_signal: float | None = None
    from daemon.protect.quarantine import abandon_attempts  # imported now: the handler leaves at once

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        nonlocal first_signal
        now = time.monotonic()
        if first_signal is not None and now - first_signal < SAME_STOP_S:  # daemon.cli.interrupt
            # the same request: `timeout` and `kill -- -PGID` signal the whole group, a terminal's
            # Ctrl-C pressed twice (a black-box review: the daemon left at once, a file half-done)
            log.debug("signal %s again: already stopping", signal.Signals(signum).name)
            return
        if first_signal is not None:  # asked again later: leave now; the next start finishes the rest
            sys.stderr.write("ppd: stopping at once: files in flight are finished at the next start\n")
            abandon_attempts(ctx.paths.data_dir, os.getpid())  # a stop asked for: not "ppd died"
            os._exit(130)
        first_signal = now
        log.info("signal %s: stopping", signal.Signals(signum).name)
        daemon.request_stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        code = daemon.run()
    finally:
        ctx.close()
    raise typer.Exit(code)


def _warn_if_synced(outbox: Path) -> None:
    """The daemon, which is what would leak the originals, says so too (only `ppd status` did: a
    black-box review)."""
    from daemon.watch.syncdirs import sync_warning

    said = sync_warning(outbox)
    if said is not None:
        err_console().print(f"warning: {said}", highlight=False, markup=False)


def _unit_place() -> str:
    """Where the unit goes, as the user's environment says it ($XDG_CONFIG_HOME when set)."""
    xdg = os.environ.get("XDG_CONFIG_HOME")
    return f"$XDG_CONFIG_HOME/systemd/user ({xdg}/systemd/user)" if xdg else "~/.config/systemd/user"


def service_install(
    start: bool = typer.Option(True, "--start/--no-start", help="Enable and start it now."),
    print_only: bool = typer.Option(
        False, "--print", help="Print the unit on stdout; write nothing, start nothing."
    ),
) -> None:
    from daemon.config import Config, ConfigError
    from daemon.paths import AppPaths
    from daemon.watch import service

    if print_only:  # the folders and config as they stand: nothing made (a black-box review: the
        paths = AppPaths.from_env()  # outbox, vault and store were made by "write nothing")
        try:
            config = Config.load(paths)
        except ConfigError as exc:
            raise _fail(str(exc).splitlines()[0]) from None
    else:  # the unit's folders must exist when it starts (ReadWritePaths=): made, as the daemon makes them
        ctx = _open_context(None)
        paths, config = ctx.paths, ctx.config
        ctx.close()
    try:
        layout = service.installed_layout(paths, config)
        quarantine = service.quarantine_folder(paths.outbox, config)
    except FileNotFoundError as exc:
        raise _fail(str(exc)) from None
    _warn_if_synced(paths.outbox)
    for folder in service.temporary_folders(layout):
        err_console().print(
            f"warning: {folder} is under a temporary folder, which the service cannot see (PrivateTmp): "
            "install ppd, and set PPD_OUTBOX, PPD_DATA_DIR, PPD_CACHE_DIR and PPD_CONFIG_DIR, elsewhere "
            "before installing",
            highlight=False, markup=False,
        )  # fmt: skip
    if print_only:
        sys.stdout.write(service.render_unit(layout))
        return
    quarantine.mkdir(mode=0o700, parents=True, exist_ok=True)  # the sandbox cannot make it later
    target = service.install_unit(service.render_unit(layout))
    err_console().print(f"wrote {target}", highlight=False)
    reload = service.systemctl_user("daemon-reload")
    if not reload.ran:
        err_console().print(
            "no systemd user manager reachable here; once logged in with one, run:\n"
            "  systemctl --user daemon-reload && systemctl --user enable --now ppd",
            highlight=False,
        )
        return
    if start:
        enabled = service.systemctl_user("enable", "--now", service.UNIT_NAME)
        err_console().print(enabled.output or f"enabled and started {service.UNIT_NAME}", highlight=False)
        if enabled.returncode != 0:
            raise typer.Exit(1)


@service_app.command("uninstall")
def service_uninstall() -> None:
    """Stop and disable the service, remove its unit file, reload systemd."""
    from daemon.watch import service

    stopped = service.systemctl_user("disable", "--now", service.UNIT_NAME)
    removed = service.uninstall_unit()
    err_console().print(f"removed {removed}" if removed else "ppd.service was not installed", highlight=False)
    if stopped.ran:
        service.systemctl_user("daemon-reload")


@service_app.command("status")
def service_status() -> None:
    """Where the unit file is, and what systemd says about the service."""
    from daemon.watch import service

    target = service.unit_dir() / service.UNIT_NAME
    state = "installed" if target.is_file() else "not installed"
    err_console().print(f"unit file: {target} ({state})", highlight=False)
    result = service.systemctl_user("status", "--no-pager", "--lines=5", service.UNIT_NAME)
    if not result.ran:
        reason = (result.output.splitlines() or ["unknown reason"])[0]
        err_console().print(f"systemd user manager: not reachable ({reason})", highlight=False)
        raise typer.Exit(0 if target.is_file() else 3)
    sys.stdout.write(result.output + "\n")
    raise typer.Exit(result.returncode)


def register(app: typer.Typer) -> None:
    service_app.command(
        "install",
        help=f"Write ppd.service for this installation into {_unit_place()} and reload systemd.\n\n"
        "\b\nExamples:\n  ppd service install\n  ppd service install --print   show the unit only",
    )(service_install)
    app.command("watch")(watch)
    app.add_typer(service_app, name="service")
