"""The originals vault: every original ppd poisons is kept here first, content-addressed.

Layout: vault_dir/ab/abcdef... (sha256 of the content, no suffix), folders mode 0700.

Keeping is by hard link when the vault shares the original's filesystem: no copy, and because
the outbox file is later *replaced* (rename of a new inode), the old inode lives on in the
vault. The outbox path therefore always holds the original or the complete poisoned file,
never nothing. Across filesystems the original is copied and fsynced before it counts as kept.

Blobs are never deleted implicitly. An optional size limit makes `keep` refuse (VaultFullError),
so a full vault stops protection instead of losing originals.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import logging
import os
import shutil
import tempfile
from pathlib import Path

from daemon.paths import make_private_dir
from poisoner.atomic import atomic_output, fsync_dir

log = logging.getLogger(__name__)

CHUNK = 1 << 20
VAULT_TMP_PREFIX = ".keep-"


class VaultError(RuntimeError):
    """A vault operation failed (message = one line)."""


class VaultFullError(VaultError):
    """Keeping another original would exceed the configured vault size limit."""


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


class Vault:
    def __init__(self, vault_dir: Path, max_bytes: int = 0) -> None:
        self.vault_dir = Path(vault_dir)
        self.max_bytes = max_bytes  # 0 = unlimited
        make_private_dir(self.vault_dir)

    def path_for(self, sha256: str) -> Path:
        if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
            raise VaultError(f"not a sha256 hex digest: {sha256!r}")
        return self.vault_dir / sha256[:2] / sha256

    def has(self, sha256: str) -> bool:
        return self.path_for(sha256).is_file()

    def keep(self, path: Path, *, link: bool = True) -> str:
        """Keep the content of path; returns its sha256.

        link=False forces a copy: use it when the original stays in place (`ppd poison --out`),
        where a later in-place edit of a hard-linked original would change the vault blob too.

        The hash is taken of what was actually kept (the linked inode or the copy), so the
        returned digest always names the vault blob's true content even if path changes.
        """
        path = Path(path)
        fd, tmp_name = tempfile.mkstemp(prefix=VAULT_TMP_PREFIX, dir=self.vault_dir)
        os.close(fd)
        tmp = Path(tmp_name)
        try:
            linked = self._link_or_copy(path, tmp, link)
            sha = sha256_file(tmp)
            final = self.path_for(sha)
            if final.exists():
                return sha  # the same content is already kept (content addressing)
            self._check_room(tmp.stat().st_size)
            make_private_dir(final.parent)
            os.replace(tmp, final)
            fsync_dir(final.parent)
            log.debug("vault kept", extra={"sha256": sha, "src": str(path), "hard_link": linked})
            return sha
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()

    def _link_or_copy(self, src: Path, tmp: Path, link: bool) -> bool:
        """Put src's content at tmp: hard link if possible (True), else an fsynced copy."""
        tmp.unlink()
        if link:
            try:
                os.link(src, tmp, follow_symlinks=False)
                return True
            except OSError as exc:
                if exc.errno not in (errno.EXDEV, errno.EPERM, errno.EMLINK, errno.ENOTSUP, errno.EACCES):
                    raise
        with open(src, "rb") as fin, open(tmp, "xb") as fout:
            shutil.copyfileobj(fin, fout, CHUNK)
            fout.flush()
            os.fsync(fout.fileno())
        os.chmod(tmp, 0o600)
        return False

    def _check_room(self, size: int) -> None:
        if not self.max_bytes:
            return
        used = self.usage_bytes()
        if used + size > self.max_bytes:
            raise VaultFullError(
                f"vault {self.vault_dir} holds {used} bytes; keeping {size} more would pass its limit of "
                f"{self.max_bytes} (raise [vault] max_bytes; ppd never deletes originals on its own)"
            )

    def usage_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.vault_dir.glob("??/*") if p.is_file())

    def verify(self, sha256: str) -> bool:
        """Whether the blob still has the content its name says (a hard-linked original edited
        in place before it was replaced would not)."""
        path = self.path_for(sha256)
        return path.is_file() and sha256_file(path) == sha256

    def restore(self, sha256: str, dst: Path) -> None:
        """Atomically put the original with this digest at dst (a copy, never a link: edits to
        the restored file must not reach the vault)."""
        src = self.path_for(sha256)
        if not src.is_file():
            raise VaultError(f"original {sha256[:12]} is not in the vault {self.vault_dir}")
        dst = Path(dst)
        with atomic_output(dst, mode_like=dst if dst.exists() else None) as tmp:
            digest = hashlib.sha256()
            with open(src, "rb") as fin, open(tmp, "wb") as fout:
                while chunk := fin.read(CHUNK):
                    digest.update(chunk)
                    fout.write(chunk)
            if digest.hexdigest() != sha256:
                raise VaultError(f"vault blob {sha256[:12]} is corrupt (content changed); not restoring it")
