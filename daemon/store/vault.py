"""The originals vault: every original ppd patches is kept here first, content-addressed.

Layout: vault_dir/ab/abcdef... (sha256 of the content, no suffix), folders mode 0700; the specs
that patched them under vault_dir/specs/<spec_id>.json (so a lost store can be rebuilt).

The vault owns its bytes: each original is an independent copy, never a hard link to a file the
user (or a writer that still holds it open) can change. The copy is a reflink (FICLONE) where
the filesystem shares extents copy-on-write (btrfs, XFS, bcachefs: no extra disk), else a read
loop that hashes while it copies; `keep_bytes` writes bytes the caller read and hashed once
(the protect stages: the original is read once for its hash and its copy). It is written under a
temporary name, fsynced, and renamed into place; the folder is fsynced. The blob's name is
therefore always the hash of its content. Content already kept (same hash and size, the vault's
own inode) is not copied again.

Blobs are never deleted implicitly: only `ppd dataset forget` removes one, once no row of the store
names it (daemon.protect.forgetting). An optional size limit makes `keep` refuse (VaultFullError),
so a full vault stops protection instead of losing originals; a full filesystem gives a
VaultNoSpaceError that names the filesystem and its free bytes.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import logging
import os
import shutil
import stat
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

from daemon.fsops import clear_stale_temps_once, sha256_fd
from daemon.paths import filesystem_of, make_private_dir
from daemon.platform import reflink
from poisoner.atomic import atomic_output, atomic_write_text, fsync_dir
from poisoner.errors import ExitStatus, PpdError
from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

CHUNK = 1 << 20
VAULT_TMP_PREFIX = ".keep-"
SPECS_DIR = "specs"
NO_SPACE = frozenset({errno.ENOSPC, errno.EDQUOT})


class VaultError(PpdError, RuntimeError):
    """A vault operation failed (message = one line)."""

    exit_status = ExitStatus.ENVIRONMENT


class VaultFullError(VaultError):
    """Keeping another original would exceed the configured vault size limit."""


class VaultNoSpaceError(VaultFullError):
    """The vault's filesystem is full; the message names it and its free bytes."""

    def __init__(self, message: str, errno_: int) -> None:
        super().__init__(message)
        self.errno = errno_


class VaultContentChanged(VaultError):
    """What was read is not what the caller hashed: the file changed; nothing was kept."""


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def open_regular_nofollow(path: Path) -> int:
    """An fd of path for reading; refuses a symlink (O_NOFOLLOW) and anything not a regular file
    (O_NONBLOCK so a FIFO cannot block the open)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise VaultError(f"{path} is a symbolic link; ppd keeps only regular files") from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise VaultError(f"{path} is not a regular file; ppd keeps only regular files")
    return fd


STALE_KEEP_S = 10.0  # a `.keep-*` copy younger than this may be between its creation and its lock
_cleared: set[Path] = set()


def clear_stale_keeps(vault_dir: Path, min_age_s: float = STALE_KEEP_S) -> list[Path]:
    """Remove `.keep-*` partial copies no living process holds (each copy is flock()ed while it is
    written): what a SIGKILLed keep leaves behind. Younger than min_age_s: left alone."""
    removed = []
    for tmp in Path(vault_dir).glob(f"{VAULT_TMP_PREFIX}*"):
        try:
            if time.time() - tmp.lstat().st_mtime < min_age_s:
                continue
            fd = os.open(tmp, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            continue  # a keep in progress
        else:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            removed.append(tmp)
        finally:
            os.close(fd)
    if removed:
        log.warning("removed %d partial vault copies left by a killed process", len(removed))
    return removed


WORK_PREFIX = ".work-"  # a protect's scratch folder in the vault (daemon.protect.poisoning.work_folder)
WORK_LOCK = ".lock"  # in each: flock()ed by the process using the folder, for as long as it does
NAMED_PREFIX = ".named-"  # what ppd before issue 30 called its named copies (no lock): swept alike


def clear_stale_work_folders(vault_dir: Path, min_age_s: float = STALE_KEEP_S) -> list[Path]:
    """Remove `.work-*` folders no living process holds (their lock is free) and at least min_age_s
    old (the instant between a folder's creation and its lock): a killed protect's patched copy and
    hard link to its original, up to twice a large file's size."""
    removed = []
    folders = [*Path(vault_dir).glob(f"{WORK_PREFIX}*"), *Path(vault_dir).glob(f"{NAMED_PREFIX}*")]
    for folder in folders:
        try:
            if time.time() - folder.lstat().st_mtime < min_age_s or folder.is_symlink():
                continue
            fd = os.open(folder / WORK_LOCK, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            continue
        finally:
            os.close(fd)
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    if removed:
        log.warning("removed %d scratch folders left in the vault by a killed process", len(removed))
    return removed


def blob_path(vault_dir: Path, sha256: str) -> Path:
    """Where the vault in vault_dir keeps the original with this digest (no Vault made: that creates
    and sweeps the folder, which a check must not)."""
    if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
        raise VaultError(f"not a sha256 hex digest: {sha256!r}")
    return Path(vault_dir) / sha256[:2] / sha256


# A file that failed on [vault] max_bytes says so, then the limit in bytes (`ppd status` counts them)
LIMIT_WORDS = "would pass its limit of"


def limit_message(vault_dir: Path, used: int, size: int, limit: int, config_file: Path | None) -> str:
    """VaultFullError's line for the size limit, with the whole way out: the limit is read at start, so a
    running `ppd watch` kept failing after the user raised it as told, and nothing said to restart it,
    nor that forgetting a finished shoot frees room (a black-box review)."""
    where = config_file or "config.toml"
    return (
        f"vault {vault_dir} holds {used} bytes; keeping {size} more {LIMIT_WORDS} {limit} bytes: raise "
        f"[vault] max_bytes in {where} and restart ppd watch (`systemctl --user restart ppd` for the "
        "service), or `ppd dataset forget` a finished shoot (ppd never deletes originals on its own)"
    )


class Vault:
    def __init__(self, vault_dir: Path, max_bytes: int = 0, config_file: Path | None = None) -> None:
        self.vault_dir = Path(vault_dir)
        self.max_bytes = max_bytes  # 0 = unlimited
        self._specs_kept: set[str] = set()  # spec ids keep_spec found or wrote (in this process)
        self.config_file = config_file  # where max_bytes is set: named when the limit is reached
        make_private_dir(self.vault_dir)
        if self.vault_dir not in _cleared:  # once per process: what a killed keep or protect left
            _cleared.add(self.vault_dir)
            clear_stale_keeps(self.vault_dir)
            clear_stale_work_folders(self.vault_dir)

    def path_for(self, sha256: str) -> Path:
        return blob_path(self.vault_dir, sha256)

    def has(self, sha256: str) -> bool:
        return self.path_for(sha256).is_file()

    def blobs(self) -> list[str]:
        """The sha256 of every kept original (by name)."""
        return sorted(p.name for p in self.vault_dir.glob("??/*") if len(p.name) == 64 and p.is_file())

    def is_empty(self) -> bool:
        return not any(len(p.name) == 64 for p in self.vault_dir.glob("??/*"))

    # ---- keeping ------------------------------------------------------------------------------
    def keep(self, path: Path, *, link: bool | None = None, expected_sha256: str | None = None) -> str:
        """Keep the content of the regular file at path (never through a symlink); its sha256.

        `link` is accepted for older callers and ignored: the vault always holds its own copy."""
        del link
        fd = open_regular_nofollow(Path(path))
        try:
            return self.keep_fd(fd, expected_sha256)
        finally:
            os.close(fd)

    def keep_fd(self, fd: int, expected_sha256: str | None = None) -> str:
        """Keep an independent copy of the open file's content; returns its sha256.

        The copy is a reflink where possible (then hashed as kept: no byte passed through here),
        else a read loop that hashes each chunk as it writes it (one pass over the bytes). With
        expected_sha256, content already kept is not copied again, and a copy whose hash differs
        (the file changed since the caller hashed it) is dropped and VaultContentChanged is
        raised. The fd's offset is not moved."""
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise VaultError("ppd keeps only regular files (this descriptor is not one)")
        if expected_sha256 is not None and self._already_kept(self.path_for(expected_sha256), st.st_size):
            return expected_sha256
        times = (st.st_atime_ns, st.st_mtime_ns)
        return self._keep(st.st_size, lambda tmp_fd: _copy_fd(fd, tmp_fd), expected_sha256, times)

    def keep_bytes(self, data: bytes, sha256: str, times: tuple[int, int] | None = None) -> str:
        """Keep `data`, whose sha256 the caller computed over exactly these bytes (read once through
        the file's descriptor, daemon.protect.stages.hash_original): written, fsynced and renamed
        into place without being read or hashed again. Content already kept is not written again.
        times: the original's (atime, mtime) in ns, which restore gives back."""
        if self._already_kept(self.path_for(sha256), len(data)):
            return sha256

        def fill(tmp_fd: int) -> tuple[str, str]:
            return "bytes", _write_blob(tmp_fd, data, sha256)

        return self._keep(len(data), fill, sha256, times)

    def _keep(
        self, size: int, fill: Callable[[int], tuple[str, str]], expected_sha256: str | None,
        times: tuple[int, int] | None = None,
    ) -> str:  # fmt: skip
        """The crash-safe keep: a flock()ed temporary filled by fill(fd) -> (method, sha256), fsynced
        (its bytes are durable before they have a name), renamed to its content address, and the
        folder fsynced (the name is durable before anyone relies on it; the vault folder too when
        the two-letter folder is new: its own name). times: the blob takes the original's dates
        (restore gives them back), set on the temporary while it is locked, so the name never
        exists without them."""
        self._check_room(size)
        tmp_fd, tmp_name = tempfile.mkstemp(prefix=VAULT_TMP_PREFIX, dir=self.vault_dir)
        fcntl.flock(tmp_fd, fcntl.LOCK_EX)  # held while written: clear_stale_keeps leaves it alone
        tmp = Path(tmp_name)
        try:
            try:
                method, sha = fill(tmp_fd)
                if times is not None:  # on the locked temporary, durable with its bytes: a keep killed
                    with contextlib.suppress(OSError):  # after the rename left the blob dated that
                        os.utime(tmp_fd, ns=times)  # day, and no later keep fixed it (a review)
                os.fsync(tmp_fd)
                if expected_sha256 is not None and sha != expected_sha256:
                    raise VaultContentChanged(
                        f"the file changed while being kept (sha256 {sha[:12]}, "
                        f"expected {expected_sha256[:12]}); nothing kept"
                    )
                final = self.path_for(sha)
                if self._already_kept(final, size):
                    return sha  # the same content is already kept (content addressing)
                new_folder = not final.parent.is_dir()
                make_private_dir(final.parent)
                os.replace(tmp, final)  # still locked: clear_stale_keeps never takes it for a dead one's
            finally:
                os.close(tmp_fd)
            fsync_dir(final.parent)
            if new_folder:  # the two-letter folder's own name, in the vault folder
                fsync_dir(self.vault_dir)
            log.debug("vault kept", extra={"sha256": sha, "method": method})
            return sha
        except OSError as exc:
            if exc.errno in NO_SPACE:
                raise self._no_space(exc, size) from None
            raise
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()

    @staticmethod
    def _already_kept(final: Path, size: int | None = None) -> bool:
        """An existing blob counts only if the vault alone holds it: a blob with other hard links
        (kept by an older ppd) could still be edited through them, so it is replaced by the
        fresh independent copy. size: also the size the content must have (checked before a copy
        is skipped; a blob's name is its hash, written only by a fsynced rename)."""
        try:
            st = os.lstat(final)
        except FileNotFoundError:
            return False
        return stat.S_ISREG(st.st_mode) and st.st_nlink == 1 and (size is None or st.st_size == size)

    def _no_space(self, exc: OSError, size: int, what: str = "this original") -> VaultNoSpaceError:
        try:
            where = filesystem_of(self.vault_dir).describe()
        except OSError:
            where = "filesystem unknown"
        return VaultNoSpaceError(
            f"the vault {self.vault_dir} is full: {exc.strerror} ({where}; "
            f"{what} needs {size} bytes); nothing kept, the file is left as it is",
            exc.errno or errno.ENOSPC,
        )

    def _check_room(self, size: int) -> None:
        if not self.max_bytes:
            return
        used = self.usage_bytes()
        if used + size > self.max_bytes:
            raise VaultFullError(limit_message(self.vault_dir, used, size, self.max_bytes, self.config_file))

    def usage_bytes(self) -> int:
        """Kept originals and partial copies (in progress, or left by a killed process)."""
        kept = sum(p.stat().st_size for p in self.vault_dir.glob("??/*") if p.is_file())
        partial = 0
        for p in self.vault_dir.glob(f"{VAULT_TMP_PREFIX}*"):
            with contextlib.suppress(OSError):
                partial += p.lstat().st_size
        return kept + partial

    # ---- letting go ---------------------------------------------------------------------------
    def discard(self, sha256: str) -> int | None:
        """Remove the original with this digest (`ppd dataset forget`, once no row of the store names
        it: the caller's check, under the store lock held alone); the bytes it freed, None when it was
        not here. The folder is fsynced: a removal said done stays done."""
        path = self.path_for(sha256)
        try:
            size = os.lstat(path).st_size
            os.unlink(path)
        except FileNotFoundError:
            return None
        fsync_dir(path.parent)
        with contextlib.suppress(OSError):  # its two-letter folder, once empty
            path.parent.rmdir()
        return size

    # ---- specs --------------------------------------------------------------------------------
    def spec_path(self, spec_id: str) -> Path:
        if not spec_id or any(c not in "0123456789abcdef" for c in spec_id):
            raise VaultError(f"not a spec id: {spec_id!r}")
        return self.vault_dir / SPECS_DIR / f"{spec_id}.json"

    def keep_spec(self, spec: PatchSpec) -> Path:
        """Keep the spec that patches originals next to them, so a store rebuilt from the vault and the
        files' seals (which name only its id) knows each dataset's patch. Written once per spec id,
        atomic and fsynced like the originals (the file, its folder, the vault folder when `specs` is
        new); later calls cost no system call in this process, one stat in the next."""
        path = self.spec_path(spec.spec_id)
        if spec.spec_id in self._specs_kept:
            return path
        if not path.is_file():
            text = spec.to_json()
            new_folder = not path.parent.is_dir()
            try:
                make_private_dir(path.parent)
                atomic_write_text(path, text, mode=0o600)
                if new_folder:  # the specs folder's own name, in the vault folder
                    fsync_dir(self.vault_dir)
            except OSError as exc:
                if exc.errno in NO_SPACE:
                    raise self._no_space(exc, len(text), "its patch spec") from None
                raise
        self._specs_kept.add(spec.spec_id)
        return path

    def load_spec(self, spec_id: str) -> PatchSpec | None:
        """The kept spec with this id; None when it was never kept (or does not match its id)."""
        try:
            spec = PatchSpec.from_json(self.spec_path(spec_id).read_text())
        except (OSError, ValueError, TypeError, KeyError):
            return None
        return spec if spec.spec_id == spec_id else None

    # ---- reading back -------------------------------------------------------------------------
    def verify(self, sha256: str) -> bool:
        """Whether the blob still has the content its name says."""
        path = self.path_for(sha256)
        return path.is_file() and sha256_file(path) == sha256

    def restore(
        self, sha256: str, dst: Path, *, replaces: str | None | Literal[True] = True,
        mtime_ns: int | None = None,
    ) -> None:  # fmt: skip
        """Atomically put the original with this digest at dst: a copy (never a link: edits to
        the restored file must not reach the vault), hash-verified while copying; a blob whose
        content no longer matches its name is refused and dst is left untouched.

        replaces says what dst may hold when the original takes its place, checked just before
        the rename (compare-and-swap): True anything (--force), a sha256 exactly that content (what
        ppd wrote) or nothing, None nothing (dst must not exist). Otherwise RestoreRefused, dst
        untouched. mtime_ns: the original's modification time when the store knows it (a blob
        shared by two files with the same bytes has the first one's), else the blob's."""
        src = self.path_for(sha256)
        try:
            fd = open_regular_nofollow(src)
        except FileNotFoundError:
            raise VaultError(f"original {sha256[:12]} is not in the vault {self.vault_dir}") from None
        dst = Path(dst)
        _clear_stale_temps_beside(dst)  # a restore killed before its rename left a copy of the original
        try:
            expected = None if replaces is True else replaces  # what dst may hold (narrowed for the check)
            check = None if replaces is True else (lambda: _still_holds(dst, expected))
            with atomic_output(dst, mode_like=dst if dst.exists() else None, check=check) as tmp:
                digest = hashlib.sha256()
                offset = 0
                with open(tmp, "wb") as fout:
                    while chunk := os.pread(fd, CHUNK, offset):
                        digest.update(chunk)
                        fout.write(chunk)
                        offset += len(chunk)
                if digest.hexdigest() != sha256:
                    raise VaultError(
                        f"vault blob {sha256[:12]} is corrupt (content changed); not restoring it"
                    )
                kept = os.fstat(fd)  # the original's dates, as the vault kept them (keep's times)
                os.utime(tmp, ns=(kept.st_atime_ns, kept.st_mtime_ns if mtime_ns is None else mtime_ns))
        finally:
            os.close(fd)


def _clear_stale_temps_beside(dst: Path) -> None:
    """ppd's stale temporaries in dst's folder, removed once per process: a restore killed before its
    rename leaves a hidden copy of the original there, where the folder is published (a black-box
    review: only the next `ppd poison` removed it)."""
    try:
        dir_fd = os.open(dst.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        return
    try:
        clear_stale_temps_once(dir_fd)
    finally:
        os.close(dir_fd)


class RestoreRefused(VaultError):
    """dst no longer holds what restore may replace (another writer's bytes)."""

    exit_status = ExitStatus.FAILED


def _still_holds(dst: Path, expected: str | None) -> None:
    """Raise RestoreRefused unless dst is absent or holds exactly expected (None: absent only)."""
    try:
        fd = os.open(dst, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        return  # nobody's bytes at that name: nothing is overwritten
    except OSError as exc:
        raise RestoreRefused(f"{dst.name} cannot be checked ({exc.strerror}); not overwriting it") from None
    try:
        if expected is None:
            raise RestoreRefused(f"{dst} exists; not overwriting it with the original (use --force)")
        if sha256_fd(fd) != expected:
            raise RestoreRefused(f"{dst.name} changed since ppd patched it; not overwriting (use --force)")
    finally:
        os.close(fd)


def _copy_fd(src: int, dst: int) -> tuple[str, str]:
    """Copy src's whole content into the empty file dst; (method, sha256 of what dst holds).

    A reflink first (no bytes copied where the filesystem shares extents; dst is then hashed:
    what is hashed is what was kept), else a read loop that hashes each chunk as it writes it:
    one pass over the bytes. (A kernel copy, copy_file_range, would need a second pass to hash
    what it wrote: not cheaper where the vault must know the hash.)"""
    with contextlib.suppress(OSError):
        reflink(dst, src)
        return "reflink", sha256_fd(dst)
    # A failed clone leaves dst empty; anything else is a real error and will surface below.
    os.ftruncate(dst, 0)
    digest = hashlib.sha256()
    _read_loop(src, dst, 0, digest)
    return "read", digest.hexdigest()


def _write_blob(fd: int, data: bytes, sha256: str) -> str:
    """Write data (already hashed by the caller: sha256) into the empty file fd; sha256."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]
    return sha256


def _read_loop(src: int, dst: int, offset: int, digest: Any) -> None:
    os.lseek(dst, offset, os.SEEK_SET)
    while chunk := os.pread(src, CHUNK, offset):
        if digest is not None:
            digest.update(chunk)
        view = memoryview(chunk)
        while view:
            view = view[os.write(dst, view) :]
        offset += len(chunk)
