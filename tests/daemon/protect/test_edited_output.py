"""ppd's output edited after patching without its pixels changing (a tagger wrote keywords in
place) is recognised as ppd's output, not patched a second time, and `ppd restore --force` still
gives back the true original (a black-box review, 2026-12-07: the once-marked file went into the vault
as an "original", got a second mark, and restore returned the marked file); without --force
restore keeps the creator's edit (the review's F2: it wrote the original over it, no copy kept).
A token copied onto another photo is still not trusted: that photo is patched as a new one."""

from __future__ import annotations

import hashlib
import io
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from daemon.protect.one_file import AppContext, protect_file, restore_file
from daemon.states import FileState
from testkit.photos import write_image


def with_comment(data: bytes, text: bytes) -> bytes:
    """A JPEG with a comment segment added after SOI, as a tagger edits metadata: no pixel moves."""
    return data[:2] + b"\xff\xfe" + (len(text) + 2).to_bytes(2, "big") + text + data[2:]


def replace(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".t")
    tmp.write_bytes(data)
    os.replace(tmp, path)


@pytest.mark.parametrize("name", ["b01.jpg", "b02.png"])
def test_a_metadata_edit_is_not_patched_twice_and_restore_gives_the_original(
    ppd_env: dict[str, Path], name: str
) -> None:
    photo = write_image(ppd_env["outbox"] / "k2" / name, seed=7)
    original = photo.read_bytes()
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        patched = photo.read_bytes()
        if name.endswith(".jpg"):
            edited = with_comment(patched, b"copyright me")
        else:  # a PNG text chunk before IEND
            import struct
            import zlib

            body = b"Comment\x00copyright me"
            chunk = (
                struct.pack(">I", len(body)) + b"tEXt" + body + struct.pack(">I", zlib.crc32(b"tEXt" + body))
            )
            edited = patched[:-12] + chunk + patched[-12:]
        replace(photo, edited)
        assert np.array_equal(np.asarray(Image.open(photo)), np.asarray(Image.open(io.BytesIO(patched))))
        again = protect_file(photo, ctx)
        assert again.state == "unchanged", again.reason  # before: patched (a second mark)
        assert "changed after patching" in (again.reason or "")
        assert photo.read_bytes() == edited
        row = ctx.store.file(photo)
        assert row["state"] == FileState.PATCHED
        assert row["original_sha256"] == hashlib.sha256(original).hexdigest()
        assert row["poisoned_sha256"] == hashlib.sha256(edited).hexdigest()
        # the rating or keywords are the creator's: not written over without --force (a black-box review,
        # F2: restore wrote the original over the edited file and kept no copy)
        refused = restore_file(ctx, photo)
        assert refused.state == "failed" and "saved again since by another program" in (refused.reason or "")
        assert "--force keeps your version in" in (refused.reason or "") and photo.read_bytes() == edited
        forced = restore_file(ctx, photo, force=True)
        assert forced.state == "restored", forced.reason
        assert photo.read_bytes() == original  # the true original, not the once-marked file
        ((_, kept),) = forced.displaced
        assert kept.read_bytes() == edited and kept.is_relative_to(ppd_env["data"] / "displaced")
        # patched again by ppd: its own output, no longer called the creator's bytes
        assert protect_file(photo, ctx, force=True).state == "patched"
        assert not ctx.store.file(photo)["resaved"]
    finally:
        ctx.close()


def test_a_token_copied_onto_another_photo_is_not_trusted(ppd_env: dict[str, Path]) -> None:
    photo = write_image(ppd_env["outbox"] / "k2" / "a.jpg", seed=7)
    other = write_image(ppd_env["outbox"] / "k2" / "b.jpg", seed=8)
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        patched = photo.read_bytes()
        # the other photo with the patched file's whole header (its token included) grafted on
        sos = patched.index(b"\xff\xda")
        theirs = other.read_bytes()
        replace(other, patched[:sos] + theirs[theirs.index(b"\xff\xda") :])
        before = other.read_bytes()
        outcome = protect_file(other, ctx)
        assert outcome.state == "patched", outcome.reason
        assert other.read_bytes() != before
    finally:
        ctx.close()


def test_an_edited_output_copied_into_a_new_folder_is_recognised_there(ppd_env: dict[str, Path]) -> None:
    """A diff review: in a folder ppd had not seen, recording it failed ('FOREIGN KEY constraint
    failed': no dataset row yet) and the file was reported failed."""
    photo = write_image(ppd_env["outbox"] / "a" / "p.jpg", seed=9)
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        copy = ppd_env["outbox"] / "newds" / "p.jpg"
        copy.parent.mkdir()
        copy.write_bytes(with_comment(photo.read_bytes(), b"rated 5 stars"))
        outcome = protect_file(copy, ctx)
        assert outcome.state == "unchanged", outcome.reason
        assert ctx.store.file(copy)["state"] == FileState.PATCHED
    finally:
        ctx.close()


def test_an_edited_output_given_to_out_is_not_marked_again(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """With --out, an edited output was patched again into the copy (a second mark) and kept in the
    vault as an "original" (a diff review); it is left as ppd's sealed output is."""
    photo = write_image(ppd_env["outbox"] / "k" / "b.jpg", seed=11)
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        edited = with_comment(photo.read_bytes(), b"keywords")
        replace(photo, edited)
        out = tmp_path / "out" / "b.jpg"
        outcome = protect_file(photo, ctx, out_path=out)
        assert outcome.state == "unchanged", outcome.reason
        assert not ctx.vault.has(hashlib.sha256(edited).hexdigest())
    finally:
        ctx.close()
