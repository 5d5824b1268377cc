"""`ppd restore` gives back the original's modification time, not the time of the restore (a black-box
review, 2026-12-07: a photo from 2020 came back dated today, and a library sorted by file date lost
it). The vault keeps the date with the original. The patched file itself gets a new time, so that a
sync tool that compares size and time (rsync's quick check) always sends the patched version."""

from __future__ import annotations

import os
from pathlib import Path

from daemon.protect.one_file import AppContext, protect_file, restore_file
from testkit.photos import write_image

MAY_2020 = 1_588_291_200_000_000_000  # ns


def test_restore_gives_back_the_originals_date(ppd_env: dict[str, Path]) -> None:
    photo = write_image(ppd_env["outbox"] / "trip" / "a.jpg", seed=2)
    os.utime(photo, ns=(MAY_2020, MAY_2020))
    original = photo.read_bytes()
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        assert photo.stat().st_mtime_ns != MAY_2020  # the patched file is new
        assert restore_file(ctx, photo).state == "restored"
    finally:
        ctx.close()
    assert photo.read_bytes() == original and photo.stat().st_mtime_ns == MAY_2020
