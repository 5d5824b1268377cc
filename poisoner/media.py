"""Which files are media, by suffix, and by their first bytes where the suffix names no format: the
one table every package reads (media_class: `ppd poison`, `ppd status` and the daemon's outbox).

Importing this module is cheap (no numpy, PIL or PyAV), so the daemon's event layer can use it.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable

# .jfif/.jfi/.jif/.pjpeg/.pjp: what browsers and Windows save JPEGs as; .hif: Canon's HEIF
IMAGE_SUFFIXES: frozenset[str] = frozenset({
    ".jpg", ".jpeg", ".jpe", ".jfif", ".jfi", ".jif", ".pjpeg", ".pjp", ".png", ".webp", ".tif", ".tiff",
    ".heic", ".heif", ".hif", ".avif",
})  # fmt: skip
VIDEO_SUFFIXES: frozenset[str] = frozenset({".mp4", ".m4v", ".mov", ".mkv", ".webm"})
MEDIA_SUFFIXES: frozenset[str] = IMAGE_SUFFIXES | VIDEO_SUFFIXES

# What COLMAP reads: the verifier's SfM sample is drawn from these.
SFM_SUFFIXES: frozenset[str] = frozenset({".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp"})

# Photos and videos ppd does not protect but a reconstruction can read (COLMAP reads BMP; raw files
# and GIFs convert in one step): a folder that holds them is not protected by patching the rest.
UNPROTECTED_SUFFIXES: frozenset[str] = frozenset({
    ".gif", ".bmp", ".dib", ".jxl", ".jp2", ".j2k", ".psd", ".exr", ".hdr", ".ppm", ".pgm", ".pnm",
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2", ".raf",
    ".pef", ".srw", ".x3f", ".3fr", ".iiq", ".erf", ".mrw", ".kdc", ".dcr", ".raw", ".rwl",
    ".avi", ".mpg", ".mpeg", ".wmv", ".flv", ".3gp", ".mts", ".m2ts", ".ts", ".ogv", ".mxf", ".braw",
})  # fmt: skip

# Names that mean "still being written": browsers, download managers, sync tools, editors.
PARTIAL_SUFFIXES: frozenset[str] = frozenset({
    ".crdownload", ".part", ".partial", ".download", ".opdownload", ".filepart", ".crswap",
    ".tmp", ".temp", ".swp", ".swx", ".bak", ".aria2", ".!qb", ".!ut",
    # tools that preallocate the file and fill it out of order (Resilio, BitComet, BitTorrent, Thunder,
    # FlashGet, DownThemAll): its first and last bytes can read as a whole JPEG before the middle has come
    ".!sync", ".!bt", ".bc!", ".jc!", ".td", ".xltd", ".dtapart",
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


# A file whose suffix names no format (none at all, `.jpg_original`, a camera's `.THM`) is judged by
# its first bytes: COLMAP reads an image by its content, whatever its name (a black-box review: JPEGs
# named .jfif or with no suffix were left unprotected, unsaid). Sidecars and notes are never opened.
SNIFF_BYTES = 64
NOT_MEDIA_SUFFIXES: frozenset[str] = frozenset({
    ".xmp", ".aae", ".pp3", ".dop", ".on1", ".cos", ".txt", ".md", ".json", ".xml", ".csv", ".log",
    ".html", ".pdf", ".zip", ".wav", ".mp3", ".m4a", ".aac", ".flac",
})  # fmt: skip
IMAGE, VIDEO, UNPROTECTED = "image", "video", "unprotected"  # media_class's answers

# ISO-BMFF brands of a still HEIF or AVIF image (an MP4's or a MOV's are others)
_IMAGE_BRANDS = frozenset({b"heic", b"heix", b"heim", b"heis", b"mif1", b"mif2", b"avif"})
# Images COLMAP's reader takes that ppd does not write (GIF, BMP, JPEG XL, JPEG 2000, PSD, EXR, Radiance,
# PNM), and TIFF: a camera's raw file is TIFF inside (DNG, and raws under suffixes not listed above), of
# which ppd would write back only the preview; with a `.tif` suffix it is patched as a TIFF.
_UNPROTECTED_MAGIC = re.compile(
    rb"GIF8[79]a|BM.{4}\x00{4}|\x00\x00\x00\x0c(?:JXL |jP  )\r\n\x87\n|\xff\x4f\xff\x51|8BPS"
    rb"|\x76\x2f\x31\x01|#\?(?:RADIANCE|RGBE)|P[1-6]\s+(?:#[^\n]*\n\s*)*\d|II\*\x00|MM\x00\*|II\+\x00|MM\x00\+"
    # raw files whose header is TIFF-like but not TIFF: Panasonic/Leica, Olympus, Fuji
    rb"|IIU\x00|IIR[OS]|MMOR|FUJIFILMCCD-RAW",
    re.DOTALL,
)


def media_class(path: str | os.PathLike[str], head: Callable[[], bytes] | None = None) -> str | None:
    """IMAGE or VIDEO: a file ppd patches; UNPROTECTED: a photo or video a reconstruction reads that ppd
    does not patch; None: neither (a sidecar, a note, a hidden or partial file), left alone. By the
    suffix, else by the first SNIFF_BYTES (head(): read through a file already open, else from path;
    unreadable: None, as for COLMAP). `ppd poison`, `ppd status` and the daemon's outbox all ask it."""
    suffix = suffix_of(path)
    if suffix in IMAGE_SUFFIXES:
        return IMAGE
    if suffix in VIDEO_SUFFIXES:
        return VIDEO
    if suffix in UNPROTECTED_SUFFIXES:
        return UNPROTECTED if is_unprotected_media(path) else None
    if not judged_by_content(os.path.basename(os.fspath(path))):
        return None
    try:
        data = head() if head is not None else _head(path)
    except OSError:
        return None
    return content_class(data)


def image_format(head: bytes) -> str | None:
    """The format of a photo ppd writes, from its first bytes: "jpeg", "png", "webp", "heif" (AVIF too),
    else None."""
    if head.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if head[:4] + head[8:12] == b"RIFFWEBP":
        return "webp"
    if head[4:8] == b"ftyp" and _ftyp_brands(head) & _IMAGE_BRANDS:
        return "heif"
    return None


def content_class(head: bytes) -> str | None:
    """What a file's first bytes say: IMAGE for a format ppd writes (image_format), UNPROTECTED for
    another image a reconstruction reads (_UNPROTECTED_MAGIC), None else. A video is told by its suffix
    alone: no reconstruction reads one as it is (nor an MP4 of audio only)."""
    if image_format(head) is not None:
        return IMAGE
    return UNPROTECTED if _UNPROTECTED_MAGIC.match(head) else None


def _ftyp_brands(head: bytes) -> set[bytes]:
    """The major and compatible brands an ISO-BMFF `ftyp` box lists within head."""
    end = min(max(int.from_bytes(head[:4], "big"), 16), len(head))
    return {head[8:12]} | {head[i : i + 4] for i in range(16, end - 3, 4)}


def judged_by_content(name: str) -> bool:
    """Whether media_class opens a file of this name to read its first bytes: its suffix names no
    format, and it is not hidden (ppd's own temporaries are), a partial download, an editor's file
    (unpatched_name), a sidecar or a note."""
    stem, suffix = os.path.splitext(name)
    suffix = suffix.lower()
    named = suffix in MEDIA_SUFFIXES or suffix in UNPROTECTED_SUFFIXES
    # `photo.jpg.!sync`, `a.png.xyz`: how download, sync and backup tools name what is not the photo yet
    # (a diff review: a preallocated download was patched while its tool still wrote it)
    named_before = suffix_of(stem) in MEDIA_SUFFIXES or suffix_of(stem) in UNPROTECTED_SUFFIXES
    return not (named or named_before or unpatched_name(name) is not None
                or suffix in NOT_MEDIA_SUFFIXES)  # fmt: skip


def unpatched_name(name: str) -> str | None:
    """Why ppd never patches a file of this name as it is (None: it may): hidden (a writer's temporary,
    a thumbnail, a trash), an editor's backup or lock file, a partial download or a sync tool's temporary
    (PARTIAL_SUFFIXES), which is renamed to its real name once complete. The daemon's rule (docs/DAEMON.md),
    which `ppd poison` and `ppd status` name such a file by. An editor's file is `name~`, `~$name` or
    Emacs's `#name#`: a photo named `#IMG_1.jpg` is a photo, patched by all three (a black-box review: the
    daemon left it, status and poison did not)."""
    if name.startswith("."):
        return "hidden"
    if name.endswith("~"):
        return "editor backup"
    if name.startswith("~$") or (len(name) > 1 and name.startswith("#") and name.endswith("#")):
        return "editor lock file"
    suffix = suffix_of(name)
    if suffix in PARTIAL_SUFFIXES:
        return f"partial/temporary file ({suffix})"
    return None


# ISO-BMFF (MP4, MOV) and Matroska (MKV, WebM) files begin so
_VIDEO_MAGIC = re.compile(rb".{4}ftyp|\x1a\x45\xdf\xa3", re.DOTALL)


def content_under_any_name(name: str, head: bytes) -> str | None:
    """What a file holds by its first bytes, whatever its name: IMAGE or UNPROTECTED (content_class), or
    VIDEO for an MP4, MOV or Matroska file whose name carries a video suffix, its own or before a
    partial one (`clip.mp4.part`, `.clip.mov`): audio is an MP4 too, and a `._clip.mp4` (macOS's
    resource fork beside a copy) begins otherwise. None: none of these. For a file ppd does not patch by
    its name (unpatched_name): read SNIFF_BYTES, never decoded."""
    if (kind := content_class(head)) is not None:
        return kind
    stem = name.rstrip("~")
    named = {suffix_of(stem), suffix_of(os.path.splitext(stem)[0])}
    return VIDEO if named & VIDEO_SUFFIXES and _VIDEO_MAGIC.match(head) else None


def read_head(path: str | os.PathLike[str]) -> bytes:
    """A regular file's first SNIFF_BYTES (b"" for anything else, or unreadable)."""
    try:
        return _head(path)
    except OSError:
        return b""


def _head(path: str | os.PathLike[str]) -> bytes:
    """The first bytes of a regular file (followed through a symlink), b"" for anything else: a FIFO
    opened to be read blocks until a writer comes (a diff review: `ppd status` hung on one)."""
    import stat

    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        return os.read(fd, SNIFF_BYTES) if stat.S_ISREG(os.fstat(fd).st_mode) else b""
    finally:
        os.close(fd)


def is_photo(path: str | os.PathLike[str]) -> bool:
    """A photo ppd patches, by its suffix or its first bytes (media_class): the one rule wherever photos
    are counted or sampled (a diff review: the mask lines and a dataset's corner went by suffix alone,
    so a set of photos with no suffix counted "1 of 2" of 3 and never got a judged corner)."""
    return media_class(path) == IMAGE


def is_sfm_readable(path: str | os.PathLike[str]) -> bool:
    return suffix_of(path) in SFM_SUFFIXES


__all__ = [
    "IMAGE", "IMAGE_SUFFIXES", "MEDIA_SUFFIXES", "NOT_MEDIA_SUFFIXES", "PARTIAL_SUFFIXES", "SFM_SUFFIXES",
    "SNIFF_BYTES", "UNPROTECTED", "UNPROTECTED_SUFFIXES", "VIDEO", "VIDEO_SUFFIXES", "content_class",
    "content_under_any_name", "image_format", "is_image", "is_media", "is_photo", "is_sfm_readable",
    "is_unprotected_media", "is_video", "judged_by_content", "media_class", "read_head", "suffix_of",
    "unpatched_name",
]  # fmt: skip
