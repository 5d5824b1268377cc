"""Whether two files of one format code the same picture, compared as coded (no decode): what a
metadata edit (a tagger's keywords, a rating, a comment) leaves unchanged. JPEG: the frame, tables and
scan; PNG: the header, palette, transparency and pixel data. Colour-management and text metadata (an
ICC profile, gAMA, EXIF, XMP) are not compared: a tagger may write them, and the picture's pixels, what
SIFT sees and what ppd's mark is made of, stay those of the file."""

from __future__ import annotations

from poisoner.image.png import PNG_SIGNATURE, png_chunks
from poisoner.location import MetadataParseError, jpeg_header_segments

# JPEG segments that decide the decoded pixels: SOFn, DHT, DAC, DQT, DRI, Adobe APP14 (the transform)
_JPEG_PICTURE = frozenset({*range(0xC0, 0xD0), 0xDB, 0xDD, 0xEE}) - {0xC8}
_PNG_PICTURE = frozenset({b"IHDR", b"PLTE", b"tRNS", b"IDAT"})


def comparable(data: bytes) -> bool:
    """Whether same_coded_picture can compare a file of this format (JPEG, PNG)."""
    return data[:2] == b"\xff\xd8" or data.startswith(PNG_SIGNATURE)


def same_coded_picture(a: bytes, b: bytes) -> bool | None:
    """True when a and b code the same picture (JPEG or PNG, compared as coded), False when they do
    not, None when neither comparison applies (another format, or a header that does not parse)."""
    try:
        if a[:2] == b[:2] == b"\xff\xd8":
            return _jpeg_picture(a) == _jpeg_picture(b)
        if a.startswith(PNG_SIGNATURE) and b.startswith(PNG_SIGNATURE):
            return _png_picture(a) == _png_picture(b)
    except (MetadataParseError, ValueError, IndexError):
        return None
    return None


def _jpeg_picture(data: bytes) -> tuple[list[tuple[int, bytes]], bytes]:
    segments, sos = jpeg_header_segments(data)
    return [
        (m, p) for m, p in segments if m in _JPEG_PICTURE and (m != 0xEE or p.startswith(b"Adobe"))
    ], data[sos:]


def _png_picture(data: bytes) -> list[tuple[bytes, bytes]]:
    chunks = [(t, body) for t, body in png_chunks(data) if t in _PNG_PICTURE]
    idat = b"".join(body for t, body in chunks if t == b"IDAT")  # split into chunks as a writer likes
    return [*((t, body) for t, body in chunks if t != b"IDAT"), (b"IDAT", idat)]
