"""`ppd store rebuild` against the commands that write the store (a diff review, F2: a `ppd restore`
committed while a rebuild walked was lost when the stores were swapped; the restored original was
recorded "patched" and `ppd poison` patched it again). Every command holds the store lock shared while
it runs, a rebuild holds it exclusive: one of the two is refused, with one line, exit 3. Real
processes, real files, a real store."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from daemon.config import Config
from daemon.locks import STORE_LOCK
from daemon.paths import AppPaths
from daemon.protect.rebuild import RebuildBlocked, rebuild_store
from daemon.states import FileState
from daemon.store import Store
from daemon.store.sealkey import load_key
from poisoner.provenance import read_seal
from testkit.photos import make_image, make_shoot
from testkit.reliability import REPO

runner = CliRunner()
ENV = {"PYTHONPATH": str(REPO), "COLUMNS": "200"}


def _ppd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", *args], cwd=REPO, capture_output=True, text=True, check=False,
        env={**os.environ, **ENV},
    )  # fmt: skip


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _error_line(stderr: str) -> str:
    errors = [line for line in stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith("ppd: error: "), stderr
    return errors[0]


def _holding_the_store() -> subprocess.Popen[str]:
    """Another ppd process with the store open, as a long `ppd poison` has (held until it ends)."""
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys; from daemon.context import AppContext\n"
         "ctx = AppContext.open(); print('open', flush=True); sys.stdin.read(); ctx.close()"],
        cwd=REPO, env={**os.environ, **ENV}, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert holder.stdout is not None and holder.stdout.readline().strip() == "open"
    return holder


def test_a_restore_while_the_store_is_rebuilt_is_refused_not_lost(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    key = load_key(paths.data_dir, create=False)
    restores: list[subprocess.CompletedProcess[str]] = []

    def read_marker(path: Path) -> object:
        seal = read_seal(path, key)
        if not restores:  # the walk has just read this file's seal: the user restores it now
            restores.append(_ppd("restore", os.readlink(path)))  # the walk reads by fd
        return seal

    report = rebuild_store(
        paths, config=Config.load(paths), folders=[shoot], force=True, read_marker=read_marker
    )
    assert report.recorded == 3
    (restore,) = restores
    assert restore.returncode == 3, restore.stdout + restore.stderr  # before: 0, and lost in the swap
    line = _error_line(restore.stderr)
    assert f"ppd store rebuild is rebuilding the store (pid {os.getpid()}); run this again" in line
    store = Store(paths.db_path)
    try:  # every row says what its file holds
        for photo in sorted(shoot.iterdir()):
            row = store.file(photo)
            assert row["state"] == FileState.PATCHED and row["poisoned_sha256"] == _sha(photo), photo
    finally:
        store.close()
    assert not (paths.data_dir / "locks" / STORE_LOCK).exists()


def test_a_rebuild_is_refused_while_a_command_has_the_store_open(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_image(shoot / "v0.png", 0)
    assert _ppd("poison", str(shoot)).returncode == 0
    lock_file = paths.data_dir / "locks" / STORE_LOCK
    assert not lock_file.exists()  # the command's lock file went with it

    first, second = _holding_the_store(), _holding_the_store()
    refused = _ppd("store", "rebuild", "--force")
    assert refused.returncode == 3, refused.stdout + refused.stderr  # before: rebuilt under them, 0
    line = _error_line(refused.stderr)
    assert "another ppd command is running (pid " in line and line.endswith("let it finish, then rebuild")
    assert f"pid {first.pid}" in line and f"pid {second.pid}" in line, line  # which ones: named
    assert not list(paths.data_dir.glob("*.before-rebuild-*"))  # nothing was swapped
    with pytest.raises(RebuildBlocked):
        rebuild_store(paths, force=True)

    first.communicate("")  # ends normally: the other still holds the lock, and its file
    assert first.returncode == 0 and lock_file.exists()
    os.kill(second.pid, signal.SIGKILL)  # a killed command leaves no lock held (nor a stale pid named)
    second.wait()
    rebuilt = _ppd("store", "rebuild", "--force")
    assert rebuilt.returncode == 0, rebuilt.stderr
    assert "1 patched file(s)" in rebuilt.stdout
    assert not lock_file.exists()
