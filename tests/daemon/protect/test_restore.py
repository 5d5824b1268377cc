"""restore_file never writes an original into an output or publish folder, and a lost store
neither leads to double poisoning nor hides the originals (provenance markers + the vault)."""

from __future__ import annotations

import hashlib
from pathlib import Path

from daemon.protect.one_file import AppContext, protect_file, restore_file
from daemon.states import FileState
from testkit.reliability import patched_then_store_lost, write_image


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_restore_removes_an_out_copy_and_leaves_the_source(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    source = write_image(tmp_path / "shoot" / "a.jpg", seed=1)
    before = source.read_bytes()
    out = tmp_path / "pub" / "a.jpg"
    ctx = AppContext.open()
    try:
        patched = protect_file(source, ctx, "shoot", root=source.parent, out_path=out)
        assert patched.state == "patched" and out.is_file() and source.read_bytes() == before
        restored = restore_file(ctx, out)
        assert restored.state == "restored" and "output folder" in restored.reason, restored
        assert not out.exists()  # before: the original was written into the --out folder
        assert source.read_bytes() == before
    finally:
        ctx.close()


def test_lost_store_no_double_poisoning_and_restore_by_marker(ppd_env: dict[str, Path]) -> None:
    photos = [
        write_image(ppd_env["outbox"] / "ds" / f"{i}{s}", seed=i) for i, s in enumerate((".png", ".jpg"))
    ]
    originals = {p: p.read_bytes() for p in photos}
    ctx = AppContext.open()
    first = {p: protect_file(p, ctx) for p in photos}
    assert {o.state for o in first.values()} == {"patched"}
    db = ctx.paths.db_path
    ctx.close()
    for suffix in ("", "-wal", "-shm"):  # the store lost (deleted after a kill)
        Path(f"{db}{suffix}").unlink(missing_ok=True)
    ctx = AppContext.open()
    try:
        patched_bytes = {p: p.read_bytes() for p in photos}
        again = {p: protect_file(p, ctx) for p in photos}
        for p, o in again.items():
            assert o.state == "unchanged" and "provenance seal" in o.reason, o
            assert p.read_bytes() == patched_bytes[p]  # not poisoned a second time
            assert ctx.store.file(p)["state"] == FileState.PATCHED  # the row came back
        for p in photos:
            assert restore_file(ctx, p).state == "restored"
            assert p.read_bytes() == originals[p]
    finally:
        ctx.close()


def test_restore_without_any_row_uses_the_marker(ppd_env: dict[str, Path]) -> None:
    photo, original = patched_then_store_lost(ppd_env["outbox"] / "ds", seed=7)
    ctx = AppContext.open()
    try:
        outcome = restore_file(ctx, photo)
        assert outcome.state == "restored", outcome
        assert photo.read_bytes() == original and _sha(photo) == outcome.original_sha256
    finally:
        ctx.close()


def _new_key(ctx: AppContext) -> AppContext:
    """The seal key replaced (lost, then `ppd key new`; or `ppd key import --force` of another one)."""
    from daemon.store.sealkey import new_key

    ctx.close()
    (ctx.paths.data_dir / "seal.key").unlink()
    new_key(ctx.paths.data_dir)  # ppd never makes one on its own beside a vault of originals
    return AppContext.open()


def test_a_renamed_file_sealed_with_a_replaced_key_is_found_by_its_recorded_bytes(
    ppd_env: dict[str, Path],
) -> None:
    """A black-box review (F10): the store still knew the renamed file's patched sha256, which `ppd
    poison` uses, but restore read only the seal and said "carries no ppd provenance marker"."""
    photo = write_image(ppd_env["outbox"] / "ds" / "a.png", seed=3)
    original = photo.read_bytes()
    ctx = AppContext.open()
    try:
        assert protect_file(photo, ctx).state == "patched"
        renamed = photo.rename(photo.with_name("r.png"))
        ctx = _new_key(ctx)
        outcome = restore_file(ctx, renamed)
        assert outcome.state == "restored", outcome
        assert renamed.read_bytes() == original
    finally:
        ctx.close()


def test_a_file_sealed_with_another_key_says_so(ppd_env: dict[str, Path]) -> None:
    """No row and a seal this installation's key does not open: not "no ppd provenance marker", but
    which key to import."""
    photo, _ = patched_then_store_lost(ppd_env["outbox"] / "ds", seed=5)
    ctx = AppContext.open()
    try:
        ctx = _new_key(ctx)
        patched = photo.read_bytes()
        outcome = restore_file(ctx, photo)
        assert outcome.state == "failed" and "sealed with another key" in outcome.reason, outcome
        assert "`ppd key import`" in outcome.reason and photo.read_bytes() == patched
    finally:
        ctx.close()
