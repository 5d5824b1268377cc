"""A publish folder ppd cannot write (a black-box review, s5 F3: the unit's ProtectSystem=strict made a
dataset's own publish folder read-only): the file is patched but stays in the outbox. It was logged as
`unchanged ... reason="already patched ([Errno 30] Read-only file system ...)"` at info, and `ppd
status` said nothing. Now the move's failure is a failure with the real reason, counted by `ppd status`
(and `--check`), and the next run moves the file. The folder is made read-only for real: a read-only
bind mount in a mount namespace of its own (`unshare -m`, as the review did), for `ppd watch` and for
`ppd poison`."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.states import FileState
from daemon.store import Store
from testkit.reliability import REPO, app_paths, drop_files, sha256, subprocess_env, wait_for

UNSHARE = shutil.which("unshare")


def _can_mount_read_only(tmp_path: Path) -> bool:
    if UNSHARE is None or os.geteuid() != 0:
        return False
    probe = tmp_path / "probe"
    probe.mkdir()
    script = f"mount --bind {probe} {probe} && mount -o remount,bind,ro {probe} && ! touch {probe}/x"
    done = subprocess.run([UNSHARE, "-m", "sh", "-c", script], capture_output=True, timeout=30)
    probe.rmdir()
    return done.returncode == 0


@pytest.fixture
def read_only_ok(tmp_path: Path) -> None:
    if not _can_mount_read_only(tmp_path):
        pytest.skip("needs root and unshare -m for a read-only bind mount")


def read_only(folder: Path, *args: str) -> list[str]:
    """`ppd ARGS` in a mount namespace where folder is read-only (the rest as it is)."""
    ppd = " ".join(shlex.quote(a) for a in (sys.executable, "-m", "daemon.cli", *args))
    f = shlex.quote(str(folder))
    script = f"mount --bind {f} {f} && mount -o remount,bind,ro {f} && exec {ppd}"
    return [str(UNSHARE), "-m", "sh", "-c", script]


def ppd(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", *args], env=subprocess_env(root), cwd=REPO,
                          capture_output=True, text=True, timeout=120)  # fmt: skip


def row(root: Path, path: Path) -> dict:
    store = Store(app_paths(root).db_path)
    try:
        return store.file(path) or {}
    finally:
        store.close()


def test_a_move_the_publish_folder_refuses_is_a_failure_and_the_next_run_moves(
    tmp_path: Path, read_only_ok: None
) -> None:
    pub = tmp_path / "pub2"
    pub.mkdir()
    beach = tmp_path / "outbox" / "beach"
    beach.mkdir(parents=True)  # a new dataset needs its folder (a seventh black-box review, F4)
    assert ppd(tmp_path, "dataset", "set", "beach", "--publish-dir", str(pub)).returncode == 0
    written = drop_files(tmp_path / "stage", beach, [("c.png", 3)])
    log = tmp_path / "watch.log"
    with open(log, "wb") as fh:
        daemon = subprocess.Popen(
            read_only(pub, "watch", "--no-verify", "--debounce", "0.05"), env=subprocess_env(tmp_path),
            cwd=REPO, stdout=fh, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:
        wait_for(lambda: 'msg="failed c.png"' in log.read_text(), 60, "the failed move logged")
    finally:
        daemon.terminate()
        assert daemon.wait(60) == 0
    said = log.read_text()
    line = next(ln for ln in said.splitlines() if 'msg="failed c.png"' in ln)
    assert "level=warning" in line and "already patched" not in line, line
    assert f'reason="patched, but not moved to {pub}: read-only file system' in line, line
    assert "failed 1" in said  # the daemon's own count (stop summary)
    stuck = beach / "c.png"
    assert sha256(stuck) != written[stuck] and row(tmp_path, stuck)["state"] == FileState.PATCHED
    assert not any(pub.iterdir())

    status = ppd(tmp_path, "status", "beach")
    flat = " ".join(status.stdout.split())
    assert "patched 1 (1 NOT moved to the publish folder: still in the outbox)" in flat, status.stdout
    failed = " ".join(ppd(tmp_path, "status", "beach", "--failed").stdout.split())
    assert f"beach: 0 failed, 0 quarantined, 1 not moved to the publish folder {stuck}: patched, but not " \
           f"moved to {pub}: read-only file system" in failed  # fmt: skip
    check = ppd(tmp_path, "status", "--check")
    assert check.returncode == 1 and "1 patched but NOT moved to the publish folder" in check.stderr

    again = subprocess.run(read_only(pub, "poison", str(beach)), env=subprocess_env(tmp_path), cwd=REPO,
                           capture_output=True, text=True, timeout=120)  # fmt: skip
    assert again.returncode == 1, again.stdout + again.stderr  # still read-only: still said, exit 1
    assert f"not moved to {pub}: read-only file system" in " ".join(again.stderr.split())
    moved = ppd(tmp_path, "poison", str(beach))  # writable again: the next run moves it
    assert moved.returncode == 0, moved.stdout + moved.stderr
    assert not stuck.exists() and (pub / "c.png").is_file()
    assert row(tmp_path, stuck)["published_path"] == str(pub / "c.png")
    assert "not moved" not in ppd(tmp_path, "status", "beach").stdout
    assert ppd(tmp_path, "status", "beach", "--check").stderr.count("NOT moved") == 0
