"""The installation's seal key: the secret that makes ppd's provenance seal (poisoner.provenance)
readable and makeable by this installation only.

One file, `DATA_DIR/seal.key` (`ppd config path` prints the data folder): 64 hex digits and a
newline, mode 0600, owned by the user. Created on first use, atomically: written and fsynced under
a temporary name, then hard-linked into place (a link never replaces an existing file, so two
processes starting at once end up with the same key, the first one's). The temporary is ppd's
usual one (poisoner.atomic.create_temp_at: `.ppd-tmp-*.seal.key`, flock()ed by its writer until
it is unlinked), so one left by a killed process (a copy of the key) is told from a live writer's
by its lock, not by a PID in its name, and removed by the next ppd (clear_stale_key_temporaries).

Moving to a new machine: copy this file (keeping mode 0600) into the new data folder before ppd
runs there, with the vault (`ppd key export FILE` / `ppd key import FILE` do the same and check
it). Without it, files patched here are no longer recognised as ppd's output once the store is
lost (they would be patched again); with a store, rows still recognise them by hash.

So a key is made on its own only while the vault is empty: with originals in the vault, a missing key
is one that was lost (a black-box review: a silent new key, then every patched file patched again and
its once-marked bytes vaulted as its "original"). Then SealKeyMissing says to import the old key, or
to start a new one knowingly (`ppd key new`, new_key).

A process loads the key once. `ppd key new` and `ppd key import` refuse while another ppd process uses
the data folder, and one whose key file is replaced anyway seals nothing more (check_key_stamp): its
files would be sealed with a key no longer on disk.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import stat
from pathlib import Path

from daemon.paths import VAULT_DIR_NAME, make_private_dir
from daemon.store.damage import vault_holds_originals
from poisoner.atomic import STALE_TEMP_AGE_S, TEMP_PREFIX, create_temp_at, remove_if_stale, remove_if_unlocked
from poisoner.errors import ExitStatus, PpdError
from poisoner.provenance import KEY_BYTES

KEY_FILE = "seal.key"
TEMP_SUFFIX = f".{KEY_FILE}"  # a key being written: .ppd-tmp-L<hex>.seal.key (_place_key)
# An earlier ppd's temporary, .seal.key.PID.RANDOM, unlocked (its liveness was guessed from the PID)
_OLD_TEMP = re.compile(r"\.seal\.key\.\d+\.[0-9a-f]+")
_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC


class SealKeyError(PpdError):
    """The key file exists but cannot be used (wrong mode, owner or content)."""

    exit_status = ExitStatus.ENVIRONMENT


class SealKeyMissing(SealKeyError):
    """No key while the vault holds originals: the key they were sealed with was lost."""


def key_path(data_dir: Path) -> Path:
    return Path(data_dir) / KEY_FILE


def missing_key_message(data_dir: Path) -> str:
    return (
        f"no seal key at {key_path(data_dir)} but the vault holds originals patched with one: "
        "`ppd key import FILE` the key you exported (`ppd key export`); if it is lost for good, "
        "`ppd key new` starts a new one (files patched with the old key are then not recognised)"
    )


def parse_key(text: bytes, where: Path) -> bytes:
    """The key in a key file's content; SealKeyError with one line otherwise."""
    value = text.strip()
    try:
        key = bytes.fromhex(value.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != KEY_BYTES:
        raise SealKeyError(f"{where} is not a ppd seal key ({2 * KEY_BYTES} hex digits expected)")
    return key


KeyStamp = tuple[int, int, int]  # the key file's (st_dev, st_ino, st_mtime_ns): which file, which write


def _stamp(st: os.stat_result) -> KeyStamp:
    return (st.st_dev, st.st_ino, st.st_mtime_ns)


def changed_key_message(path: Path) -> str:
    return (
        f"the seal key {path} was replaced or removed while this ppd ran (`ppd key new` or `key import`); "
        "nothing more is sealed with the one it loaded: run the command again (restart `ppd watch`)"
    )


def check_key_stamp(data_dir: Path, stamp: KeyStamp) -> None:
    """SealKeyError unless the key file is still the one stamped (one stat: a process caches its key,
    and files sealed with a key no longer on disk are not recognised after a store loss)."""
    path = key_path(data_dir)
    try:
        now = _stamp(os.stat(path, follow_symlinks=False))
    except FileNotFoundError:
        now = None
    if now != stamp:
        raise SealKeyError(changed_key_message(path))


def read_key_file(path: Path) -> bytes:
    """The key in path: a regular file (no symlink) owned by this user and readable by nobody else."""
    return read_key_stamped(path)[0]


def read_key_stamped(path: Path) -> tuple[bytes, KeyStamp]:
    """read_key_file, and the stamp of the file the key was read from."""
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.getuid():
            raise SealKeyError(f"{path} is not a regular file owned by this user; not used as the seal key")
        if st.st_mode & 0o077:
            raise SealKeyError(
                f"{path} is readable by others (mode {stat.S_IMODE(st.st_mode):o}); `chmod 600` it to use it"
            )
        return parse_key(os.read(fd, 4096), path), _stamp(st)
    finally:
        os.close(fd)


def load_key(data_dir: Path, *, create: bool = True) -> bytes | None:
    """This installation's key, created on first use when create (else None when there is none).
    Never created beside a vault that holds originals (SealKeyMissing): new_key does that, asked."""
    if not create:
        clear_stale_key_temporaries(data_dir)  # load_key_stamped does it on the other path
        with contextlib.suppress(FileNotFoundError):
            return read_key_file(key_path(data_dir))
        return None
    return load_key_stamped(data_dir)[0]


def load_key_stamped(data_dir: Path) -> tuple[bytes, KeyStamp]:
    """load_key (created on first use), and its file's stamp (check_key_stamp)."""
    path = key_path(data_dir)
    clear_stale_key_temporaries(data_dir)
    with contextlib.suppress(FileNotFoundError):
        return read_key_stamped(path)
    if vault_holds_originals(Path(data_dir) / VAULT_DIR_NAME):
        raise SealKeyMissing(missing_key_message(data_dir))
    install_key(data_dir, secrets.token_bytes(KEY_BYTES), replace=False)
    return read_key_stamped(path)  # ours, or the one another process linked first


def new_key(data_dir: Path) -> Path:
    """A new key where there is none, whatever the vault holds (`ppd key new`: the user says the old
    one is lost); FileExistsError when there is one, another process's linked meanwhile included (a
    check before the link said "made" for a key that was not this one: a diff review)."""
    return _place_key(data_dir, secrets.token_bytes(KEY_BYTES), replace=False)


def install_key(data_dir: Path, key: bytes, *, replace: bool) -> Path:
    """Write key as the installation's key, atomically, mode 0600. Without replace an existing
    key is kept (and returned as it is)."""
    try:
        return _place_key(data_dir, key, replace=replace)
    except FileExistsError:
        return key_path(data_dir)


def _place_key(data_dir: Path, key: bytes, *, replace: bool) -> Path:
    """install_key; without replace, FileExistsError when a key is there (the link never replaces)."""
    if len(key) != KEY_BYTES:
        raise SealKeyError("a seal key is 32 bytes")
    make_private_dir(Path(data_dir))
    dir_fd = os.open(data_dir, _DIR_FLAGS)
    try:
        _clear_stale_at(dir_fd)
        _write_and_place(dir_fd, key, replace=replace)
        os.fsync(dir_fd)  # the key's name on disk
    finally:
        os.close(dir_fd)
    return key_path(data_dir)


def _write_and_place(dir_fd: int, key: bytes, *, replace: bool) -> None:
    """The key written to a locked temporary, fsynced, then linked (or renamed) to KEY_FILE. The
    temporary is unlinked before its descriptor closes: while its name exists, its lock says a live
    writer holds it (a sweep never takes it for a killed one's)."""
    tmp, fd = create_temp_at(dir_fd, TEMP_SUFFIX)
    named = True  # tmp still names our file (a rename took the name away)
    try:
        os.fchmod(fd, 0o600)  # whatever the umask
        os.write(fd, key.hex().encode() + b"\n")
        os.fsync(fd)
        if replace:
            os.replace(tmp, KEY_FILE, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
            named = False
        else:
            os.link(tmp, KEY_FILE, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    finally:
        if named:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp, dir_fd=dir_fd)
        os.close(fd)


def clear_stale_key_temporaries(data_dir: Path) -> int:
    """Remove the key temporaries in data_dir that no live process holds: one killed between writing its
    key there and unlinking it left a copy of the secret key in the data folder for good (a diff
    review). A live writer's is locked: left. How many were removed."""
    try:
        dir_fd = os.open(data_dir, _DIR_FLAGS)
    except OSError:
        return 0  # no data folder yet (or none to read): the command that needs it says so
    try:
        return _clear_stale_at(dir_fd)
    except OSError:
        return 0  # housekeeping: the next command tries again
    finally:
        os.close(dir_fd)


def _clear_stale_at(dir_fd: int) -> int:
    """clear_stale_key_temporaries in the open data folder. An earlier ppd's `.seal.key.PID.RANDOM` is
    not locked by its writer: it goes once no one holds it and it is STALE_TEMP_AGE_S old (such a
    writer, mid-upgrade, takes it away within milliseconds), whatever process has that PID now."""
    removed = 0
    for name in os.listdir(dir_fd):
        if name.startswith(TEMP_PREFIX) and name.endswith(TEMP_SUFFIX):
            removed += remove_if_stale(dir_fd, name)
        elif _OLD_TEMP.fullmatch(name):
            removed += remove_if_unlocked(dir_fd, name, min_age_s=STALE_TEMP_AGE_S)
    return removed
