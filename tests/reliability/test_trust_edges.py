"""Issue 29, the smaller items, each failing on the code before it: a 255-byte file name is
patched; the single-instance lock is the outbox's device and inode (a symlink to it is the same
outbox); `ppd store rebuild` refuses while a daemon holds the outbox; a lost store is reported,
never silently recreated empty; `.keep-*` vault leftovers are cleaned and counted; folders are
0700 and quarantined files 0600 whatever the umask."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.locks import LockHeld, outbox_lock
from daemon.paths import AppPaths
from daemon.protect.one_file import AppContext, protect_file
from daemon.protect.rebuild import RebuildRefused, rebuild_store
from daemon.states import FileState
from testkit.reliability import REPO, patched_then_store_lost, write_image


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_a_255_byte_name_is_patched(ppd_env: dict[str, Path], suffix: str) -> None:
    name = "n" * (255 - len(suffix)) + suffix
    photo = write_image(ppd_env["outbox"] / "ds" / name, seed=5)
    original = photo.read_bytes()
    ctx = AppContext.open()
    try:
        outcome = protect_file(photo, ctx)
        assert outcome.state == "patched", outcome.reason  # before: "File name too long"
        assert photo.read_bytes() != original and ctx.vault.has(outcome.original_sha256)
        assert ctx.store.file(photo)["state"] == FileState.PATCHED
    finally:
        ctx.close()


def _hold_outbox_lock(data: Path, outbox: Path) -> subprocess.Popen[str]:
    """Another process holding `ppd watch`'s lock on outbox (as a running daemon does)."""
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import time; from pathlib import Path; from daemon.locks import outbox_lock\n"
         f"with outbox_lock(Path({str(data)!r}), Path({str(outbox)!r})):\n"
         "    print('held', flush=True); time.sleep(60)"],
        cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    return holder


def test_the_outbox_lock_is_the_folder_not_its_spelling(tmp_path: Path) -> None:
    """Before: `ppd watch` on a symlink to the outbox ran beside the real daemon (3/3)."""
    outbox = tmp_path / "outbox"
    outbox.mkdir()
    (tmp_path / "link").symlink_to(outbox, target_is_directory=True)
    (tmp_path / "x").mkdir()
    data = tmp_path / "data"
    holder = _hold_outbox_lock(data, outbox)
    try:
        for spelling in (tmp_path / "link", tmp_path / "x" / ".." / "outbox", outbox):
            with pytest.raises(LockHeld, match=rf"pid {holder.pid}"), outbox_lock(data, spelling):
                pass
        with outbox_lock(tmp_path / "data", tmp_path / "x"):  # a folder beside it: free (one above it
            pass  # holds the outbox: refused since, tests/daemon/watch/test_nested_outboxes.py)
    finally:
        holder.kill()
        holder.wait()


def test_store_rebuild_refuses_while_a_daemon_holds_the_outbox(ppd_env: dict[str, Path]) -> None:
    """Before: `ppd store rebuild --force` ran under a live daemon (13 of 28 files then missing)."""
    paths = AppPaths.from_env()
    paths.ensure()
    holder = _hold_outbox_lock(paths.data_dir, paths.outbox)
    try:
        with pytest.raises(RebuildRefused, match=rf"ppd watch \(pid {holder.pid}\) is running"):
            rebuild_store(paths, force=True)
        assert not list(paths.data_dir.glob("*.before-rebuild-*"))  # nothing was swapped
    finally:
        holder.kill()
        holder.wait()
    assert rebuild_store(paths, force=True).before in ("missing", "empty")  # the daemon gone: it runs


def _ppd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", *args], cwd=REPO, capture_output=True, text=True, check=False,
        env={**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "200"},
    )  # fmt: skip


def test_a_lost_store_is_reported_never_recreated_silently(ppd_env: dict[str, Path]) -> None:
    """Before: after a store loss `ppd status` and `ppd restore FILE` made an empty store (`store
    check`: "sound, 0 rows") and restore refused every file before reaching the seal (36/36)."""
    photo, original = patched_then_store_lost(ppd_env["outbox"] / "ds", seed=3)
    status = _ppd("status")
    assert "the earlier store was lost" in status.stderr and "ppd store rebuild" in status.stderr
    check = _ppd("store", "check")
    assert check.returncode != 0 and "lost" in check.stderr, (check.stdout, check.stderr)
    restored = _ppd("restore", str(photo))  # no row: the file's seal and the vault
    assert restored.returncode == 0, restored.stderr
    assert photo.read_bytes() == original


def test_folders_0700_and_quarantined_files_0600_whatever_the_umask(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before, under umask 000: ppd-quarantine/ and the config folder 0777, quarantined originals 0666."""
    import stat

    from daemon.protect.quarantine import quarantine

    root = tmp_path / "home"
    for var, name in (("PPD_DATA_DIR", "a/data"), ("PPD_CONFIG_DIR", "b/config"), ("PPD_OUTBOX", "c/outbox")):
        monkeypatch.setenv(var, str(root / name))
    monkeypatch.setenv("PPD_CACHE_DIR", str(root / "d" / "cache"))
    old = os.umask(0)
    try:
        ctx = AppContext.open()
        try:
            bad = ctx.paths.outbox / "ds" / "deep" / "bad.jpg"
            bad.parent.mkdir(parents=True)
            bad.write_bytes(b"not a photo")
            os.chmod(bad, 0o666)
            moved = quarantine(ctx, bad, "ds", "not a recognised image")
        finally:
            ctx.close()
    finally:
        os.umask(old)
    assert moved is not None and moved.read_bytes() == b"not a photo"
    assert stat.S_IMODE(moved.stat().st_mode) == 0o600
    created = [root / n for n in ("a", "a/data", "b", "b/config", "d", "d/cache")]
    created += [p for p in moved.parents if p.is_relative_to(ctx.config.quarantine_dir_for(ctx.paths.outbox))]
    for folder in created:
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700, folder


def test_a_fragment_under_a_quarantined_name_is_joined_to_its_head(ppd_env: dict[str, Path]) -> None:
    """A writer's next append after its head was quarantined (the wait ran out): the tail is not
    a file of its own; it is joined to the quarantined head (one whole file), which goes back to
    its name and is patched. Before: a second fragment in quarantine, the tail kept as an original."""
    from daemon.protect.quarantine import quarantine

    src = write_image(ppd_env["outbox"].parent / "src.png", seed=8, size=256).read_bytes()
    photo = ppd_env["outbox"] / "ds" / "a.png"
    photo.parent.mkdir(parents=True)
    photo.write_bytes(src[: len(src) // 2])
    ctx = AppContext.open()
    try:
        head = protect_file(photo, ctx)
        assert head.state == "failed" and head.incomplete, head
        first = quarantine(ctx, photo, "ds", head.reason or "")
        assert first is not None and first.read_bytes() == src[: len(src) // 2]
        photo.write_bytes(src[len(src) // 2 :])  # the writer goes on: open(..., "ab") makes a new file
        tail = protect_file(photo, ctx)
        assert tail.state == "failed" and "not a recognised image" in (tail.reason or "")
        assert not ctx.vault.has(hashlib.sha256(src[len(src) // 2 :]).hexdigest())  # no fragment kept
        joined = quarantine(ctx, photo, "ds", tail.reason or "")
        assert joined == photo and photo.read_bytes() == src and not first.exists()
        assert [p for p in first.parent.iterdir()] == []  # nothing left in quarantine
        done = protect_file(photo, ctx)
        assert done.state == "patched" and done.original_sha256 == hashlib.sha256(src).hexdigest()
    finally:
        ctx.close()


# A `ppd poison` that SIGKILLs itself as record_provenance starts: the patched file renamed into place,
# its row still pending (what a kill in those milliseconds leaves).
_KILLED_BEFORE_ITS_ROW = """
import os, sys
import daemon.protect.stages as stages
def _killed(job):  # runs with stages' globals (its __code__ is swapped in): os is there, 9 is SIGKILL
    os.kill(os.getpid(), 9)
stages.record_provenance.__code__ = _killed.__code__
from daemon.cli import app
sys.argv = ["ppd", "poison", sys.argv[1]]
app()
"""


@pytest.mark.parametrize("form", ["file", "dataset"])
def test_restore_of_a_file_patched_but_not_yet_recorded_puts_the_original_back(
    ppd_env: dict[str, Path], tmp_path: Path, form: str
) -> None:
    """Found by a crash-safety review: after that kill `ppd restore FILE` said "state is pending",
    left the patched file in place and exited 0. The file's own seal names its original: restored."""
    from typer.testing import CliRunner

    from daemon.cli import app

    photo = write_image(tmp_path / "shoot" / "a.png", seed=4, size=96)
    original = photo.read_bytes()
    killed = subprocess.run(
        [sys.executable, "-c", _KILLED_BEFORE_ITS_ROW, str(photo)], cwd=REPO, capture_output=True, timeout=120
    )
    assert killed.returncode == -9, killed.stderr
    assert photo.read_bytes() != original  # patched in place, its row pending
    ctx = AppContext.open()
    assert ctx.store.file(photo)["state"] == FileState.PENDING
    ctx.close()
    done = CliRunner().invoke(app, ["restore", str(photo if form == "file" else photo.parent)])
    assert done.exit_code == 0 and "restored 1" in done.output, done.output
    assert photo.read_bytes() == original


def test_a_rerun_that_finds_the_file_done_lets_go_of_its_dead_attempt(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Found by a crash-safety review: after that kill the rerun recovered the file ("recovered after
    an interrupted run") but its attempt marker stayed, so every `ppd watch` start said "ppd died while
    patching" it and its next attempt ran isolated for nothing."""
    from typer.testing import CliRunner

    from daemon.cli import app
    from daemon.protect.quarantine import crashed_attempts

    photo = write_image(tmp_path / "shoot" / "a.png", seed=5, size=96)
    killed = subprocess.run(
        [sys.executable, "-c", _KILLED_BEFORE_ITS_ROW, str(photo)], cwd=REPO, capture_output=True, timeout=120
    )
    assert killed.returncode == -9, killed.stderr
    data_dir = AppPaths.from_env().data_dir
    assert [a.path for a in crashed_attempts(data_dir)] == [photo]
    rerun = CliRunner().invoke(app, ["-v", "poison", str(photo.parent)])
    assert rerun.exit_code == 0 and "recovered after an interrupted run" in rerun.output, rerun.output
    assert crashed_attempts(data_dir) == []
