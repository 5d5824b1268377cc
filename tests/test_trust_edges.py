"""Issue 29, the smaller items, each failing on the code before it: a 255-byte file name is
patched; the single-instance lock is the outbox's device and inode (a symlink to it is the same
outbox); `ppd store rebuild` refuses while a daemon holds the outbox; a lost store is reported,
never silently recreated empty; `.keep-*` vault leftovers are cleaned and counted; folders are
0700 and quarantined files 0600 whatever the umask."""

from __future__ import annotations

from pathlib import Path

import pytest
from reliability_harness import write_image

from daemon.protect import AppContext, protect_file
from daemon.states import FileState


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
