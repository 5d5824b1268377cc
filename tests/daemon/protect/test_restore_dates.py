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
JUNE_2020 = MAY_2020 + 31 * 86_400 * 10**9


def _twins(folder: Path) -> tuple[Path, Path]:
    """a.jpg and b.jpg with the same bytes (one vault blob), dated May and June 2020."""
    first = write_image(folder / "a.jpg", seed=2)
    second = first.with_name("b.jpg")
    second.write_bytes(first.read_bytes())
    os.utime(first, ns=(MAY_2020, MAY_2020))
    os.utime(second, ns=(JUNE_2020, JUNE_2020))
    return first, second


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


def test_two_photos_with_the_same_bytes_get_their_own_dates_back(ppd_env: dict[str, Path]) -> None:
    """The vault keeps one blob for both (content addressing), dated as the first one kept; the store
    keeps each original's date (a black-box review: the second came back with the first's)."""
    first, second = _twins(ppd_env["outbox"] / "trip")
    ctx = AppContext.open()
    try:
        for photo in (first, second):
            assert protect_file(photo, ctx).state == "patched"
        for photo in (first, second):
            assert restore_file(ctx, photo).state == "restored"
    finally:
        ctx.close()
    assert (first.stat().st_mtime_ns, second.stat().st_mtime_ns) == (MAY_2020, JUNE_2020)


def test_an_original_recognised_by_another_path_does_not_keep_the_rows_old_date(
    ppd_env: dict[str, Path],
) -> None:
    """A row's date belongs to its original: recording another original for the path without one
    clears it, so restore falls back to the vault's date instead of giving the old one."""
    from daemon.states import FileState
    from poisoner.ladder import default_spec

    ctx = AppContext.open()
    try:
        path = ppd_env["outbox"] / "trip" / "c.jpg"
        ctx.store.ensure_dataset("trip", ppd_env["outbox"] / "trip", default_spec())
        ctx.store.record_file(path, "trip", FileState.PENDING, original_sha256="a" * 64, original_mtime_ns=5)
        ctx.store.record_file(path, "trip", FileState.PATCHED, original_sha256="a" * 64)
        assert ctx.store.file(path)["original_mtime_ns"] == 5  # the same original keeps its date
        ctx.store.record_file(path, "trip", FileState.PATCHED, original_sha256="b" * 64)
        assert ctx.store.file(path)["original_mtime_ns"] is None
    finally:
        ctx.close()


def test_a_renamed_photo_keeps_its_originals_date(ppd_env: dict[str, Path]) -> None:
    """The diff review: the row carried to a renamed file (carry_moved_row) left the original's date
    behind, so the rename of the second of two same-bytes photos came back with the first's date."""
    first, second = _twins(ppd_env["outbox"] / "trip")
    ctx = AppContext.open()
    try:
        for photo in (first, second):
            assert protect_file(photo, ctx).state == "patched"
        renamed = second.rename(second.with_name("c.jpg"))
        assert "moved from" in (protect_file(renamed, ctx).reason or "")
        assert restore_file(ctx, renamed).state == "restored"
    finally:
        ctx.close()
    assert renamed.stat().st_mtime_ns == JUNE_2020
