"""Bounded memory: how big a file is once decoded, read from its header before anything decodes.

A few kilobytes can declare gigapixels (a solid-colour lossless WebP, a PNG of zeros, a TIFF that
only claims its size). `check_decode_budget` refuses such a file with one line before Pillow or
FFmpeg allocates anything; `poison_file` calls it first. The header readers are pure byte parsing
(no decoder): JPEG SOF, PNG IHDR/acTL, WebP VP8/VP8L/VP8X/ANMF, GIF screen and frame count,
TIFF IFDs, HEIF/AVIF `ispe`. Anything else falls back to Pillow's lazy open (header only).

DEFAULT_MAX_PIXELS: peak RSS of poison_file stays under ~1 GB for every 8-bit format just below it
(docs/FORMATS.md, "Memory", measured with bench_limits). Memory is also bounded in bytes (issue 29):
`peak_bytes` = the decoded size (width x height x channels x bytes per sample x frames) times the
working copies the format's path makes (PEAK_FACTOR, measured), plus the imports; a file over
`max_bytes` is refused (a 16-bit RGBA PNG needs ~4.7 bytes of memory per decoded byte, 8-bit ~1.5),
and the daemon admits files to its workers by the same estimate (daemon.protect.pool).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, replace
from pathlib import Path

from poisoner.errors import ExitStatus, ImageFormatError, PpdError

DEFAULT_MAX_PIXELS = 80_000_000  # peak RSS at 85 MP: JPEG 455 MB, PNG 438 MB (docs/FORMATS.md "Memory")
# Formats whose codecs need several times JPEG/PNG's memory get a fraction of the pixel budget
# (measured peak RSS, docs/FORMATS.md "Memory"): libwebp ~35 bytes/pixel (1411 MB at 40 MP) -> a
# fifth (16 MP by default, ~0.6 GB); HEIC/AVIF (x265 re-encode) ~26 bytes/pixel (1079 MB at 40 MP)
# -> a third (26.7 MP, ~0.74 GB).
BUDGET_DIVISOR = {
    "WEBP": (5, "a fifth", "libwebp needs ~35 bytes per pixel"),
    "HEIF": (3, "a third", "the HEIF encoder needs ~26 bytes per pixel"),
}
# 4096x2160 (DCI 4K) per frame: 3840x2160 peaks at 0.75 GB (x264, lookahead 10; docs/VIDEO.md)
DEFAULT_MAX_VIDEO_PIXELS = 4096 * 2160
_HEADER_READ = 1 << 16  # the first read; JPEG segments after it are walked with seeks (no cap)
# Peak RSS of poison_file per decoded byte, minus the imports (bench_limits, docs/FORMATS.md
# "Memory"): JPEG 1.62 (85 MP), PNG 8-bit RGB 1.50, RGBA 1.16, 16-bit RGBA 4.6 (FFmpeg's codec, 20
# and 40 MP), TIFF 2.6, WebP 8.5, HEIF 6.5; rounded up. Unknown formats: the largest of these.
# Measured again in issue 30 with ppd's own two-square mark (bench_limits used one corner patch), on
# gradients and on noise that the codec cannot shrink (a photo's sensor noise), per decoded byte plus
# per byte of the file (held as read, as compressed data, as written, as sealed): PNG 8-bit 2.8-3.1
# plus 3.5-4.7, 16-bit 5.2-6.0 plus 2.4-2.7 (FFmpeg's codec), TIFF LZW 1.9 plus 2.7, lossless WebP
# (8.8 on gradients) plus 7.8; JPEG of noise stays under 1.8 alone; rounded up. Before, noise-like
# PNG, TIFF and WebP took up to 3x, 1.6x and 1.5x the estimate. Then HEIF and lossy WebP, at 5-20
# and 5-15 MP (bench_limits, docs/FORMATS.md): HEIF 5.9-6.4 per decoded byte at the margin, plus a
# fixed ~30 MB, plus 6.6 per file byte (noise took 1.2x its old estimate, gradients 1.05x); lossy
# WebP 6.2-6.6 plus 27 per file byte (libwebp's encoder holds its tokens: noise took 1.18x); rounded
# up, the fixed part in HEIF's 7.5.
PEAK_FACTOR = {
    "JPEG": 1.8, "PNG": 3.2, "PNG16": 6.2, "TIFF": 2.0, "WEBP": 8.8, "WEBP-LOSSY": 6.6, "HEIF": 7.5,
    "GIF": 2.0,
}  # fmt: skip
# per byte of the file, on top
FILE_FACTOR = {"PNG": 4.8, "PNG16": 2.9, "TIFF": 3.0, "WEBP": 8.0, "WEBP-LOSSY": 27.5, "HEIF": 6.8}
IMPORTS_BYTES = 60_000_000  # a worker's RSS after its imports (43 MB measured), rounded up
DEFAULT_MAX_PEAK_BYTES = 1_024_000_000  # [limits] max_memory_mb


@dataclass(frozen=True)
class DecodedSize:
    format: str
    width: int
    height: int
    channels: int
    bytes_per_sample: int
    frames: int = 1
    file_bytes: int = 0  # the file's own size (decoded_size sets it)
    lossy: bool = False  # a WebP coded with VP8 (its encoder's memory follows the file's size)

    @property
    def pixels(self) -> int:
        return self.width * self.height * self.frames

    @property
    def bytes(self) -> int:
        return self.pixels * self.channels * self.bytes_per_sample

    @property
    def peak_bytes(self) -> int:
        """What protecting it takes in memory: the decoded bytes times the format's working copies,
        and for PNG the file's bytes times the copies of it held (a photo deflates poorly)."""
        key = "PNG16" if self.format == "PNG" and self.bytes_per_sample == 2 else self.format
        key = "WEBP-LOSSY" if key == "WEBP" and self.lossy else key
        held = self.file_bytes * FILE_FACTOR.get(key, 0.0)
        return IMPORTS_BYTES + int(self.bytes * PEAK_FACTOR.get(key, max(PEAK_FACTOR.values())) + held)


class HeaderError(PpdError, ValueError):
    """The header could not be read (the decoder will give its own error)."""

    exit_status = ExitStatus.FAILED


def decoded_size(path: Path, *, pillow: bool = True) -> DecodedSize:
    """What decoding path would allocate, from its header. Raises HeaderError. pillow=False: no
    Pillow fallback for other formats (the daemon process never loads it)."""
    try:
        with open(path, "rb") as f:
            head = f.read(_HEADER_READ)
            file_bytes = os.fstat(f.fileno()).st_size
    except OSError as exc:
        raise HeaderError(str(exc)) from exc
    return replace(_declared_size(path, head, pillow), file_bytes=file_bytes)


def _declared_size(path: Path, head: bytes, pillow: bool) -> DecodedSize:
    try:
        if head.startswith(b"\xff\xd8"):
            return _jpeg(path)
        if head.startswith(b"\x89PNG\r\n\x1a\n"):
            return _png(path)
        if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
            return _webp(path, head)
        if head[:6] in (b"GIF87a", b"GIF89a"):
            return _gif(path, head)
        if head[:4] in (b"II*\x00", b"MM\x00*"):
            return _tiff(path, head)
        if head[4:8] == b"ftyp":
            return _heif(path)
    except (struct.error, IndexError, ValueError, OSError) as exc:
        raise HeaderError(f"unreadable header ({exc})") from exc
    if not pillow:
        raise HeaderError("not a format whose header ppd reads itself")
    return _pillow(path)


def peak_bytes_estimate(path: Path, default: int) -> int:
    """peak_bytes from the header, without Pillow (the daemon's admission); default if unknown."""
    try:
        return decoded_size(Path(path), pillow=False).peak_bytes
    except HeaderError:
        return default


def decoded_bytes_estimate(path: Path) -> int:
    """Width x height x channels x bytes per sample x frames, from the header (0 if unreadable)."""
    try:
        return decoded_size(Path(path)).bytes
    except HeaderError:
        return 0


def check_decode_budget(
    path: Path, max_pixels: int = DEFAULT_MAX_PIXELS, *, name: str | None = None, max_bytes: int | None = None
) -> None:
    """Raise ImageFormatError (one line) when path declares more than max_pixels (all frames
    together; WebP a fifth of it, HEIF/AVIF a third), or would take more than max_bytes of memory
    to protect (peak_bytes; None: not checked), before anything is decoded. An unreadable header
    passes: the decoder refuses it. name: the file's name for the message (path may be a
    /proc/self/fd link, whose name is only a descriptor number)."""
    path = Path(path)
    try:
        size = decoded_size(path)
    except HeaderError:
        return
    limit, why = max_pixels, ""
    if size.format in BUDGET_DIVISOR:
        divisor, share, reason = BUDGET_DIVISOR[size.format]
        limit = max_pixels // divisor
        label = "WebP" if size.format == "WEBP" else "HEIF/AVIF"
        why = f" for {label} ({share} of {_mp(max_pixels)} MP: {reason})"
    frames = f" x {size.frames} frames" if size.frames > 1 else ""
    if size.pixels > limit:
        raise ImageFormatError(
            f"{name or path.name}: {size.width}x{size.height}{frames} ({_mp(size.pixels)} MP) is over the "
            f"{_mp(limit)} MP limit{why}; raise [limits] max_megapixels to protect it"
        )
    if max_bytes is not None and size.peak_bytes > max_bytes:
        depth = f"{8 * size.bytes_per_sample}-bit, {size.channels} channel(s)"
        raise ImageFormatError(
            f"{name or path.name}: {size.width}x{size.height}{frames} ({depth}) needs about "
            f"{size.peak_bytes // 1_000_000} MB to protect, over the {max_bytes // 1_000_000} MB memory "
            "limit; raise [limits] max_memory_mb to protect it"
        )


def check_video_frame_budget(name: str, width: int, height: int, max_pixels: int | None) -> str | None:
    """The one-line refusal for a video frame size over the limit, or None."""
    limit = DEFAULT_MAX_VIDEO_PIXELS if max_pixels is None else max_pixels
    if width * height > limit:
        return (
            f"{name}: {width}x{height} frames ({_mp(width * height)} MP) are over the {_mp(limit)} MP "
            "video limit; raise [limits] max_video_megapixels to protect it"
        )
    return None


def _mp(pixels: int) -> str:
    mp = pixels / 1e6
    return f"{mp:.0f}" if mp >= 10 else f"{mp:.1f}"


# ---- per-format header readers -----------------------------------------------------------------
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg(path: Path) -> DecodedSize:
    """The SOF, after however many segments (walked with seeks: a few bytes read per segment)."""
    with open(path, "rb") as f:
        f.seek(2)
        while True:
            head = f.read(4)
            if len(head) < 4:
                break
            if head[0] != 0xFF:
                raise ValueError("JPEG marker expected")
            marker = head[1]
            if marker == 0xFF:
                f.seek(-3, 1)
                continue
            if marker in (0xDA, 0xD9):
                break
            (length,) = struct.unpack(">H", head[2:4])
            if marker in _SOF:
                precision, height, width, comps = struct.unpack(">BHHB", f.read(6))
                # a DNL-marker JPEG declares height 0: the decoder then allocates per the real height;
                # treat as unknown width x 65535 (the most a JPEG can have)
                return DecodedSize("JPEG", width, height or 65535, comps, 2 if precision > 8 else 1)
            f.seek(length - 2, 1)
    raise ValueError("no JPEG frame header before the scan")


def _png(path: Path) -> DecodedSize:
    with open(path, "rb") as f:
        f.seek(8)
        length, ctype = struct.unpack(">I4s", f.read(8))
        if ctype != b"IHDR" or length != 13:
            raise ValueError("PNG without IHDR")
        width, height, depth, colour = struct.unpack(">IIBB", f.read(10))
        frames = 1
        f.seek(8 + 8 + 13 + 4)
        for _ in range(10000):  # ancillary chunks before the first IDAT
            hdr = f.read(8)
            if len(hdr) < 8:
                break
            length, ctype = struct.unpack(">I4s", hdr)
            if ctype == b"acTL":
                (frames,) = struct.unpack(">I", f.read(4))
                break
            if ctype in (b"IDAT", b"IEND"):
                break
            f.seek(length + 4, 1)
    channels = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}.get(colour, 4)  # palette decodes to RGB(A) here
    return DecodedSize("PNG", width, height, channels, 2 if depth == 16 else 1, max(1, frames))


def _webp(path: Path, head: bytes) -> DecodedSize:
    kind = head[12:16]
    if kind == b"VP8 ":
        w, h = struct.unpack("<HH", head[26:30])
        return DecodedSize("WEBP", w & 0x3FFF, h & 0x3FFF, 3, 1, lossy=True)
    if kind == b"VP8L":
        (bits,) = struct.unpack("<I", head[21:25])
        return DecodedSize("WEBP", (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1, 4, 1)
    if kind != b"VP8X":
        raise ValueError(f"unknown WebP chunk {kind!r}")
    flags = head[20]
    width = int.from_bytes(head[24:27], "little") + 1
    height = int.from_bytes(head[27:30], "little") + 1
    frames, lossy = 0, False
    with open(path, "rb") as f:  # the chunk headers only: frames of an animation, a still's coding
        f.seek(12)
        for _ in range(1_000_000):
            hdr = f.read(8)
            if len(hdr) < 8:
                break
            ctype, size = hdr[:4], struct.unpack("<I", hdr[4:])[0]
            frames += ctype == b"ANMF"
            if ctype in (b"VP8 ", b"VP8L") and not flags & 0x02:
                lossy = ctype == b"VP8 "
                break
            f.seek(size + (size & 1), 1)
    return DecodedSize("WEBP", width, height, 4, 1, max(1, frames), lossy=lossy)


def _gif(path: Path, head: bytes) -> DecodedSize:
    width, height, flags = struct.unpack("<HHB", head[6:11])
    frames = 0
    with open(path, "rb") as f:
        data = f.read(64 * 1024 * 1024)  # GIFs are small; a huge one is counted up to here
    pos = 13 + (3 << ((flags & 7) + 1) if flags & 0x80 else 0)
    while pos < len(data):
        block = data[pos]
        if block == 0x3B:
            break
        if block == 0x2C:  # image descriptor
            frames += 1
            lflags = data[pos + 9]
            pos += 10 + (3 << ((lflags & 7) + 1) if lflags & 0x80 else 0) + 1  # + LZW min code size
        elif block == 0x21:  # extension
            pos += 2
        else:
            break
        while pos < len(data) and data[pos]:  # sub-blocks
            pos += data[pos] + 1
        pos += 1
    return DecodedSize("GIF", width, height, 4, 1, max(1, frames))


def _tiff(path: Path, head: bytes) -> DecodedSize:
    bo = "<" if head[:2] == b"II" else ">"
    (ifd,) = struct.unpack(bo + "I", head[4:8])
    seen: set[int] = set()
    first: dict[int, int] = {}
    frames = 0
    with open(path, "rb") as f:
        while ifd and ifd not in seen and frames < 100_000:
            seen.add(ifd)
            f.seek(ifd)
            (count,) = struct.unpack(bo + "H", f.read(2))
            entries = f.read(12 * count)
            if frames == 0:
                for i in range(count):
                    tag, typ, n = struct.unpack(bo + "HHI", entries[12 * i : 12 * i + 8])
                    raw = entries[12 * i + 8 : 12 * i + 12]
                    if tag in (256, 257, 258, 277) and n >= 1:
                        first[tag] = (
                            struct.unpack(bo + "H", raw[:2])[0]
                            if typ == 3
                            else struct.unpack(bo + "I", raw)[0]
                        )
            frames += 1
            nxt = f.read(4)
            ifd = struct.unpack(bo + "I", nxt)[0] if len(nxt) == 4 else 0
    if 256 not in first or 257 not in first:
        raise ValueError("TIFF without dimensions")
    bits = first.get(258, 8)
    bits = bits if bits in (1, 2, 4, 8, 16, 32) else 8  # an offset (several values): 8-bit samples
    return DecodedSize("TIFF", first[256], first[257], first.get(277, 1), 2 if bits > 8 else 1, frames)


def _boxes(data: bytes, start: int, end: int) -> list[tuple[bytes, int, int]]:
    """(type, body start, body end) of the ISO-BMFF boxes in data[start:end]."""
    out = []
    pos = start
    while pos + 8 <= end:
        size, typ = struct.unpack(">I4s", data[pos : pos + 8])
        head = 8
        if size == 1:
            (size,) = struct.unpack(">Q", data[pos + 8 : pos + 16])
            head = 16
        elif size == 0:
            size = end - pos
        if size < head:
            break
        out.append((typ, pos + head, min(pos + size, end)))
        pos += size
    return out


def _heif(path: Path) -> DecodedSize:
    with open(path, "rb") as f:
        data = f.read(4 * 1024 * 1024)  # meta precedes mdat in HEIC/AVIF as written by cameras
    best, deep = (0, 0), False
    for typ, s, e in _boxes(data, 0, len(data)):
        if typ != b"meta":
            continue
        for t2, s2, e2 in _boxes(data, s + 4, e):  # meta is a full box
            if t2 != b"iprp":
                continue
            for t3, s3, e3 in _boxes(data, s2, e2):
                if t3 != b"ipco":
                    continue
                for t4, s4, _ in _boxes(data, s3, e3):
                    if t4 == b"ispe":
                        w, h = struct.unpack(">II", data[s4 + 4 : s4 + 12])
                        if w * h > best[0] * best[1]:
                            best = (w, h)
                    elif t4 == b"pixi":  # bits per channel: a 10- or 12-bit picture is decoded at 16
                        channels = data[s4 + 4] if len(data) > s4 + 4 else 0
                        deep = deep or any(b > 8 for b in data[s4 + 5 : s4 + 5 + channels])
    if best == (0, 0):
        return _pillow(path)
    return DecodedSize("HEIF", best[0], best[1], 4, 2 if deep else 1)


def _pillow(path: Path) -> DecodedSize:
    import warnings

    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as im:  # lazy: the header only
                w, h = im.size
                frames = getattr(im, "n_frames", 1)
                channels = len(im.getbands())
    except Image.DecompressionBombError as exc:
        raise HeaderError(str(exc)) from exc
    except Exception as exc:  # any reader failure means "header unknown"
        raise HeaderError(f"{type(exc).__name__}: {exc}") from exc
    return DecodedSize("other", w, h, channels, 1, frames)
