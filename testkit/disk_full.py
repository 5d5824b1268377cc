"""A small real filesystem that fills up (a size-limited tmpfs; root or CAP_SYS_ADMIN), and
protect_file run on it as the disk runs out and space comes back
(tests/reliability/test_reliability_diskfull.py, tests/daemon/store/test_vault.py); a folder that
refuses writes (read_only_folder)."""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from testkit.photos import write_image
from testkit.reliability import app_paths, check_invariants, leftover_temporaries, sha256


class MountUnavailable(RuntimeError):
    """A tmpfs cannot be mounted here (not root, no CAP_SYS_ADMIN, a locked-down container)."""


@contextlib.contextmanager
def small_filesystem(where: Path, size: str = "6m") -> Iterator[Path]:
    """A size-limited tmpfs mounted at where for the block (lazily unmounted afterwards). 6 MiB:
    the vault keeps an independent copy of every original (no hard link), so a run needs room
    for both."""
    where.mkdir(parents=True, exist_ok=True)
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(where)],
        capture_output=True, text=True,
    )  # fmt: skip
    if mounted.returncode != 0:
        raise MountUnavailable(mounted.stderr.strip() or f"mount exited {mounted.returncode}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


@contextlib.contextmanager
def read_only_folder(folder: Path) -> Iterator[Path]:
    """folder refuses writes for the block: chmod 0555 for a user, a read-only bind mount for root (who
    writes into a 0555 folder whatever its bits). MountUnavailable where root cannot mount."""
    if os.geteuid() != 0:
        mode = stat.S_IMODE(folder.stat().st_mode)
        folder.chmod(0o555)
        try:
            yield folder
        finally:
            folder.chmod(mode)
        return
    bound = subprocess.run(["mount", "--bind", str(folder), str(folder)], capture_output=True, text=True)
    if bound.returncode != 0:
        raise MountUnavailable(bound.stderr.strip() or f"mount exited {bound.returncode}")
    try:
        ro = subprocess.run(["mount", "-o", "remount,bind,ro", str(folder)], capture_output=True, text=True)
        if ro.returncode != 0:
            raise MountUnavailable(ro.stderr.strip() or f"mount exited {ro.returncode}")
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def fill(folder: Path, leave: int = 0) -> Path:
    """Write one filler file until the filesystem refuses another byte (ENOSPC), then give
    `leave` bytes back (room for the store's pages, not for a poisoned image)."""
    filler = folder / "filler.bin"
    with open(filler, "wb", buffering=0) as fh:
        try:
            while True:
                fh.write(b"\0" * 4096)
        except OSError as exc:
            if exc.errno != errno.ENOSPC:
                raise
    with open(filler, "ab", buffering=0) as fh, contextlib.suppress(OSError):  # the last partial block
        while True:
            fh.write(b"\0")
    if leave:
        os.truncate(filler, max(0, filler.stat().st_size - leave))
    return filler


@dataclass
class DiskFullReport:
    leave_bytes: int
    files: int = 0
    failed_while_full: int = 0
    protected_while_full: int = 0
    unclear_reasons: list[str] = field(default_factory=list)  # failures whose reason is not one line
    violations_while_full: list[str] = field(default_factory=list)
    violations_after: list[str] = field(default_factory=list)
    protected_after_space_returned: int = 0
    leftover_temporaries: int = 0


def run_disk_full(fs: Path, leave: int, files: int = 4) -> DiskFullReport:
    """protect_file in this process with outbox, store and vault on the small filesystem fs:
    one file protected, the disk filled (leaving `leave` bytes), the rest tried, space given
    back, the rest tried again."""
    from daemon.protect.one_file import AppContext, protect_file

    paths = app_paths(fs)
    report = DiskFullReport(leave_bytes=leave, files=files)
    ctx = AppContext.open(paths)
    try:
        images = [write_image(paths.outbox / "shoot" / f"{i}.png", seed=i, size=256) for i in range(files)]
        originals = {f: sha256(f) for f in images}
        assert protect_file(images[0], ctx).state == "patched"  # the store and vault exist
        filler = fill(fs, leave)
        for outcome in (protect_file(f, ctx) for f in images[1:]):
            report.failed_while_full += outcome.state == "failed"
            report.protected_while_full += outcome.state == "patched"
            if outcome.state == "failed" and (not outcome.reason or "\n" in outcome.reason):
                report.unclear_reasons.append(repr(outcome.reason))
        report.leftover_temporaries = len(leftover_temporaries(paths))
        report.violations_while_full = check_invariants(paths, originals)
        filler.unlink()
        report.protected_after_space_returned = sum(
            protect_file(f, ctx).state in ("patched", "unchanged") for f in images
        )
    finally:
        ctx.close()
    report.violations_after = check_invariants(paths, originals)
    return report
