"""One owner per outbox and per file, across processes (`ppd watch`, `ppd poison`, `ppd restore`).

Both are advisory fcntl.flock locks on small files in ppd's private data folder (never in the
user's folders): the kernel drops them when the holding process dies, so a crash never leaves a
lock behind. The holder writes its pid into the file, so a refusal can say who holds it.

- `outbox_lock`: one `ppd watch` per outbox, none on a folder above or inside a watched one; a second
  gets LockHeld at once.
- `file_lock`: one process (and one thread) at a time works on a given path; others wait up to
  a bound, then get LockHeld (or WaitLeft, once their caller stops: the file is the holder's).
  flock locks belong to an open file description, so two threads of one process that each open
  the lock file exclude each other too. Its lock file goes when the work is done (see `_flock`).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from daemon.paths import SERVICE_UNIT, make_private_dir, user_unit_dir
from poisoner.errors import ExitStatus, PpdError

log = logging.getLogger(__name__)

DEFAULT_FILE_WAIT_S = 600.0  # a video can take minutes; the waiter then finds ppd's output ("unchanged")
_POLL_S = 0.05
# A wait for another process's file lock longer than this is said (`ppd poison` meeting a 4K clip `ppd
# watch` is encoding waited in silence, up to DEFAULT_FILE_WAIT_S: a black-box review).
WAIT_NOTICE_S = 2.0


class LockHeld(PpdError, RuntimeError):
    """Another process holds the lock (message: one line naming its pid)."""

    exit_status = ExitStatus.ENVIRONMENT


class WaitLeft(PpdError):
    """The waiter's caller stopped (Ctrl-C) while another process held the lock: nothing was done.
    Not a failure: the file is the holder's to finish (`ppd poison` kept waiting for a clip `ppd
    watch` was encoding, saying "stopping after the file in progress": a black-box review)."""

    exit_status = ExitStatus.INTERRUPTED

    def __init__(self, holder: str) -> None:
        super().__init__(f"stopped waiting for another ppd process ({holder}) working on it")
        self.holder = holder


# A stoppable run's files in progress and, of those, the ones waiting for another process's lock
# (a wait its stop ends at once: WaitLeft): [files, waits]. This process's, or shared with its pool's
# workers (share_counts): `ppd poison`'s waits are in its workers, its Ctrl-C handler in the caller,
# which said "stopping after the file in progress" while they only waited (a diff review).
_counts: Any = [0, 0]
_counts_lock: Any = threading.Lock()  # its writers' (a read needs none); a shared one for shared counts
# A worker killed while it held the shared lock would leave it held: the counts only shape a message,
# so a writer that cannot take it in this long leaves them as they are rather than hang its file.
COUNT_LOCK_S = 1.0
_FILES, _WAITS = 0, 1


def waiting_to_leave() -> bool:
    """Whether all the run has in progress is waits for other processes' locks, which its stop ends
    at once: a Ctrl-C then has no file of its own to finish. A plain read of memory: called in a
    signal handler."""
    waits = _counts[_WAITS]
    return waits > 0 and _counts[_FILES] <= waits


def share_counts(counts: Any, lock: Any) -> None:
    """Count into counts (two ints in shared memory, e.g. multiprocessing's RawArray("i", 2)),
    updated under lock: a pool's caller reads what its workers count."""
    global _counts, _counts_lock
    _counts, _counts_lock = counts, lock


@contextlib.contextmanager
def counts_shared(counts: Any, lock: Any) -> Iterator[None]:
    """share_counts for the block; this process's own counts again after it."""
    before = (_counts, _counts_lock)
    share_counts(counts, lock)
    try:
        yield
    finally:
        share_counts(*before)


def _count(which: int, by: int) -> None:
    if not _counts_lock.acquire(timeout=COUNT_LOCK_S):
        return
    try:
        _counts[which] += by
    finally:
        _counts_lock.release()


@contextlib.contextmanager
def file_in_progress() -> Iterator[None]:
    """One file of the run in progress (waiting_to_leave), its waits for a lock counted apart."""
    _count(_FILES, 1)
    try:
        yield
    finally:
        _count(_FILES, -1)


def lock_dir(data_dir: Path) -> Path:
    folder = Path(data_dir) / "locks"
    make_private_dir(folder)
    return folder


def _key(path: Path) -> str:
    return hashlib.sha256(os.fsencode(str(Path(path).absolute()))).hexdigest()[:32]


def _content(fd: int) -> list[str]:
    """The holder's lines: its pid, then (a `ppd watch`) the outbox it watches."""
    try:
        return os.pread(fd, 4096, 0).decode("utf-8", "surrogateescape").splitlines()
    except OSError:
        return []


def _holder(fd: int) -> str:
    text = (_content(fd) or [""])[0].strip()
    return f"pid {text}" if text.isdigit() else "another process"


def _write_pid(fd: int, note: str = "") -> None:
    """Best effort: on a full disk the lock still holds, only the refusal cannot name the pid."""
    with contextlib.suppress(OSError):
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n{note}".encode("utf-8", "surrogateescape"), 0)


@contextlib.contextmanager
def _flock(
    lock_file: Path, wait_s: float, refusal: Callable[[str], str], note: str = "", remove: bool = False,
    waiting: Callable[[str], None] | None = None, give_up: Callable[[], bool] | None = None,
) -> Iterator[None]:
    """refusal(holder): the one-line message when the wait runs out. note: written after the pid.
    give_up(): once true, a wait for another holder ends with WaitLeft.

    remove: the lock file is unlinked when the work is done, while still locked (a lock file per
    path ever processed piled up: a black-box review). Safe because a lock counts only on the file
    the name holds: one who opened it before the unlink and got the lock after finds the name gone
    or another file there, and tries the name again; and no one unlinks a file without its lock."""
    deadline = time.monotonic() + wait_s
    while True:
        fd = os.open(lock_file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
        try:
            _lock_by(fd, deadline, refusal, waiting=waiting, give_up=give_up)
        except BaseException:
            os.close(fd)
            raise
        waiting = None  # said once for the whole wait
        if not remove or _names(lock_file, fd):
            break
        os.close(fd)  # unlinked by its last holder while this one waited: the name's file now
    try:
        _write_pid(fd, note)
        try:
            yield
        finally:
            if remove:
                with contextlib.suppress(OSError):
                    os.unlink(lock_file)
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _lock_by(
    fd: int, deadline: float, refusal: Callable[[str], str], mode: int = fcntl.LOCK_EX,
    waiting: Callable[[str], None] | None = None, give_up: Callable[[], bool] | None = None,
) -> None:  # fmt: skip
    """waiting(holder): said once, after WAIT_NOTICE_S, of a wait that goes on. give_up(): polled
    with the lock; once true, WaitLeft (the wait was for another process's work, none of ours)."""
    notice = time.monotonic() + WAIT_NOTICE_S
    counted = give_up is not None  # a wait its caller's stop ends (waiting_to_leave)
    if counted:
        _count(_WAITS, 1)
    try:
        while True:
            try:
                fcntl.flock(fd, mode | fcntl.LOCK_NB)
                return
            except BlockingIOError:
                now = time.monotonic()
                if give_up is not None and give_up():
                    raise WaitLeft(_holder(fd)) from None
                if now >= deadline:
                    raise LockHeld(refusal(_holder(fd))) from None
                if waiting is not None and now >= notice:
                    waiting(_holder(fd))
                    waiting = None
                time.sleep(_POLL_S)
    finally:
        if counted:
            _count(_WAITS, -1)


def _names(lock_file: Path, fd: int) -> bool:
    """Whether lock_file still names the file open as fd."""
    try:
        st = os.stat(lock_file, follow_symlinks=False)
    except FileNotFoundError:
        return False
    held = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (held.st_dev, held.st_ino)


def _outbox_key(outbox: Path) -> str:
    """The outbox folder itself: its device and inode (a symlink or another spelling of the path
    is the same outbox); its path only while it does not exist yet."""
    try:
        st = os.stat(outbox)
    except OSError:
        return _key(outbox)
    return f"dev{st.st_dev:x}-ino{st.st_ino:x}"


@contextlib.contextmanager
def outbox_lock(data_dir: Path, outbox: Path) -> Iterator[None]:
    """Held for the life of `ppd watch` on outbox; LockHeld at once if another process has it, or
    watches a folder above it or inside it (both would process the same files: a black-box review).

    The outbox's own lock file is held exclusive, with the holder's pid and the outbox in it; the
    lock file of every folder above it (its real path's) is held shared. So a daemon on a folder
    above finds its own lock file held shared (a daemon below) and one on a folder inside finds a
    folder above held exclusive: each is refused by the kernel's lock, two at once included.
    Each lock file goes with its last holder (one per folder up to / stayed after every stop: a
    black-box review), as in _flock; a crash leaves them, and the next run takes the same names."""
    folder = lock_dir(data_dir)
    outbox = Path(outbox).absolute()
    with contextlib.ExitStack() as held:
        for above in Path(os.path.realpath(outbox)).parents:
            held.enter_context(_shared_above(folder / f"watch-{_outbox_key(above)}.lock", above, outbox))
        lock_file = folder / f"watch-{_outbox_key(outbox)}.lock"
        held.enter_context(
            _flock(lock_file, 0.0, lambda h: _refusal(folder, h, outbox), f"{outbox}\n", remove=True)
        )
        yield


# A folder's lock file held exclusive with nothing written in it is its last holder removing it (a
# `ppd watch` stopping, see _unlink_if_last): an instant, waited out up to this long, not refused.
REMOVAL_WAIT_S = 1.0


@contextlib.contextmanager
def _shared_above(lock_file: Path, above: Path, outbox: Path) -> Iterator[None]:
    """A folder above the outbox, held shared: LockHeld when a `ppd watch` watches it."""
    deadline = time.monotonic() + REMOVAL_WAIT_S
    while True:
        fd = os.open(lock_file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            lines, holder = _content(fd), _holder(fd)
            os.close(fd)
            if not lines and time.monotonic() < deadline:
                time.sleep(_POLL_S)
                continue
            watched = lines[1] if len(lines) > 1 else str(above)
            said = f"another ppd watch ({holder}) is already watching {watched}, which holds {outbox}"
            raise LockHeld(said) from None
        if _names(lock_file, fd):
            break
        os.close(fd)  # removed by its last holder meanwhile: the name's file now
    try:
        yield
    finally:
        _unlink_if_last(lock_file, fd)


def _refusal(folder: Path, holder: str, outbox: Path) -> str:
    """Why the outbox's own lock is taken: a daemon on it (its pid in the file), else one on a
    folder inside it (holding it shared: named from its own lock file)."""
    if holder != "another process":
        return f"another ppd watch ({holder}) is already watching {outbox}"
    for lock_file in sorted(folder.glob("watch-*.lock")):
        with contextlib.suppress(OSError):
            fd = os.open(lock_file, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
                lines = []  # not held exclusive: what it says is a dead holder's
            except BlockingIOError:
                lines = _content(fd)
            finally:
                os.close(fd)
            if len(lines) > 1 and Path(lines[1]).is_relative_to(outbox) and Path(lines[1]) != outbox:
                return f"another ppd watch (pid {lines[0]}) is already watching {lines[1]}, inside {outbox}"
    return f"another ppd watch is already watching a folder inside {outbox}"


def watch_running(holder: str, then: str, why: str = "") -> str:
    """The refusal of a command that needs `ppd watch` stopped (holder: watching()'s "pid N"): how to stop
    it, the service's command only where its unit is installed; one run in a terminal (`ppd watch &`) is
    stopped by its pid (a black-box review: `systemctl --user stop ppd` was said with no unit installed)."""
    pid = holder.removeprefix("pid ")
    by_hand = f"Ctrl-C in its terminal, or `kill {pid}`" if pid.isdigit() else "Ctrl-C in its terminal"
    if (user_unit_dir() / SERVICE_UNIT).is_file():
        stop = f"stop it first (`systemctl --user stop ppd`; run in a terminal: {by_hand})"
    else:
        stop = f"stop {holder} first ({by_hand})"
    return f"ppd watch ({holder}) is running on this data folder{why}; {stop}, then {then}"


def watching(data_dir: Path) -> list[str]:
    """Who holds a `ppd watch` lock of this data folder now ("pid N"): daemons using its store."""
    holders = []
    folder = Path(data_dir) / "locks"
    for lock_file in sorted(folder.glob("watch-*.lock")) if folder.is_dir() else []:
        try:
            fd = os.open(lock_file, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            fcntl.flock(fd, fcntl.LOCK_UN)
        except BlockingIOError:
            holders.append(_holder(fd))
        finally:
            os.close(fd)
    return holders


@contextlib.contextmanager
def file_lock(
    data_dir: Path, path: Path, wait_s: float = DEFAULT_FILE_WAIT_S, give_up: Callable[[], bool] | None = None
) -> Iterator[None]:
    """Exclusive work on path; waits up to wait_s for another holder, then LockHeld; WaitLeft
    at once when give_up() turns true meanwhile (the caller was asked to stop)."""
    folder = lock_dir(data_dir) / "files"
    make_private_dir(folder)
    name = Path(path).name

    def refusal(holder: str) -> str:
        return f"{name} is being worked on by another ppd process ({holder}); waited {wait_s:g} s, try later"

    def waiting(holder: str) -> None:
        log.warning("%s: waiting for another ppd process (%s) working on it, up to %g s", name, holder,
                    wait_s)  # fmt: skip

    lock_file = folder / f"{_key(path)}.lock"
    with _flock(lock_file, wait_s, refusal, remove=True, waiting=waiting, give_up=give_up):
        yield


# ---- the store lock ----------------------------------------------------------------------------------
STORE_LOCK = "store.lock"
# a command that ends holds the lock exclusive for an instant, to remove its file (release_store): a
# newcomer waits that out rather than be refused
STORE_WAIT_S = 2.0


def _hold_store(data_dir: Path, mode: int, wait_s: float, refusal: Callable[[str], str]) -> int:
    """The store lock's fd, locked in mode; the name is tried again when its last holder removed it
    meanwhile (as in _flock)."""
    lock_file = lock_dir(data_dir) / STORE_LOCK
    deadline = time.monotonic() + wait_s
    while True:
        fd = os.open(lock_file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
        try:
            _lock_by(fd, deadline, refusal, mode)
        except BaseException:
            os.close(fd)
            raise
        if _names(lock_file, fd):
            return fd
        os.close(fd)


class StoreBusy(LockHeld):
    """`ppd store rebuild` (or `ppd key new|import`) holds the store alone. busy: what it does and
    its pid, "ppd store rebuild is rebuilding the store (pid 123)"; the message adds what to do."""

    def __init__(self, busy: str) -> None:
        super().__init__(f"{busy}; run this again when it is done")
        self.busy = busy


def use_store(data_dir: Path, wait_s: float = STORE_WAIT_S) -> int:
    """Hold the store lock shared for a command's life (AppContext.open; release_store at its close,
    or the kernel at its death); StoreBusy while `ppd store rebuild` (or `ppd key new`) holds it."""
    busy = ""

    def refusal(holder: str) -> str:
        nonlocal busy
        lines: list[str] = []  # the holder's: its pid, then what it does
        with contextlib.suppress(OSError):
            fd = os.open(lock_dir(data_dir) / STORE_LOCK, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
            try:
                lines = _content(fd)
            finally:
                os.close(fd)
        doing = lines[1] if len(lines) > 1 else "ppd store rebuild is rebuilding the store"
        busy = f"{doing} ({holder})"
        return busy

    try:
        return _hold_store(data_dir, fcntl.LOCK_SH, wait_s, refusal)
    except LockHeld:
        raise StoreBusy(busy) from None


def release_store(data_dir: Path, fd: int) -> None:
    """Let go of use_store's lock; the last holder removes its file (_unlink_if_last)."""
    _unlink_if_last(Path(data_dir) / "locks" / STORE_LOCK, fd)


def _unlink_if_last(lock_file: Path, fd: int) -> None:
    """Let go of a shared lock on lock_file (open as fd); the last holder removes the file. Taking it
    exclusive for that fails at once while another holds it (who removes it in turn); no one removes
    the file without holding it exclusive, so a newcomer never locks a name that is gone (it checks
    the name still holds the file it locked, _names, and tries again)."""
    try:
        with contextlib.suppress(BlockingIOError):
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if _names(lock_file, fd):
                with contextlib.suppress(OSError):
                    os.unlink(lock_file)
    finally:
        os.close(fd)


def _store_holders(data_dir: Path) -> str:
    """Who holds the store lock, in words: "pid 123: ppd verify castle" (a refusal that named no one
    sent the user hunting a long verify or a Ctrl-Z'd ppd in another terminal: a black-box review)."""
    from daemon.platform import lock_holders

    try:
        st = os.stat(lock_dir(data_dir) / STORE_LOCK)
    except OSError:
        return "which one is not known"
    said = []
    for pid, argv in lock_holders(st):
        if pid != os.getpid():
            command = argv.split(" daemon.cli ", 1)[-1] if " daemon.cli " in argv else argv.rsplit("/", 1)[-1]
            said.append(f"pid {pid}: {'ppd ' if ' daemon.cli ' in argv else ''}{command}"[:80])
    return "; ".join(said) or "which one is not known"


@contextlib.contextmanager
def store_alone(
    data_dir: Path, doing: str = "ppd store rebuild is rebuilding the store", then: str = "rebuild",
    wait_s: float = STORE_WAIT_S,
) -> Iterator[None]:  # fmt: skip
    """The store lock exclusive: no other ppd command runs meanwhile (`ppd store rebuild`, `ppd key
    new`, whose key a running command would not see, and `ppd dataset forget`, whose originals a running
    command could name again); LockHeld while one runs. doing: what a command
    refused meanwhile is told; then: what to do once the others are done."""

    def refusal(_holder: str) -> str:
        return f"another ppd command is running ({_store_holders(data_dir)}); let it finish, then {then}"

    fd = _hold_store(data_dir, fcntl.LOCK_EX, wait_s, refusal)
    try:
        _write_pid(fd, doing)  # a command refused names it
        yield
    finally:
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
        release_store(data_dir, fd)
