"""The seal key changed under a running ppd (a diff review, F4: `ppd key new` or `ppd key import --force`
while `ppd watch` ran; the daemon went on sealing with the key it had loaded, one no longer on disk, so
after a store loss its files were not recognised, patched again and their patched bytes vaulted as
originals). Now both are refused while any ppd process uses the data folder, and a process whose key
file was replaced anyway seals nothing more. Real processes, real files, a real store."""

from __future__ import annotations

import os
import secrets
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.context import AppContext
from daemon.paths import AppPaths
from daemon.protect.one_file import protect_file
from daemon.store.sealkey import SealKeyError, install_key, key_path
from poisoner.provenance import KEY_BYTES
from testkit.daemon_proc import start_daemon, stop_daemon
from testkit.photos import make_shoot
from testkit.reliability import REPO


def _ppd(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", *args], cwd=REPO, capture_output=True, text=True, check=False,
        env={**os.environ, **(env or {}), "PYTHONPATH": str(REPO), "COLUMNS": "200"},
    )  # fmt: skip


def _error_line(result: subprocess.CompletedProcess[str]) -> str:
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("ppd: error: "), result.stdout + result.stderr
    return lines[0]


def _other_key(where: Path) -> Path:
    where.write_text(secrets.token_bytes(KEY_BYTES).hex() + "\n")
    where.chmod(0o600)
    return where


def test_key_new_and_key_import_are_refused_while_ppd_watch_runs(tmp_path: Path) -> None:
    root = tmp_path / "root"
    for name in ("data", "config", "outbox", "cache"):
        (root / name).mkdir(parents=True)
    env = {"PPD_DATA_DIR": str(root / "data"), "PPD_CONFIG_DIR": str(root / "config"),
           "PPD_OUTBOX": str(root / "outbox"), "PPD_CACHE_DIR": str(root / "cache")}  # fmt: skip
    other = _other_key(tmp_path / "other.key")
    daemon = start_daemon(root, "--no-verify")  # loads (makes) the key and seals with it
    try:
        key = key_path(root / "data")
        loaded = key.read_bytes()
        imported = _ppd("key", "import", str(other), "--force", env=env)
        assert imported.returncode == 3  # before: 0, and the daemon sealed on with the old key
        line = _error_line(imported)
        assert f"ppd watch (pid {daemon.pid}) is running" in line and f"`kill {daemon.pid}`" in line
        assert line.endswith("then import the key")
        key.unlink()  # the user "lost" it
        made = _ppd("key", "new", env=env)
        assert made.returncode == 3 and "then make the new key" in _error_line(made)
        assert not key.exists()
        key.write_bytes(loaded)
        key.chmod(0o600)
    finally:
        stop_daemon(daemon)
    assert _ppd("key", "import", str(other), "--force", env=env).returncode == 0  # the daemon gone
    assert key.read_bytes() == other.read_bytes()


def test_key_import_is_refused_while_a_command_uses_the_data_folder(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    ctx = AppContext.open()  # a long `ppd poison`, say
    try:
        loaded = ctx.seal_key()
        imported = _ppd("key", "import", str(_other_key(tmp_path / "other.key")), "--force")
        assert imported.returncode == 3  # before: 0
        said = _error_line(imported)  # which command holds the store: this test's process
        assert f"another ppd command is running (pid {os.getpid()}: " in said, said
        assert said.endswith("let it finish, then import the key"), said
        assert ctx.seal_key() == loaded
    finally:
        ctx.close()


def test_a_process_whose_key_file_was_replaced_seals_nothing_more(ppd_env: dict[str, Path]) -> None:
    """By hand, or by a ppd from before the refusal: the running process stops sealing, each file fails
    with one line, untouched; a pool worker started since does not take up the new key either."""
    shoot = ppd_env["outbox"] / "shoot"
    make_shoot(shoot, 2)
    ctx = AppContext.open()
    try:
        assert protect_file(shoot / "v0.png", ctx).state == "patched"
        data_dir = AppPaths.from_env().data_dir
        st = key_path(data_dir).stat()
        install_key(data_dir, secrets.token_bytes(KEY_BYTES), replace=True)
        before = (shoot / "v1.png").read_bytes()
        outcome = protect_file(shoot / "v1.png", ctx)
        assert outcome.state == "failed", outcome  # before: patched, sealed with the key no longer on disk
        assert "was replaced or removed while this ppd ran" in (outcome.reason or "")
        assert (shoot / "v1.png").read_bytes() == before
        stamp = (st.st_dev, st.st_ino, st.st_mtime_ns)  # its caller's key (daemon.protect.pool)
        worker = AppContext(ctx.paths, ctx.config, ctx.store, ctx.vault, key_stamp=stamp)
        with pytest.raises(SealKeyError, match="was replaced or removed"):
            worker.seal_key()
    finally:
        ctx.close()
