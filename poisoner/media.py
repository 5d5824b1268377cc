"""Which files are media, by suffix: the one table every package reads.

Importing this module is cheap (no numpy, PIL or PyAV), so the daemon's event layer can use it.
"""

from __future__ import annotations

import os

IMAGE_SUFFIXES: frozenset[str] = frozenset(
    {".jpg", ".jpeg", ".jpe", ".png", ".webp", ".tif", ".tiff", ".heic", ".heif", ".avif"}
)
VIDEO_SUFFIXES: frozenset[str] = frozenset({".mp4", ".m4v", ".mov", ".mkv", ".webm"})
MEDIA_SUFFIXES: frozenset[str] = IMAGE_SUFFIXES | VIDEO_SUFFIXES

# What COLMAP reads: the verifier's SfM sample is drawn from these.
SFM_SUFFIXES: frozenset[str] = frozenset({".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp"})

# Photos and videos ppd does not protect but a reconstruction can read (COLMAP reads BMP; raw files
# and GIFs convert in one step): a folder that holds them is not protected by patching the rest.
UNPROTECTED_SUFFIXES: frozenset[str] = frozenset({
    ".gif", ".bmp", ".dib", ".jxl", ".jp2", ".j2k", ".psd", ".exr", ".hdr", ".ppm", ".pgm", ".pnm",
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2", ".raf",
    ".pef", ".srw", ".x3f", ".3fr", ".iiq", ".erf", ".mrw", ".kdc", ".dcr",
    ".avi", ".mpg", ".mpeg", ".wmv", ".flv", ".3gp", ".mts", ".m2ts", ".ts", ".ogv", ".mxf", ".braw",
})  # fmt: skip

# Names that mean "still being written": browsers, download managers, sync tools, editors.
PARTIAL_SUFFIXES: frozenset[str] = frozenset({
    ".crdownload", ".part", ".partial", ".download", ".opdownload", ".filepart", ".crswap",
    ".tmp", ".temp", ".swp", ".swx", ".bak", ".aria2", ".!qb", ".!ut",
})  # fmt: skip


def suffix_of(path: str | os.PathLike[str]) -> str:
    return os.path.splitext(os.fspath(path))[1].lower()


def is_image(path: str | os.PathLike[str]) -> bool:
    return suffix_of(path) in IMAGE_SUFFIXES


def is_video(path: str | os.PathLike[str]) -> bool:
    return suffix_of(path) in VIDEO_SUFFIXES


def is_media(path: str | os.PathLike[str]) -> bool:
    return suffix_of(path) in MEDIA_SUFFIXES


# `.ts` names both an MPEG transport stream (a video) and TypeScript source: such a file is a video
# only when its bytes say so (a black-box review: a folder's script made `ppd poison` fail).
MPEG_TS_PACKET = 188
MPEG_TS_M2TS_PACKET = 192
MPEG_TS_SYNC = 0x47


def is_unprotected_media(path: str | os.PathLike[str]) -> bool:
    """A photo or video ppd leaves as it is (UNPROTECTED_SUFFIXES). A `.ts` file counts only when
    it reads as an MPEG transport stream (path must then name the file; unreadable: counted)."""
    suffix = suffix_of(path)
    if suffix == ".ts":
        return _reads_as_mpeg_ts(path)
    return suffix in UNPROTECTED_SUFFIXES


def _reads_as_mpeg_ts(path: str | os.PathLike[str]) -> bool:
    """The sync byte at one offset of every packet read: packets of 188 bytes, or 192 (M2TS, a camera's
    AVCHD: a 4-byte time code before each), from any offset in the first packet (a stream cut
    mid-packet); one packet only: it starts the file or follows a time code."""
    try:
        with open(path, "rb") as f:
            head = f.read(4 * MPEG_TS_M2TS_PACKET)
    except OSError:
        return True  # not read: counted as a video ppd cannot protect, never left out in silence
    if len(head) <= MPEG_TS_M2TS_PACKET:
        return MPEG_TS_SYNC in head[:5:4]
    for size in (MPEG_TS_PACKET, MPEG_TS_M2TS_PACKET):
        for start in range(size):
            marks = range(start, len(head), size)
            if len(marks) >= 2 and all(head[i] == MPEG_TS_SYNC for i in marks):
                return True
    return False


def is_sfm_readable(path: str | os.PathLike[str]) -> bool:
    return suffix_of(path) in SFM_SUFFIXES


__all__ = [
    "IMAGE_SUFFIXES", "MEDIA_SUFFIXES", "PARTIAL_SUFFIXES", "SFM_SUFFIXES", "UNPROTECTED_SUFFIXES",
    "VIDEO_SUFFIXES", "is_image", "is_media", "is_sfm_readable", "is_unprotected_media", "is_video",
    "suffix_of",
]  # fmt: skip
