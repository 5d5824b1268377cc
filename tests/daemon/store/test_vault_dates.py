"""The vault's copy of an original carries the original's dates from the moment it has its name: a
keep killed right after the rename left a blob dated the day of the run, which no later keep fixed
(content already kept is not written again), so `ppd restore` gave back the wrong modification time
(a black-box review, strace-injected kills)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from daemon.store import vault as vault_module
from daemon.store.vault import Vault


def test_a_keep_killed_just_after_its_rename_leaves_the_originals_date(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    photo = tmp_path / "a.jpg"
    photo.write_bytes(b"\xff\xd8 an original \xff\xd9")
    os.utime(photo, ns=(1_600_000_000_000_000_000, 1_600_000_050_000_000_000))
    vault = Vault(tmp_path / "vault")
    real_replace = os.replace

    def rename_then_die(src: str | Path, dst: str | Path) -> None:
        real_replace(src, dst)
        raise KeyboardInterrupt  # the process ends here, as a SIGKILL right after the rename would

    monkeypatch.setattr(vault_module.os, "replace", rename_then_die)
    with pytest.raises(KeyboardInterrupt):
        vault.keep(photo)
    monkeypatch.undo()
    (blob,) = [p for p in (tmp_path / "vault").glob("??/*") if len(p.name) == 64]
    assert blob.stat().st_mtime_ns == 1_600_000_050_000_000_000
    assert blob.read_bytes() == photo.read_bytes()
