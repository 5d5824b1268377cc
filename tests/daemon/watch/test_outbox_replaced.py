"""The outbox moved away and a folder of the same name made again under the running daemon (a
black-box review: `mv outbox outbox.moved; mkdir -p outbox/new; cp a.jpg outbox/new/` and a.jpg
was never patched, nothing logged: the observer lived on in the moved folder and the path was a
folder again, so the liveness check passed). Real inotify, a real store, real files."""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
from pathlib import Path

import pytest

from daemon.locks import LockHeld, outbox_lock
from daemon.states import FileState
from testkit.daemon_proc import wait_for
from testkit.photos import write_image
from tests.daemon.watch.test_watcher import FAST, running, store_of, wait_idle


def test_an_outbox_moved_away_and_made_again_is_watched_again(
    ppd_env: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    outbox = ppd_env["outbox"]
    first = write_image(outbox / "old" / "one.png", 1)
    photo = write_image(tmp_path / "stage" / "a.png", 2)
    caplog.set_level(logging.INFO, logger="daemon.watch")
    with running(ppd_env) as daemon:
        wait_for(lambda: daemon.counts.patched >= 1, 30, "the first file")
        wait_idle(daemon)
        os.rename(outbox, outbox.parent / "outbox.moved")
        (outbox / "new").mkdir(parents=True)
        shutil.copyfile(photo, outbox / "new" / "a.png")
        wait_for(lambda: daemon.counts.patched >= 2, 20, "the file in the folder made again")
        wait_idle(daemon)
        assert daemon.counts.removed == 1  # one.png went with the folder moved away
        # the moved folder is not watched any more: a file dropped there is left alone
        shutil.copyfile(photo, outbox.parent / "outbox.moved" / "old" / "b.png")
        shutil.copyfile(photo, outbox / "new" / "c.png")
        wait_for(lambda: daemon.counts.patched >= 3, 20, "a later file in the new outbox")
        wait_idle(daemon)
        assert daemon.counts.patched == 3
        # the outbox lock moved with the watch: the new folder is held, the moved one free
        with pytest.raises(LockHeld, match="is already watching"), outbox_lock(ppd_env["data"], outbox):
            pass
        with outbox_lock(ppd_env["data"], outbox.parent / "outbox.moved"):
            pass
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(said) == 1 and str(outbox) in said[0], said  # said once
    store = store_of(ppd_env)
    assert store.file(outbox / "new" / "a.png")["state"] == FileState.PATCHED
    assert store.file(first)["state"] == FileState.REMOVED
    assert store.file(outbox.parent / "outbox.moved" / "old" / "b.png") is None


def test_an_outbox_moved_with_its_parent_is_told_apart_by_its_identity(
    ppd_env: dict[str, Path],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A folder above the outbox renamed: no event reaches the daemon (the outbox itself was not
    renamed); the folder at the outbox's path is told apart by its (device, inode) on the next check."""
    outbox = tmp_path / "top" / "outbox"
    outbox.mkdir(parents=True)
    monkeypatch.setenv("PPD_OUTBOX", str(outbox))
    photo = write_image(tmp_path / "stage" / "a.png", 2)
    caplog.set_level(logging.INFO, logger="daemon.watch")
    with running(ppd_env, dataclasses.replace(FAST, outbox_check_s=0.5)) as daemon:
        os.rename(tmp_path / "top", tmp_path / "top.moved")
        (outbox / "new").mkdir(parents=True)
        shutil.copyfile(photo, outbox / "new" / "a.png")
        wait_for(lambda: daemon.counts.patched >= 1, 20, "the file in the folder made again")
        wait_idle(daemon)
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(said) == 1 and "is another folder now" in said[0], said
    assert store_of(ppd_env).file(outbox / "new" / "a.png")["state"] == FileState.PATCHED
