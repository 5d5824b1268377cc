"""The originals vault on real files: content addressing, hard links, byte-exact restore."""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

import pytest

from daemon.vault import Vault, VaultError, VaultFullError


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@pytest.fixture
def vault(tmp_path: Path) -> Vault:
    return Vault(tmp_path / "vault")


def test_keep_then_restore_is_byte_exact(vault: Vault, tmp_path: Path) -> None:
    data = os.urandom(100_000)
    src = tmp_path / "a.jpg"
    src.write_bytes(data)
    sha = vault.keep(src)
    assert sha == _sha(data)
    assert vault.path_for(sha) == vault.vault_dir / sha[:2] / sha
    dst = tmp_path / "restored.jpg"
    vault.restore(sha, dst)
    assert dst.read_bytes() == data


def test_replace_after_keep_leaves_the_original_in_the_vault(vault: Vault, tmp_path: Path) -> None:
    data = os.urandom(50_000)
    src = tmp_path / "a.png"
    src.write_bytes(data)
    sha = vault.keep(src)
    blob = vault.path_for(sha)
    assert blob.stat().st_ino == src.stat().st_ino  # same filesystem: kept by hard link
    new = tmp_path / ".tmp"
    new.write_bytes(b"poisoned version")
    os.replace(new, src)  # what atomic_output does
    assert blob.read_bytes() == data and vault.verify(sha)
    vault.restore(sha, src)
    assert src.read_bytes() == data
    assert src.stat().st_ino != blob.stat().st_ino  # restored as a copy, never a link


def test_vault_dirs_are_private(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"x" * 10)
    sha = vault.keep(src)
    assert stat.S_IMODE(vault.vault_dir.stat().st_mode) == 0o700
    assert stat.S_IMODE(vault.path_for(sha).parent.stat().st_mode) == 0o700


def test_copy_when_not_linking(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"original")
    sha = vault.keep(src, link=False)
    assert vault.path_for(sha).stat().st_ino != src.stat().st_ino
    with open(src, "r+b") as fh:  # an in-place edit of the original does not reach the vault
        fh.write(b"EDITED!!")
    assert vault.path_for(sha).read_bytes() == b"original"


def test_same_content_is_kept_once(vault: Vault, tmp_path: Path) -> None:
    for name in ("a.png", "b.png"):
        (tmp_path / name).write_bytes(b"same bytes")
    assert vault.keep(tmp_path / "a.png") == vault.keep(tmp_path / "b.png")
    assert len(list(vault.vault_dir.glob("??/*"))) == 1
    assert not list(vault.vault_dir.glob(".keep-*"))  # no temporaries left


def test_restore_keeps_destination_mode(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"original")
    sha = vault.keep(src, link=False)
    dst = tmp_path / "dst.png"
    dst.write_bytes(b"poisoned")
    os.chmod(dst, 0o640)
    vault.restore(sha, dst)
    assert dst.read_bytes() == b"original"
    assert stat.S_IMODE(dst.stat().st_mode) == 0o640


def test_corrupt_blob_is_not_restored(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"original")
    sha = vault.keep(src, link=False)
    vault.path_for(sha).write_bytes(b"tampered")
    dst = tmp_path / "dst.png"
    dst.write_bytes(b"poisoned")
    assert not vault.verify(sha)
    with pytest.raises(VaultError, match="corrupt"):
        vault.restore(sha, dst)
    assert dst.read_bytes() == b"poisoned"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ppd-tmp-")]


def test_missing_and_malformed_digests(vault: Vault, tmp_path: Path) -> None:
    with pytest.raises(VaultError, match="not in the vault"):
        vault.restore("0" * 64, tmp_path / "x")
    with pytest.raises(VaultError, match="sha256"):
        vault.path_for("../../etc/passwd")


def test_full_vault_refuses_instead_of_deleting(tmp_path: Path) -> None:
    vault = Vault(tmp_path / "vault", max_bytes=1500)
    first, second = tmp_path / "a", tmp_path / "b"
    first.write_bytes(b"a" * 1000)
    second.write_bytes(b"b" * 1000)
    kept = vault.keep(first)
    with pytest.raises(VaultFullError, match="max_bytes"):
        vault.keep(second)
    assert vault.has(kept) and vault.usage_bytes() == 1000
    assert second.read_bytes() == b"b" * 1000


def test_cross_filesystem_keep_copies(tmp_path: Path) -> None:
    shm = Path("/dev/shm")
    if not shm.is_dir() or shm.stat().st_dev == tmp_path.stat().st_dev:
        pytest.skip("no second filesystem to keep across")
    src = tmp_path / "a.png"
    src.write_bytes(b"cross fs original")
    import tempfile

    with tempfile.TemporaryDirectory(dir=shm) as other:
        vault = Vault(Path(other) / "vault")
        sha = vault.keep(src)
        blob = vault.path_for(sha)
        assert blob.read_bytes() == b"cross fs original"
        assert blob.stat().st_dev != src.stat().st_dev
