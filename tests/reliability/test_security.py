"""Security: the vault and the store are readable by their owner only (checked by really trying
as another user, which works when the tests run as root), the daemon never follows a symlink
out of the outbox, and it opens no network socket."""

from __future__ import annotations

import os
import signal
import socket
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from daemon.protect.one_file import AppContext, protect_file
from daemon.states import FileState
from daemon.store import Store
from testkit.reliability import (
    DAEMON_ARGS,
    app_paths,
    kill_daemon,
    sha256,
    start_daemon,
    wait_all_protected,
    write_image,
)

NOBODY = 65534


@pytest.fixture
def open_root() -> Iterator[Path]:
    """A folder every user may traverse (pytest's own tmp folder is 0700 root, which would make
    any access by another user fail for the wrong reason)."""
    folder = Path(tempfile.mkdtemp(prefix="ppd-security-"))
    folder.chmod(0o755)
    try:
        yield folder
    finally:
        import shutil

        shutil.rmtree(folder, ignore_errors=True)


def readable_by(uid: int, paths: list[Path]) -> dict[str, bool]:
    """For each path, whether user uid can open it for reading (a forked child drops to uid)."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: drop privileges for good, then try
        os.close(read_end)
        try:
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            answers = []
            for path in paths:
                try:
                    if path.is_dir():
                        os.listdir(path)
                    else:
                        with open(path, "rb") as fh:
                            fh.read(1)
                    answers.append("1")
                except OSError:
                    answers.append("0")
            os.write(write_end, "".join(answers).encode())
        finally:
            os._exit(0)
    os.close(write_end)
    with os.fdopen(read_end, "rb") as fh:
        answers = fh.read().decode()
    os.waitpid(pid, 0)
    return {str(p): a == "1" for p, a in zip(paths, answers, strict=True)}


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to try the files as another user")
def test_vault_and_store_are_unreadable_by_other_users(
    open_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for name, var in (("data", "PPD_DATA_DIR"), ("config", "PPD_CONFIG_DIR"), ("outbox", "PPD_OUTBOX")):
        monkeypatch.setenv(var, str(open_root / name))
    old_umask = os.umask(0o022)  # a typical desktop umask: new files 0644
    try:
        ctx = AppContext.open()
        photo = write_image(ctx.paths.outbox / "shoot" / "a.png", seed=1)
        outcome = protect_file(photo, ctx)
        ctx.close()
    finally:
        os.umask(old_umask)
    assert outcome.state == "patched"
    paths = ctx.paths
    blob = paths.vault_dir / outcome.original_sha256[:2] / outcome.original_sha256
    store_files = [p for p in paths.data_dir.iterdir() if p.name.startswith(paths.db_path.name)]
    control = open_root / "control.txt"
    control.write_text("anyone may read this")
    control.chmod(0o644)
    targets = [control, photo, paths.data_dir, paths.vault_dir, blob, *store_files]
    answers = readable_by(NOBODY, targets)
    assert answers[str(control)] and answers[str(photo)], "the check cannot see access at all"
    assert not any(answers[str(p)] for p in targets[2:]), answers
    for private in (paths.data_dir, paths.vault_dir, blob.parent):
        assert stat.S_IMODE(private.stat().st_mode) & 0o077 == 0, private


def test_store_file_modes_are_owner_only(ppd_env: dict[str, Path]) -> None:
    """The mode bits themselves (meaningful as any user): no group/other bits on the store, nor on
    the -wal/-shm files SQLite keeps beside it while it is open (they hold its newest rows), and
    the store keeps its mode once closed (the last close removes the -wal/-shm files)."""
    db = ppd_env["data"] / "ppd.sqlite3"
    old_umask = os.umask(0o022)
    try:
        store = Store(db)
        store.conn.execute("SELECT 1")
    finally:
        os.umask(old_umask)
    try:
        for path in (db, Path(f"{db}-wal"), Path(f"{db}-shm")):
            assert path.exists(), f"{path} should exist while the store is open in WAL mode"
            assert stat.S_IMODE(path.stat().st_mode) & 0o077 == 0, (path, oct(path.stat().st_mode))
    finally:
        store.close()
    assert stat.S_IMODE(db.stat().st_mode) & 0o077 == 0, oct(db.stat().st_mode)


def test_daemon_never_follows_a_symlink_out_of_the_outbox(tmp_path: Path) -> None:
    paths = app_paths(tmp_path)
    outside = tmp_path / "elsewhere"
    album = outside / "album"
    secret = write_image(outside / "secret.png", seed=1)
    early = write_image(album / "early.png", seed=2)
    shoot = paths.outbox / "shoot"
    shoot.mkdir(parents=True)
    (shoot / "link.png").symlink_to(secret)  # present at start: the catch-up scan sees it
    (paths.outbox / "linked-album").symlink_to(album, target_is_directory=True)
    before = {p: sha256(p) for p in (secret, early)}
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)
    try:
        late = write_image(album / "late.png", seed=3)  # appears behind the folder link
        before[late] = sha256(late)
        (shoot / "late-link.png").symlink_to(late)  # a link arriving live
        canary = write_image(shoot / "canary.png", seed=4)  # an ordinary file, to know it ran
        wait_all_protected(paths, [canary], 30)
        swapped = shoot / "swap.png"
        write_image(tmp_path / "swap-src.png", seed=5)
        os.symlink(secret, tmp_path / "swap-link")
        os.replace(tmp_path / "swap-link", swapped)  # a symlink renamed into place
        canary2 = write_image(shoot / "canary2.png", seed=6)
        wait_all_protected(paths, [canary2], 30)
    finally:
        kill_daemon(daemon, signal.SIGTERM)
    for path, digest in before.items():
        assert sha256(path) == digest, f"{path.name} outside the outbox was changed"
    vault_blobs = {p.name for p in paths.vault_dir.glob("??/*")}
    assert len(vault_blobs) == 2  # the two canaries: the method sees what ppd keeps
    assert not vault_blobs & set(before.values()), "an outside file was kept as if it were ours"
    store = Store(paths.db_path)
    rows = {r["path"]: r for ds in store.datasets() for r in store.files(ds["name"])}
    store.close()
    assert all(r["state"] != FileState.PATCHED for p, r in rows.items() if "link" in p or "swap" in p)
    assert not any("linked-album" in p for p in rows), "a file behind a folder link was processed"


def _socket_inodes(pid: int) -> set[str]:
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:[") : -1])
    return inodes


def _inet_socket_inodes() -> set[str]:
    """Inodes of every TCP/UDP/raw socket, v4 and v6, listening or not."""
    inodes = set()
    for table in ("tcp", "tcp6", "udp", "udp6", "raw", "raw6", "udplite", "udplite6"):
        path = Path(f"/proc/net/{table}")
        if path.exists():
            for line in path.read_text().splitlines()[1:]:
                fields = line.split()
                if len(fields) > 9:
                    inodes.add(fields[9])
    return inodes


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net")
def test_daemon_opens_no_network_socket(tmp_path: Path) -> None:
    paths = app_paths(tmp_path)
    with socket.socket() as control:  # the method must see a listening socket where there is one
        control.bind(("127.0.0.1", 0))
        control.listen()
        assert _socket_inodes(os.getpid()) & _inet_socket_inodes()
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)
    try:
        photo = write_image(paths.outbox / "shoot" / "a.jpg", seed=1)
        wait_all_protected(paths, [photo], 30)
        sockets = _socket_inodes(daemon.pid)
        inet = _inet_socket_inodes()
    finally:
        kill_daemon(daemon, signal.SIGTERM)
    assert not sockets & inet, f"network sockets open: {sockets & inet}"
