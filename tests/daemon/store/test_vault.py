"""The originals vault on real files: content addressing, independent copies, byte-exact restore."""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

import daemon.store.vault
from daemon.store.vault import (
    RestoreRefused,
    Vault,
    VaultContentChanged,
    VaultError,
    VaultFullError,
    VaultNoSpaceError,
    open_regular_nofollow,
)
from poisoner.spec import PatchSpec
from testkit.disk_full import MountUnavailable, fill, small_filesystem


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _temporaries(vault: Vault) -> list[Path]:
    return [p for p in vault.vault_dir.iterdir() if p.name.startswith(daemon.store.vault.VAULT_TMP_PREFIX)]


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
    assert blob.stat().st_ino != src.stat().st_ino and blob.stat().st_nlink == 1  # its own copy
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
    assert stat.S_IMODE(vault.path_for(sha).stat().st_mode) == 0o600


@pytest.mark.parametrize("link", [None, True, False])
def test_in_place_edits_of_the_source_never_reach_the_vault(vault: Vault, tmp_path: Path, link: bool) -> None:
    """A writer that still holds the file (same inode) appends and overwrites after the keep:
    the blob keeps the bytes that were kept, whatever the old `link` argument says."""
    data = os.urandom(300_000)
    src = tmp_path / "a.png"
    src.write_bytes(data)
    inode = src.stat().st_ino
    sha = vault.keep(src) if link is None else vault.keep(src, link=link)
    with open(src, "r+b") as fh:
        fh.seek(0, os.SEEK_END)
        fh.write(b"the rest of a stalled writer's bytes" * 100)
        fh.seek(0)
        fh.write(b"EDITED!!")
    assert src.stat().st_ino == inode
    blob = vault.path_for(sha)
    assert blob.read_bytes() == data and vault.verify(sha)
    assert blob.stat().st_nlink == 1
    vault.restore(sha, tmp_path / "back.png")
    assert (tmp_path / "back.png").read_bytes() == data


def test_symlink_is_refused_and_nothing_kept(vault: Vault, tmp_path: Path) -> None:
    private = tmp_path / "private.jpg"
    private.write_bytes(b"someone's private photo")
    link = tmp_path / "a.jpg"
    link.symlink_to(private)
    with pytest.raises(VaultError, match="symbolic link"):
        vault.keep(link)
    assert vault.is_empty() and vault.blobs() == []
    assert _temporaries(vault) == []


def test_fifo_is_refused_without_blocking(vault: Vault, tmp_path: Path) -> None:
    fifo = tmp_path / "a.jpg"
    os.mkfifo(fifo)
    with pytest.raises(VaultError, match="not a regular file"):
        vault.keep(fifo)


def test_keep_fd_refuses_what_is_not_a_regular_file(vault: Vault) -> None:
    read_end, write_end = os.pipe()
    try:
        os.write(write_end, b"bytes from a pipe")
        with pytest.raises(VaultError, match="regular files"):
            vault.keep_fd(read_end)
    finally:
        os.close(read_end)
        os.close(write_end)
    assert vault.blobs() == [] and _temporaries(vault) == []


def test_keep_fd_verifies_the_expected_hash(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"what the caller hashed")
    expected = _sha(b"what the caller hashed")
    with open(src, "r+b") as fh:
        fh.write(b"WHAT")  # changed after hashing
        fh.flush()
        with pytest.raises(VaultContentChanged, match="changed while being kept"):
            vault.keep_fd(fh.fileno(), expected)
    assert vault.blobs() == []
    assert _temporaries(vault) == []
    assert vault.keep(src, expected_sha256=_sha(src.read_bytes())) == _sha(src.read_bytes())


def test_keep_fd_leaves_the_callers_offset_alone(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"0123456789" * 1000)
    fd = open_regular_nofollow(src)
    try:
        os.lseek(fd, 1234, os.SEEK_SET)
        sha = vault.keep_fd(fd)
        assert os.lseek(fd, 0, os.SEEK_CUR) == 1234
    finally:
        os.close(fd)
    assert vault.path_for(sha).read_bytes() == src.read_bytes()


def test_the_read_loop_copy_is_identical_independent_and_hashed_as_copied(tmp_path: Path) -> None:
    """_copy_fd's copy where there is no reflink (this filesystem): one pass, hashed as it copies."""
    data = os.urandom(3 * daemon.store.vault.CHUNK + 12345)
    src, dst = tmp_path / "src", tmp_path / "dst"
    src.write_bytes(data)
    src_fd = os.open(src, os.O_RDONLY)
    dst_fd = os.open(dst, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        method, sha = daemon.store.vault._copy_fd(src_fd, dst_fd)
    finally:
        os.close(src_fd)
        os.close(dst_fd)
    assert (method, sha) == ("read", _sha(data))
    assert dst.read_bytes() == data and dst.stat().st_ino != src.stat().st_ino


def test_keep_bytes_writes_what_the_caller_hashed_and_nothing_twice(vault: Vault) -> None:
    data = os.urandom(100_000)
    sha = vault.keep_bytes(data, _sha(data))
    blob = vault.path_for(sha)
    assert sha == _sha(data) and blob.read_bytes() == data and blob.stat().st_mode & 0o777 == 0o600
    inode = blob.stat().st_ino
    assert vault.keep_bytes(data, sha) == sha and blob.stat().st_ino == inode  # already kept: no new copy
    assert _temporaries(vault) == []


def test_keep_fd_with_the_expected_hash_skips_content_already_kept(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"kept once")
    sha = vault.keep(src)
    inode = vault.path_for(sha).stat().st_ino
    assert vault.keep(src, expected_sha256=sha) == sha
    assert vault.path_for(sha).stat().st_ino == inode


def test_a_blob_of_the_wrong_size_is_not_taken_as_kept(vault: Vault) -> None:
    """A blob at the hash's name with another size (not written by a keep) is replaced, not trusted."""
    data = b"the real original"
    sha = _sha(data)
    blob = vault.path_for(sha)
    blob.parent.mkdir(mode=0o700, exist_ok=True)
    blob.write_bytes(b"short")
    assert vault.keep_bytes(data, sha) == sha and blob.read_bytes() == data


def test_an_old_hard_linked_blob_is_replaced_by_an_own_copy(vault: Vault, tmp_path: Path) -> None:
    """A blob an older ppd kept by hard link is still the user's inode: keeping that content
    again makes the vault's copy independent."""
    src = tmp_path / "a.png"
    src.write_bytes(b"kept by an older ppd")
    sha = _sha(src.read_bytes())
    vault.path_for(sha).parent.mkdir(parents=True)
    os.link(src, vault.path_for(sha))
    assert vault.keep(src) == sha
    assert vault.path_for(sha).stat().st_nlink == 1
    src.write_bytes(b"edited later")  # write_bytes truncates in place: same inode
    assert vault.verify(sha)


def test_full_vault_filesystem_names_the_filesystem(tmp_path: Path) -> None:
    """A real 1 MiB tmpfs filled to the last block: the error says which filesystem is full and
    how many bytes are free, keeps the no-space text the daemon retries on, leaves nothing."""
    src = tmp_path / "a.png"
    src.write_bytes(os.urandom(200_000))
    before = src.read_bytes()
    try:
        with small_filesystem(tmp_path / "small", size="1m") as fs:
            vault = Vault(fs / "vault")
            fill(fs)
            with pytest.raises(VaultNoSpaceError) as caught:
                vault.keep(src)
            message = str(caught.value)
            leftovers = _temporaries(vault)
            assert vault.blobs() == []
    except MountUnavailable as exc:
        pytest.skip(f"cannot mount a tmpfs here: {exc}")
    assert caught.value.errno == errno.ENOSPC and isinstance(caught.value, VaultFullError)
    assert "\n" not in message and os.strerror(errno.ENOSPC) in message
    assert f"tmpfs filesystem mounted at {fs}" in message and " bytes free" in message
    assert f"needs {len(before)} bytes" in message
    assert leftovers == [] and src.read_bytes() == before


def test_specs_are_kept_and_loaded_by_id(vault: Vault) -> None:
    spec = PatchSpec(seed=7)
    path = vault.keep_spec(spec)
    assert path == vault.vault_dir / "specs" / f"{spec.spec_id}.json"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert vault.load_spec(spec.spec_id) == spec
    assert vault.load_spec(PatchSpec(seed=8).spec_id) is None
    path.write_text(PatchSpec(seed=9).to_json())  # a file that does not match its name
    assert vault.load_spec(spec.spec_id) is None
    assert vault.blobs() == [] and vault.usage_bytes() == 0  # specs are not originals


def test_a_symlinked_blob_is_not_restored(vault: Vault, tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    outside.write_bytes(b"x")
    sha = _sha(b"x")
    vault.path_for(sha).parent.mkdir(parents=True)
    vault.path_for(sha).symlink_to(outside)
    with pytest.raises(VaultError, match="symbolic link"):
        vault.restore(sha, tmp_path / "dst")
    assert not (tmp_path / "dst").exists()


def test_same_content_is_kept_once(vault: Vault, tmp_path: Path) -> None:
    for name in ("a.png", "b.png"):
        (tmp_path / name).write_bytes(b"same bytes")
    assert vault.keep(tmp_path / "a.png") == vault.keep(tmp_path / "b.png")
    assert len(list(vault.vault_dir.glob("??/*"))) == 1
    assert not list(vault.vault_dir.glob(".keep-*"))  # no temporaries left


def test_restore_keeps_destination_mode(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"original")
    sha = vault.keep(src)
    dst = tmp_path / "dst.png"
    dst.write_bytes(b"poisoned")
    os.chmod(dst, 0o640)
    vault.restore(sha, dst)
    assert dst.read_bytes() == b"original"
    assert stat.S_IMODE(dst.stat().st_mode) == 0o640


def test_corrupt_blob_is_not_restored(vault: Vault, tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    src.write_bytes(b"original")
    sha = vault.keep(src)
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


@pytest.fixture
def btrfs(tmp_path: Path) -> Iterator[Path]:
    """A real btrfs (copy-on-write, reflinks) on a loop device; skipped where one cannot be made."""
    if shutil.which("mkfs.btrfs") is None:
        pytest.skip("mkfs.btrfs is not installed (btrfs-progs)")
    image, mount_point = tmp_path / "btrfs.img", tmp_path / "btrfs"
    with open(image, "wb") as fh:
        fh.truncate(128 << 20)  # sparse
    mount_point.mkdir()
    made = subprocess.run(["mkfs.btrfs", "-q", str(image)], capture_output=True, text=True)
    mounted = made.returncode == 0 and subprocess.run(
        ["mount", "-o", "loop", str(image), str(mount_point)], capture_output=True, text=True
    ).returncode == 0  # fmt: skip
    if not mounted:
        pytest.skip(f"cannot make and mount a btrfs here: {made.stderr.strip() or 'mount refused'}")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=False)


def test_reflink_where_the_filesystem_shares_extents(btrfs: Path) -> None:
    """On btrfs the copy is a reflink (no bytes copied), and still independent: copy-on-write."""
    data = os.urandom(2_000_000)
    src = btrfs / "a.png"
    src.write_bytes(data)
    src_fd = os.open(src, os.O_RDONLY)
    dst_fd = os.open(btrfs / "clone", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        assert daemon.store.vault._copy_fd(src_fd, dst_fd) == ("reflink", _sha(data))
    finally:
        os.close(src_fd)
        os.close(dst_fd)
    vault = Vault(btrfs / "vault")
    sha = vault.keep(src, expected_sha256=_sha(data))
    with open(src, "r+b") as fh:  # the writer goes on, in place
        fh.seek(0, os.SEEK_END)
        fh.write(b"more")
        fh.seek(1000)
        fh.write(b"EDIT")
    assert vault.path_for(sha).read_bytes() == data and vault.verify(sha)
    assert vault.path_for(sha).stat().st_ino != src.stat().st_ino


def test_restore_replaces_only_what_it_may(vault: Vault, tmp_path: Path) -> None:
    """Issue 29: the check runs just before the rename; bytes ppd did not write are never replaced
    unless the caller says so (--force)."""
    src = tmp_path / "a.bin"
    src.write_bytes(b"original")
    sha = vault.keep(src)
    patched = hashlib.sha256(b"patched").hexdigest()
    src.write_bytes(b"the user's edit")
    with pytest.raises(RestoreRefused):
        vault.restore(sha, src, replaces=patched)
    with pytest.raises(RestoreRefused):
        vault.restore(sha, src, replaces=None)
    assert src.read_bytes() == b"the user's edit"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "vault"]  # no temporary left
    src.write_bytes(b"patched")
    vault.restore(sha, src, replaces=patched)
    assert src.read_bytes() == b"original"
    src.write_bytes(b"anything")
    vault.restore(sha, src)  # force
    assert src.read_bytes() == b"original"
    src.unlink()
    vault.restore(sha, src, replaces=patched)  # nothing at the name: nothing overwritten
    assert src.read_bytes() == b"original"


def test_partial_copies_of_a_killed_keep_are_cleaned_and_counted(tmp_path: Path) -> None:
    """Issue 29: a SIGKILLed keep left a `.keep-*` partial original that no start removed and
    max_bytes did not count. Now: counted while there, removed at the next start unless a living
    process holds it (a keep in progress), never touching kept originals."""
    import time

    folder = tmp_path / "vault"
    vault = Vault(folder, max_bytes=3_000_000)
    src = tmp_path / "a.bin"
    src.write_bytes(b"x" * 1000)
    sha = vault.keep(src)
    stale = folder / f"{daemon.store.vault.VAULT_TMP_PREFIX}dead"
    stale.write_bytes(b"p" * 2_300_000)  # what the killed keep had copied
    live = folder / f"{daemon.store.vault.VAULT_TMP_PREFIX}live"
    live.write_bytes(b"q" * 10)
    old = time.time() - 3600
    for p in (stale, live):
        os.utime(p, (old, old))
    assert vault.usage_bytes() == 1000 + 2_300_000 + 10
    big = tmp_path / "big.bin"
    big.write_bytes(b"y" * 1_000_000)
    with pytest.raises(VaultFullError):  # the partial copy counts against max_bytes
        vault.keep(big)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import fcntl, sys, time; f = open(sys.argv[1]); "
         "fcntl.flock(f, fcntl.LOCK_EX); print('held', flush=True); time.sleep(30)", str(live)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        assert daemon.store.vault.clear_stale_keeps(folder) == [stale]  # at start (Vault() runs it once)
    finally:
        holder.kill()
        holder.wait()
    assert not stale.exists() and live.exists() and vault.verify(sha)



def test_discard_removes_a_blob_and_says_what_it_freed(vault: Vault) -> None:
    data = b"an original to let go"
    sha = vault.keep_bytes(data, hashlib.sha256(data).hexdigest())
    other = vault.keep_bytes(b"x", hashlib.sha256(b"x").hexdigest())
    assert vault.discard(sha) == len(data)
    assert not vault.has(sha) and not vault.path_for(sha).parent.exists() and vault.has(other)
    assert vault.discard(sha) is None  # not here: nothing to say freed
    with pytest.raises(VaultError):
        vault.discard("../../etc")
