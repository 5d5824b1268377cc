"""What `ppd restore --force` does with a file that is not ppd's output: another photo saved under the
patched one's name, or an edit made in another program. That file is the user's, so it is copied aside
before the original takes its place, into DATA/displaced/DATASET/ (the data folder is never in the
outbox or a publish folder: daemon.paths refuses it), and restore names the copy. Before, --force
destroyed it with no copy kept (a black-box review, F6).

changed_words says what changed, from the two pictures' headers only: another size or format than the
original ppd patched (another photo, or a crop) or the same size with other bytes (an edit)."""

from __future__ import annotations

import os
import stat
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.paths import make_private_dir

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
    replaced."""
    folder = displaced_folder(ctx, dataset)
    make_private_dir(folder)  # the user's photos: as private as the vault beside it
    st = os.lstat(path)
    if stat.S_ISLNK(st.st_mode):
        copy = _free_name(folder, path, lambda dst: os.symlink(os.readlink(path), dst))
        return copy, None
    if not stat.S_ISREG(st.st_mode):
        raise IsADirectoryError(f"{path} is not a regular file; not replacing it")
    src = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        made: list[int] = []

        def create(dst: Path) -> None:
            made.append(os.open(dst, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600))

        copy = _free_name(folder, path, create)
        try:
            sha = _copy_hashed(src, made[0])
            os.fsync(made[0])
        finally:
            os.close(made[0])
        os.utime(copy, ns=(st.st_atime_ns, st.st_mtime_ns))
    finally:
        os.close(src)
    return copy, sha


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


def _copy_hashed(src: int, dst: int) -> str:
    import hashlib

    from daemon.fsops import CHUNK

    digest = hashlib.sha256()
    offset = 0
    while chunk := os.pread(src, CHUNK, offset):
        digest.update(chunk)
        view = memoryview(chunk)
        while view:
            view = view[os.write(dst, view) :]
        offset += len(chunk)
    return digest.hexdigest()


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
