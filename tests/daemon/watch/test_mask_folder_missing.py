"""A dataset's `[datasets.NAME] subject_masks` folder that is not there (a drive unplugged) is that
dataset's state, not a bad config (a black-box review, s5 F4: `ppd status` and `ppd watch` exited 2 at
config load, systemd does not restart on 2, and nothing dropped in the outbox for any dataset was
protected until the drive was back). Now: the daemon runs, the other datasets go on, that dataset's
files are left as they are (never patched without their masks) and retried once the folder is back;
`ppd status` and the daemon's log say why; `ppd poison` of that dataset stops with one line, exit 3.
A real `ppd watch` process, real files, a real store."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from daemon.states import FileState
from daemon.store import Store
from testkit.photos import changed_pixels, masked_shoot
from testkit.reliability import (
    DAEMON_ARGS,
    REPO,
    app_paths,
    drop_files,
    kill_daemon,
    start_daemon,
    subprocess_env,
    wait_all_protected,
    wait_for,
)


def ppd(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", *args], env=subprocess_env(root), cwd=REPO,
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_a_missing_mask_folder_holds_back_its_dataset_only(tmp_path: Path) -> None:
    usb = tmp_path / "usb" / "porch-masks"  # the drive is not plugged in
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "config.toml").write_text(f'[datasets.porch]\nsubject_masks = "{usb}"\n')
    said_missing = f"[datasets.porch] subject_masks: {usb} is not a readable folder"

    status = ppd(tmp_path, "status")  # it read the config and stopped: exit 2
    assert status.returncode == 0, status.stderr
    assert said_missing in " ".join(status.stderr.split())

    staged = tmp_path / "staged"
    porch = masked_shoot(staged / "porch", staged / "masks", n=1)[0]
    outbox = tmp_path / "outbox"
    (outbox / "porch").mkdir(parents=True)
    original = porch.read_bytes()
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)
    try:
        shutil.move(porch, outbox / "porch" / porch.name)
        beach = drop_files(tmp_path / "stage", outbox / "beach", [("b.jpg", 1)])
        wait_all_protected(app_paths(tmp_path), list(beach), timeout=60)  # the other dataset goes on
        waiting = outbox / "porch" / porch.name
        wait_for(lambda: f'msg="failed {porch.name}"' in daemon.log.read_text(), 60, "porch's file failed")
        log = daemon.log.read_text()
        assert said_missing in log and "msg=\"ppd watch ready\"" in log
        assert waiting.read_bytes() == original  # left as it is: not patched without its masks

        status = ppd(tmp_path, "status")
        assert status.returncode == 0 and said_missing in " ".join(status.stderr.split())
        assert "NOT protected (porch/000000.png)" in " ".join(status.stdout.split())
        assert ppd(tmp_path, "status", "--check").returncode == 1

        poison = ppd(tmp_path, "poison", str(outbox / "porch"))
        lines = poison.stderr.strip().splitlines()
        assert poison.returncode == 3 and lines[-1].startswith(f"ppd: error: {said_missing}"), poison.stderr
        assert waiting.read_bytes() == original

        usb.parent.mkdir()
        shutil.move(staged / "masks", usb)  # the drive is back: the file is patched off its subject
        wait_all_protected(app_paths(tmp_path), [waiting], timeout=60)
    finally:
        assert kill_daemon(daemon, signal.SIGTERM) == 0
    mask = np.asarray(Image.open(usb / "000.png")) > 0
    changed = changed_pixels(original, waiting)
    assert changed.any() and not (changed & mask).any()
    store = Store(app_paths(tmp_path).db_path)
    try:
        assert store.file(waiting)["state"] == FileState.PATCHED
    finally:
        store.close()
