"""A patched photo saved again in place by another program, its seal gone (a black-box review,
2026-12-07, F1): a PNG re-saved by Pillow (the same pixels, the seal chunk dropped), a JPEG saved again
at quality 90. It was taken as a new original: vaulted as one, marked a second time, and `ppd restore`
said "restored" and handed back the once-marked picture. Now (the daemon's protect_file, in the outbox)
it is ppd's output, recorded as such with its clean original, never marked twice, and restore --force
gives the clean original back, keeping the re-saved file; an edit or a crop is still a new photo, and
its restore says its original was saved over ppd's patched photo and where the photo from before is."""

from __future__ import annotations

import hashlib
import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from daemon.protect.one_file import AppContext, protect_file, restore_file
from daemon.protect.resaved import RESAVED_REASON
from daemon.states import FileState
from testkit.photos import textured


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _pixels(data: bytes | Path) -> np.ndarray:
    with Image.open(io.BytesIO(data) if isinstance(data, bytes) else data) as im:
        return np.asarray(im.convert("RGB"))


def _photo(path: Path) -> bytes:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(textured(240, 320, seed=3)).save(path, quality=95)
    return path.read_bytes()


def _resave(path: Path) -> bytes:
    """Opened and saved again by Pillow, as an editor does: a JPEG at quality 90, a PNG as it is."""
    with Image.open(path) as im:
        im.load()
        im.save(path, **({"quality": 90} if path.suffix == ".jpg" else {}))
    return path.read_bytes()


@pytest.mark.parametrize("name", ["a.png", "a.jpg"])
def test_a_resaved_patched_photo_is_not_marked_twice_and_restore_keeps_it(
    ppd_env: dict[str, Path], name: str
) -> None:
    photo = ppd_env["outbox"] / "shoot" / name
    original = _photo(photo)
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        patched = photo.read_bytes()
        resaved = _resave(photo)
        assert resaved != patched
        if name.endswith(".png"):  # the same pixels, other bytes
            assert np.array_equal(_pixels(resaved), _pixels(patched))
        again = protect_file(photo, ctx)
        assert (again.state, again.reason) == ("unchanged", RESAVED_REASON)  # before: patched (a second mark)
        assert photo.read_bytes() == resaved
        assert not ctx.vault.has(_sha(resaved))  # never kept as an "original"
        row = ctx.store.file(photo)
        assert row["state"] == FileState.PATCHED and row["resaved"] == 1
        assert (row["original_sha256"], row["poisoned_sha256"]) == (_sha(original), _sha(resaved))
        assert protect_file(photo, ctx).reason == "already patched"  # judged once
        refused = restore_file(ctx, photo)  # its bytes are the creator's: kept without --force
        assert refused.state == "failed" and "saved again since" in (refused.reason or ""), refused.reason
        assert photo.read_bytes() == resaved
        forced = restore_file(ctx, photo, force=True)
        assert forced.state == "restored" and photo.read_bytes() == original  # the clean original
        ((_, kept),) = forced.displaced
        assert kept.read_bytes() == resaved
    finally:
        ctx.close()


@pytest.mark.parametrize("edit", ["retouch", "crop"])
def test_an_edit_of_a_patched_photo_is_a_new_photo_and_restore_says_what_its_original_is(
    ppd_env: dict[str, Path], edit: str
) -> None:
    photo = ppd_env["outbox"] / "shoot" / "b.jpg"
    original = _photo(photo)
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        with Image.open(photo) as im:
            pixels = np.asarray(im.convert("RGB")).copy()
        if edit == "retouch":  # a spot painted out, far from the mark
            pixels[100:140, 140:180] = 128
        else:
            pixels = pixels[:200, :280]
        Image.fromarray(pixels).save(photo, quality=92)
        saved = photo.read_bytes()
        outcome = protect_file(photo, ctx)
        assert outcome.state == "patched", outcome.reason  # a new photo to protect, as before
        row = ctx.store.file(photo)
        assert row["original_sha256"] == _sha(saved) and row["saved_over"] == _sha(original)
        restored = restore_file(ctx, photo)
        assert restored.state == "restored" and photo.read_bytes() == saved
        said = restored.reason or ""
        assert "its original is the file saved over ppd's patched photo" in said, said
        assert "still carries ppd's mark" in said and str(ctx.vault.path_for(_sha(original))) in said, said
        assert ctx.vault.path_for(_sha(original)).read_bytes() == original  # the photo from before, kept
    finally:
        ctx.close()


def test_a_photo_patched_again_after_its_restore_keeps_no_note(ppd_env: dict[str, Path]) -> None:
    """A restored photo edited and patched: its original holds nothing of ppd's, no note."""
    photo = ppd_env["outbox"] / "shoot" / "c.png"
    _photo(photo)
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        assert restore_file(ctx, photo).state == "restored"
        Image.fromarray(textured(240, 320, seed=4)).save(photo)
        assert protect_file(photo, ctx).state == "patched"
        assert ctx.store.file(photo)["saved_over"] is None
        assert restore_file(ctx, photo).reason is None
    finally:
        ctx.close()
