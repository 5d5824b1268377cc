"""ppd's own leftovers are cleared the first time a process works in a folder: stale `.ppd-tmp-*`
files (by name, age and a free lock; never another live process's, never anyone else's) and
stale private work folders in the vault (issue 15 row 4, issue 20 row 7)."""

from __future__ import annotations

import fcntl
import logging
import os
import time
from pathlib import Path

import pytest

import daemon.fsops
from daemon.protect.one_file import AppContext, protect_file
from poisoner.atomic import TEMP_PREFIX
from testkit.reliability import write_image


def _age(path: Path, seconds: float) -> None:
    then = time.time() - seconds
    os.utime(path, (then, then))


def test_stale_temporaries_go_live_ones_and_others_stay(
    ppd_env: dict[str, Path], caplog: pytest.LogCaptureFixture
) -> None:
    """Another program's file under ppd's prefix stays (a black-box review, F14: a user's
    `.ppd-tmp-notes.txt` went); what is removed from the user's folder is logged."""
    folder = ppd_env["outbox"] / "ds"
    photo = write_image(folder / "a.jpg", seed=1)
    stale = folder / f"{TEMP_PREFIX}0000000dead1.jpg"
    stale.write_bytes(b"")  # a zero-byte leftover of a killed `ppd poison`
    _age(stale, 3600)
    live = folder / f"{TEMP_PREFIX}00000000a1fe.jpg"
    live.write_bytes(b"half")
    _age(live, 3600)
    holder = os.open(live, os.O_RDWR)
    fcntl.flock(holder, fcntl.LOCK_EX)  # another ppd process still writing it
    young = folder / f"{TEMP_PREFIX}0000000000e1.jpg"
    young.write_bytes(b"")
    other = folder / ".someone-else.tmp"
    other.write_bytes(b"not ours")
    _age(other, 3600)
    notes = folder / f"{TEMP_PREFIX}notes.txt"  # ppd's prefix, not its form: a person's
    notes.write_bytes(b"my notes")
    _age(notes, 3600)
    caplog.set_level(logging.INFO, logger="daemon.fsops")
    daemon.fsops._cleared.clear()  # a fresh process
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        assert not stale.exists()  # before: stayed for good
        assert live.exists() and young.exists() and other.read_bytes() == b"not ours"
        assert notes.read_bytes() == b"my notes"  # before: removed
        assert sorted(p.name for p in folder.iterdir() if p.name.startswith(TEMP_PREFIX)) == sorted(
            [live.name, young.name, notes.name]
        )
        said = [r.getMessage() for r in caplog.records if r.name == "daemon.fsops"]
        assert said == [f"removed 1 temporary file(s) a killed ppd left in {folder}: {stale.name}"], said
    finally:
        os.close(holder)
        ctx.close()


def test_stale_work_folders_in_the_vault_go(ppd_env: dict[str, Path]) -> None:
    """A killed protect's `.work-*` (its original's link and patched copy, up to twice a large file)
    goes when the next process opens the vault, whatever it does: before, only a process that
    patched a large file itself cleared them, so reruns with nothing left to patch kept them."""
    import daemon.store.vault

    ctx = AppContext.open()
    vault_dir = ctx.paths.vault_dir
    ctx.close()
    dead = vault_dir / ".work-deadbeef"
    dead.mkdir()
    (dead / "patched-a.png").write_bytes(b"x" * 1000)
    _age(dead, 3600)
    named = vault_dir / ".named-old1"  # an older ppd's named copy (no lock), left by a kill
    named.mkdir()
    (named / "a.png").write_bytes(b"y" * 1000)
    _age(named, 3600)
    young = vault_dir / ".work-young"  # between its creation and its lock
    young.mkdir()
    held = vault_dir / ".work-held"  # another process still working in it
    held.mkdir()
    _age(held, 3600)
    holder = os.open(held / ".lock", os.O_RDWR | os.O_CREAT, 0o600)
    fcntl.flock(holder, fcntl.LOCK_EX)
    daemon.store.vault._cleared.clear()  # a new process
    ctx = AppContext.open()  # nothing patched: `ppd status`, a rerun with every file done
    try:
        assert not dead.exists() and not named.exists()
        assert young.exists() and held.exists()
        photo = write_image(ppd_env["outbox"] / "ds" / "a.png", seed=2)
        assert protect_file(photo, ctx).state == "patched"
        assert sorted(p.name for p in vault_dir.glob(".work-*")) == [".work-held", ".work-young"]
    finally:
        os.close(holder)
        ctx.close()


def test_a_stale_temporary_goes_on_a_rerun_with_nothing_to_patch(ppd_env: dict[str, Path]) -> None:
    """A re-protect killed mid-write leaves `.ppd-tmp-*` beside its file (found in review); a rerun
    whose files are all done already never replaced anything there, so it never cleared the folder."""
    folder = ppd_env["outbox"] / "ds"
    photo = write_image(folder / "a.png", seed=3)
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        stale = folder / f"{TEMP_PREFIX}L630ad606c82b.png"
        stale.write_bytes(b"")
        _age(stale, 3600)
        daemon.fsops._cleared.clear()  # a new process
        assert protect_file(photo, ctx).state == "unchanged"
        assert not stale.exists()
    finally:
        ctx.close()
