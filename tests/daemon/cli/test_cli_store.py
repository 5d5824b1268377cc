"""`ppd store check` / `ppd store rebuild` through the real command line (typer), on real stores."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from daemon.cli.store_cmd import register
from daemon.paths import AppPaths
from daemon.states import FileState
from daemon.store import Store
from daemon.store.vault import Vault
from poisoner.atomic import atomic_output
from poisoner.spec import PatchSpec
from testkit.reliability import sealed_patch, write_image

ROOT = Path(__file__).resolve().parents[3]
CLI = "import typer; from daemon.cli.store_cmd import register; app = typer.Typer(); register(app); app()"


@pytest.fixture
def app() -> typer.Typer:
    app = typer.Typer()
    register(app)

    @app.callback()
    def _root() -> None:  # a group, as in daemon/cli.py, so `store` is a sub-command
        pass

    return app


def _patched_outbox(paths: AppPaths, count: int = 3) -> dict[Path, bytes]:
    """Files patched as the core pipeline does (vault, spec, marker, row)."""
    paths.ensure()
    vault, store, spec = Vault(paths.vault_dir), Store(paths.db_path), PatchSpec()
    originals = {}
    for i in range(count):
        path = write_image(paths.outbox / "shoot" / f"{i}.png", seed=i, size=96)
        data = path.read_bytes()
        sha = vault.keep(path)
        vault.keep_spec(spec)
        store.ensure_dataset("shoot", paths.outbox / "shoot", spec)
        with atomic_output(path) as tmp:
            sealed_patch(path, tmp, spec, sha, paths.data_dir)
        store.record_file(
            path, "shoot", FileState.PATCHED, original_sha256=sha, spec_id=spec.spec_id,
            poisoned_sha256=hashlib.sha256(path.read_bytes()).hexdigest(),
        )  # fmt: skip
        originals[path] = data
    store.close()
    return originals


def _one_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    assert "Traceback" not in text
    return lines[0]


def test_check_then_rebuild_a_deleted_store(app: typer.Typer, ppd_env: dict[str, Path]) -> None:
    paths = AppPaths.from_env()
    originals = _patched_outbox(paths)
    runner = CliRunner()
    sound = runner.invoke(app, ["store", "check"])
    assert sound.exit_code == 0 and "sound" in _one_line(sound.stdout) and "3 file row(s)" in sound.stdout
    for suffix in ("", "-wal", "-shm"):
        Path(f"{paths.db_path}{suffix}").unlink(missing_ok=True)

    missing = runner.invoke(app, ["store", "check"])
    assert missing.exit_code == 3 and "`ppd store rebuild`" in _one_line(missing.stderr)
    assert missing.stderr.startswith("ppd: error: ")  # as every other command says it (was `error:`, 1)
    assert not paths.db_path.exists()  # checking creates nothing

    rebuilt = runner.invoke(app, ["store", "rebuild"])
    assert rebuilt.exit_code == 0, rebuilt.stderr
    assert "3 patched file(s) in 1 dataset(s)" in _one_line(rebuilt.stdout)
    store = Store(paths.db_path)
    vault = Vault(paths.vault_dir)
    for path, data in originals.items():
        row = store.file(path)
        assert row["state"] == FileState.PATCHED
        assert vault.path_for(row["original_sha256"]).read_bytes() == data
    store.close()
    again = runner.invoke(app, ["store", "rebuild"])  # now sound: refused, one line
    assert again.exit_code == 2 and "--force" in _one_line(again.stderr)  # bad input: the option missing
    assert again.stderr.startswith("ppd: error: ")
    verbose = runner.invoke(app, ["store", "rebuild", "--force", "-v"])
    assert verbose.exit_code == 0 and "rebuilt datasets" in verbose.stdout and "vault" in verbose.stdout


def test_a_garbage_store_is_one_line_in_a_real_process(ppd_env: dict[str, Path]) -> None:
    paths = AppPaths.from_env()
    _patched_outbox(paths, count=1)
    for suffix in ("-wal", "-shm"):
        Path(f"{paths.db_path}{suffix}").unlink(missing_ok=True)
    paths.db_path.write_bytes(os.urandom(10_000))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "80"}

    def ppd(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-c", CLI, *args], env=env, cwd=ROOT, capture_output=True, text=True, timeout=120
        )

    check = ppd("store", "check")
    assert check.returncode == 3  # `ppd --help`: 3 = damaged store, as every other command exits
    line = _one_line(check.stderr)
    assert str(paths.db_path) in line and "is damaged" in line and "`ppd store rebuild`" in line
    rebuild = ppd("store", "rebuild")
    assert rebuild.returncode == 0, rebuild.stderr
    assert (
        "1 patched file(s)" in _one_line(rebuild.stdout) and "the damaged store is kept at" in rebuild.stdout
    )
    assert ppd("store", "check").returncode == 0


def test_rebuild_keeps_a_dataset_patched_inside_another(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd poison album/zoo --dataset zoo`, then `ppd poison album`: two datasets, one inside the
    other's folder. The rebuild walked the old roots by name, so album (first) took zoo's files: zoo
    was left with none and `ppd restore zoo` said "restored 0" while its photos stayed patched."""
    from daemon.cli import app as ppd

    album = tmp_path / "shoots" / "album"
    for i in range(2):
        write_image(album / f"a{i}.png", seed=i, size=96)
    originals = {i: write_image(album / "zoo" / f"z{i}.png", seed=10 + i, size=96).read_bytes()
                 for i in range(3)}  # fmt: skip
    runner = CliRunner()
    assert runner.invoke(ppd, ["poison", str(album / "zoo"), "--dataset", "zoo"]).exit_code == 0
    assert runner.invoke(ppd, ["poison", str(album)]).exit_code == 0
    rebuilt = runner.invoke(ppd, ["store", "rebuild", "--force"])
    assert rebuilt.exit_code == 0, rebuilt.output
    store = Store(AppPaths.from_env().db_path)
    assert {r["path"].split("/")[-1] for r in store.files("zoo")} == {"z0.png", "z1.png", "z2.png"}
    assert len(store.files("album")) == 2
    store.close()
    restored = runner.invoke(ppd, ["restore", "zoo"])
    assert restored.exit_code == 0 and "restored 3" in restored.output, restored.output
    assert all((album / "zoo" / f"z{i}.png").read_bytes() == data for i, data in originals.items())


def test_check_says_when_the_vault_lost_originals(app: typer.Typer, ppd_env: dict[str, Path]) -> None:
    """A black-box review: `ppd store check` said "sound" with a patched file's original gone from
    the vault, which only a restore then found out."""
    paths = AppPaths.from_env()
    originals = _patched_outbox(paths)
    runner = CliRunner()
    assert runner.invoke(app, ["store", "check"]).exit_code == 0
    first = sorted(originals)[0]
    sha = Store(paths.db_path).file(first)["original_sha256"]
    Vault(paths.vault_dir).path_for(sha).unlink()
    lost = runner.invoke(app, ["store", "check"])
    assert lost.exit_code == 3, lost.stdout
    assert "1 patched file(s) have no original in the vault" in _one_line(lost.stderr), lost.stderr


def test_a_rebuild_that_recovers_nothing_fails(app: typer.Typer, ppd_env: dict[str, Path]) -> None:
    """A black-box review: the seal key and the store both lost, `ppd store rebuild` recorded 0 of the
    vault's originals and exited 0, naming only folders to walk. It exits 1 and names the key too."""
    paths = AppPaths.from_env()
    _patched_outbox(paths)
    for lost in (paths.data_dir / "seal.key", paths.db_path):
        lost.unlink()
    rebuilt = CliRunner().invoke(app, ["store", "rebuild"])
    assert rebuilt.exit_code == 1, rebuilt.stdout
    line = _one_line(rebuilt.stdout)
    assert "0 patched file(s)" in line and "3 vault original(s) no file names" in line
    assert "`ppd key import`" in line


def test_a_lost_store_is_said_once_per_command_and_checked_as_damaged(ppd_env: dict[str, Path]) -> None:
    """A black-box review: after a store loss every command printed the 'store is new but the vault
    holds originals' warning twice, and `ppd store check` said `error: ...` with exit 1 where every
    other command says `ppd: error: ...` with exit 3 (the store cannot be worked with)."""
    paths = AppPaths.from_env()
    _patched_outbox(paths, count=1)
    for suffix in ("", "-wal", "-shm"):
        Path(f"{paths.db_path}{suffix}").unlink(missing_ok=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "80"}

    def ppd(*args: str) -> subprocess.CompletedProcess[str]:
        command = [sys.executable, "-m", "daemon.cli", *args]
        return subprocess.run(command, env=env, cwd=ROOT, capture_output=True, text=True, timeout=120)

    status = ppd("status")
    assert status.returncode == 0, status.stderr
    assert status.stderr.count("already holds originals") == 1, status.stderr
    check = ppd("store", "check")
    assert check.returncode == 3 and check.stderr.count("already holds originals") == 1, check.stderr
    assert _one_line(check.stderr).startswith("ppd: error: the store ")
