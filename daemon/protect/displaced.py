"""What `ppd restore --force` does with a file that is not ppd's output: another photo saved under the
patched one's name, or an edit made in another program. That file is the user's, so it is copied aside
before the original takes its place, into DATA/displaced/DATASET/ (the data folder is never in the
outbox or a publish folder: daemon.paths refuses it), and restore names the copy. Before, --force
destroyed it with no copy kept (a black-box review, F6).

changed_words says what changed, from the two pictures' headers only: another size or format than the
original ppd patched (another photo, or a crop) or the same size with other bytes (an edit)."""

from __future__ import annotations

import contextlib
import os
import stat
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.fsops import clear_stale_temps_once, copy_fd_to_fd
from daemon.paths import make_private_dir
from poisoner.atomic import create_temp_at, fsync_dir

if TYPE_CHECKING:
    from daemon.context import AppContext

DISPLACED_DIR = "displaced"  # in the data folder; daemon.paths skips it when it looks for photos there
_NAME_TRIES = 1000  # copies of one name within one second


def displaced_folder(ctx: AppContext, dataset: str | None) -> Path:
    """DATA/displaced/DATASET: one folder per dataset, so a name kept twice is found by its dataset."""
    safe = (dataset or "no-dataset").replace(os.sep, "_").lstrip(".") or "no-dataset"
    return Path(ctx.paths.data_dir) / DISPLACED_DIR / safe


def keep_aside(ctx: AppContext, dataset: str | None, path: Path) -> tuple[Path, str | None]:
    """Copy the file at path (not followed: a symlink is kept as a link) into displaced_folder, under its
    name with the time and, where needed, a number added (never over an earlier copy); its dates kept.
    Returns (the copy, the sha256 of the bytes copied; None for a link). The caller replaces path only if
    it still holds exactly those bytes. Raises OSError when the copy cannot be made: then nothing is
    replaced.

    The copy is whole and on disk, its name too, before this returns: it is written to a ppd temporary
    (a kill mid-copy leaves no half file that looks like "your version"; the next call sweeps it), fsynced,
    linked to its free name, and the folders fsynced (the rename over the user's file, in another folder,
    must not reach the disk before the copy's name does: after a power cut it could be their only copy)."""
    folder = displaced_folder(ctx, dataset)
    make_private_dir(folder)  # the user's photos: as private as the vault beside it
    st = os.lstat(path)
    if stat.S_ISLNK(st.st_mode):
        copy = _free_name(folder, path, lambda dst: os.symlink(os.readlink(path), dst))
        _fsync_up(folder)
        return copy, None
    if not stat.S_ISREG(st.st_mode):
        raise IsADirectoryError(f"{path} is not a regular file; not replacing it")
    src = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    dir_fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        clear_stale_temps_once(dir_fd)  # a copy killed midway
        tmp, out = create_temp_at(dir_fd, path.suffix)
        try:
            sha = copy_fd_to_fd(src, out)
            os.utime(out, ns=(st.st_atime_ns, st.st_mtime_ns))
            copy = _free_name(folder, path, lambda dst: os.link(tmp, dst.name, src_dir_fd=dir_fd,
                                                                dst_dir_fd=dir_fd))  # fmt: skip
        finally:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp, dir_fd=dir_fd)
            os.close(out)
    finally:
        os.close(dir_fd)
        os.close(src)
    _fsync_up(folder)
    return copy, sha


def _fsync_up(folder: Path) -> None:
    """The folder's entries on disk, and its own and DATA/displaced's (make_private_dir may have just
    made them)."""
    for f in (folder, folder.parent, folder.parent.parent):
        fsync_dir(f)


def _free_name(folder: Path, path: Path, create: Callable[[Path], None]) -> Path:
    """The first name NAME.YYYYmmdd-HHMMSS[-N].EXT in folder that create(dst) makes (O_EXCL)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for n in range(_NAME_TRIES):
        dst = folder / f"{path.stem}.{stamp}{f'-{n}' if n else ''}{path.suffix}"
        try:
            create(dst)
        except FileExistsError:
            continue
        return dst
    raise FileExistsError(f"{folder}: {_NAME_TRIES} copies of {path.name} this second; not replacing it")


def changed_words(ctx: AppContext, path: Path, original_sha256: str) -> str:
    """'NAME changed since ppd patched it' and what changed, from the headers of the file and of its
    original in the vault (no decode): another picture size or format, or the same size."""
    from poisoner.limits import HeaderError, decoded_size

    said = f"{path.name} changed since ppd patched it"
    try:
        now = decoded_size(path, pillow=False)
        was = decoded_size(ctx.vault.path_for(original_sha256), pillow=False)
    except HeaderError:  # not a picture ppd reads the header of (a video, another format): no more said
        return said
    if (now.format, now.width, now.height) != (was.format, was.width, was.height):
        return (f"{said}: it is another picture now ({now.width}x{now.height} {now.format}; the original "
                f"ppd patched is {was.width}x{was.height} {was.format}): another photo, or a crop")
    return f"{said}: same {now.width}x{now.height} {now.format} picture, other bytes (edited elsewhere?)"


def resaved_words(path: Path) -> str:
    """What a file ppd recognised as its output saved again by another program is, for a restore that
    would write over it (the store's files.resaved)."""
    return (f"{path.name} is ppd's patched photo saved again since by another program (its picture ppd's, "
            "its bytes yours: metadata written, or re-encoded)")


SAVED_OVER = "its original is the file saved over ppd's patched photo"  # restore prints it without -v


def saved_over_note(ctx: AppContext, earlier: str | None) -> str | None:
    """What a restore says of an original that was saved over ppd's patched photo (files.saved_over:
    the clean photo from before): an edit of the patched photo still carries ppd's mark, and where the
    photo from before is (a black-box review, F1: "restored" handed back a marked picture, silently)."""
    if not earlier:
        return None
    # said as a condition: another photo saved under the name (a camera's counter reused) carries none
    edit = "if it was an edit of that photo, it still carries ppd's mark"
    if not ctx.vault.has(earlier):
        return f"{SAVED_OVER}: {edit}; the photo ppd patched before is kept no more"
    return (f"{SAVED_OVER}: {edit}; the photo ppd patched before is kept at {ctx.vault.path_for(earlier)} "
            "(copy it out to have it back)")
