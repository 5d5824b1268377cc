"""Issue 29: nothing a file claims is trusted. A seal copied into a never-patched photo, a patched
photo cropped or edited with its metadata kept: each is a new photo (patched, its own bytes kept
in the vault, given back by restore), with the store and after losing it; restore never
overwrites bytes ppd did not write; the published file names no tool and no original hash."""

from __future__ import annotations

import hashlib
import struct
from pathlib import Path

import pytest

from daemon.protect.one_file import AppContext, protect_file, restore_file
from daemon.states import FileState
from poisoner.provenance import MAGIC
from testkit.forgery import edited, forged
from testkit.reliability import make_media


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _lose_store(ctx: AppContext) -> AppContext:
    db = ctx.paths.db_path
    ctx.close()
    for suffix in ("", "-wal", "-shm"):
        Path(f"{db}{suffix}").unlink(missing_ok=True)
    return AppContext.open()


@pytest.mark.parametrize("store_lost", [False, True])
@pytest.mark.parametrize("kind", ["jpg", "png", "mp4"])
def test_forged_and_edited_files_are_new_photos(
    ppd_env: dict[str, Path], kind: str, store_lost: bool
) -> None:
    ds = ppd_env["outbox"] / "ds"
    genuine = make_media(ds / f"genuine.{kind}", seed=1)
    genuine_original = genuine.read_bytes()
    ctx = AppContext.open()
    try:
        assert protect_file(genuine, ctx).state == "patched"
        patched = genuine.read_bytes()
        # what an attacker or a user makes from it
        impostors = {
            ds / f"forged.{kind}": forged(kind, patched, seed=2),
            ds / f"edited.{kind}": edited(kind, patched),
        }
        if store_lost:
            ctx = _lose_store(ctx)
        for path, data in impostors.items():
            path.write_bytes(data)
            outcome = protect_file(path, ctx)
            assert outcome.state == "patched", outcome  # before: "unchanged" (the marker trusted)
            assert path.read_bytes() != data and ctx.vault.verify(_sha(data))
            assert ctx.store.file(path)["original_sha256"] == _sha(data)
        # the genuine output is still recognised (no double patch), with or without its row
        again = protect_file(genuine, ctx)
        assert again.state == "unchanged" and genuine.read_bytes() == patched, again
        # restore gives each file its own bytes back, never another photo's original
        for path, data in impostors.items():
            assert restore_file(ctx, path).state == "restored"
            assert path.read_bytes() == data
        assert restore_file(ctx, genuine).state == "restored"
        assert genuine.read_bytes() == genuine_original
    finally:
        ctx.close()


@pytest.mark.parametrize("kind", ["jpg", "png"])
def test_restore_never_overwrites_an_edit_without_force(ppd_env: dict[str, Path], kind: str) -> None:
    """A patched file edited in place (cropped, its seal kept) before ppd saw it again: restore
    refuses it, with the store and after losing it (before: the marker named the original)."""
    photo = make_media(ppd_env["outbox"] / "ds" / f"a.{kind}", seed=3)
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        user_edit = edited(kind, photo.read_bytes())
        photo.write_bytes(user_edit)
        refused = restore_file(ctx, photo)
        assert refused.state == "failed" and "changed since ppd patched it" in refused.reason
        assert photo.read_bytes() == user_edit
        ctx = _lose_store(ctx)
        refused = restore_file(ctx, photo)
        assert refused.state == "failed" and photo.read_bytes() == user_edit, refused
        assert ctx.store.file(photo) is None or ctx.store.file(photo)["state"] != FileState.RESTORED
    finally:
        ctx.close()


@pytest.mark.parametrize("kind", ["jpg", "png", "mp4"])
def test_published_file_names_no_tool_and_no_original_hash(ppd_env: dict[str, Path], kind: str) -> None:
    photo = make_media(ppd_env["outbox"] / "ds" / f"a.{kind}", seed=4)
    original = photo.read_bytes()
    ctx = AppContext.open()
    try:
        outcome = protect_file(photo, ctx)
        assert outcome.state == "patched"
        meta = metadata_of(photo.read_bytes())
        assert MAGIC in meta  # sealed, in the metadata looked at
        for clear in (b"ppd", _sha(original).encode(), bytes.fromhex(_sha(original)), b"sha256"):
            assert clear not in meta.lower(), clear
    finally:
        ctx.close()


def metadata_of(data: bytes) -> bytes:
    """A file without its compressed picture (where any 3 bytes may occur by chance): a JPEG's
    header, a PNG's chunks but IDAT, an MP4's boxes but the mdat payload."""
    if data.startswith(b"\xff\xd8"):
        from poisoner.location import jpeg_header_segments

        return data[: jpeg_header_segments(data)[1]]
    parts, pos = [], 8 if data.startswith(b"\x89PNG") else 0
    while pos + 8 <= len(data):
        if pos and data.startswith(b"\x89PNG"):
            (n,) = struct.unpack(">I", data[pos : pos + 4])
            if data[pos + 4 : pos + 8] != b"IDAT":
                parts.append(data[pos : pos + 12 + n])
            pos += 12 + n
        else:
            (n,) = struct.unpack(">I", data[pos : pos + 4])
            parts.append(data[pos : pos + 8] if data[pos + 4 : pos + 8] == b"mdat" else data[pos : pos + n])
            pos += n
    return b"".join(parts)
