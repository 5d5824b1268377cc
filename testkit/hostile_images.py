"""Hostile image corpus: tiny files that decode huge (issue 20, row 6).

Every generator writes a real, well-formed file in bounded memory (streamed compression, or a
header patched onto a bitstream that does not depend on the size). Used by tests/poisoner/test_limits.py;
`python -m testkit.hostile_images OUT_DIR` writes the corpus for bench or manual runs.
"""

from __future__ import annotations

import io
import struct
import sys
import zlib
from collections.abc import Callable
from pathlib import Path


def _chunk(ctype: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + ctype + body + struct.pack(">I", zlib.crc32(ctype + body))


def _zero_idat(width: int, height: int, bytes_per_pixel: int) -> bytes:
    """Deflate of `height` rows of filter 0 + zeros, streamed (never the whole raw image)."""
    comp = zlib.compressobj(9)
    row = bytes(1 + width * bytes_per_pixel)
    out = [comp.compress(row) for _ in range(height)]
    out.append(comp.flush())
    return b"".join(out)


def png_zeros(path: Path, width: int = 12000, height: int = 12000) -> None:
    """A black RGB PNG: ~0.4 MB on disk, 432 MB decoded (x4 or more in a naive pipeline)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"IDAT", _zero_idat(width, height, 3))
        + _chunk(b"IEND", b"")
    )


def png_huge_ihdr(path: Path) -> None:
    """IHDR claims 100000 x 100000 RGBA; the data is one row (the decoder would allocate first)."""
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 6, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"IDAT", _zero_idat(100_000, 1, 4))
        + _chunk(b"IEND", b"")
    )


def png_text_bomb(path: Path, inflated: int = 256 * 1024 * 1024) -> None:
    """A 64x64 PNG whose compressed XMP iTXt inflates to `inflated` bytes (a deflate bomb)."""
    comp = zlib.compressobj(9)
    block = bytes(1 << 20)
    body = b"".join(comp.compress(block) for _ in range(inflated >> 20)) + comp.flush()
    itxt = b"XML:com.adobe.xmp\x00\x01\x00\x00\x00" + body
    ihdr = struct.pack(">IIBBBBB", 64, 64, 8, 2, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"iTXt", itxt)
        + _chunk(b"IDAT", _zero_idat(64, 64, 3))
        + _chunk(b"IEND", b"")
    )


def apng_many_frames(path: Path, frames: int = 1000) -> None:
    """An APNG header declaring 1000 frames of 2000 x 2000 (4 gigapixels in all)."""
    ihdr = struct.pack(">IIBBBBB", 2000, 2000, 8, 2, 0, 0, 0)
    actl = struct.pack(">II", frames, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"acTL", actl)
        + _chunk(b"IDAT", _zero_idat(2000, 2000, 3))
        + _chunk(b"IEND", b"")
    )


def webp_solid_lossless(path: Path, size: int = 16383) -> None:
    """A solid-colour lossless WebP of size x size (1 GB decoded) in a few dozen bytes.

    libwebp codes a solid colour with single-symbol Huffman codes and no transforms, so every
    pixel costs zero bits and the bitstream does not depend on the size: a 16 x 16 encode with
    its VP8L header's size fields patched is a valid size x size file (checked at 1024 in tests)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGBA", (16, 16), (40, 90, 200, 255)).save(buf, "WEBP", lossless=True, exact=True)
    data = bytearray(buf.getvalue())
    if data[12:16] != b"VP8L":
        raise RuntimeError("libwebp wrote an extended WebP; the size patch needs a simple VP8L file")
    (bits,) = struct.unpack("<I", data[21:25])
    bits = (bits & ~0x0FFFFFFF) | (size - 1) | ((size - 1) << 14)
    data[21:25] = struct.pack("<I", bits)
    path.write_bytes(bytes(data))


def tiff_huge(path: Path) -> None:
    """A classic TIFF whose IFD says 100000 x 100000 RGB, one 8-byte strip."""
    entries = [
        (256, 4, 1, 100_000),  # ImageWidth
        (257, 4, 1, 100_000),  # ImageLength
        (258, 3, 1, 8),  # BitsPerSample (one value: all samples)
        (259, 3, 1, 1),  # no compression
        (262, 3, 1, 2),  # RGB
        (273, 4, 1, 8),  # StripOffsets
        (277, 3, 1, 3),  # SamplesPerPixel
        (278, 4, 1, 100_000),  # RowsPerStrip
        (279, 4, 1, 8),  # StripByteCounts
    ]
    ifd = struct.pack("<H", len(entries))
    for tag, typ, n, value in entries:
        ifd += struct.pack("<HHI", tag, typ, n) + (
            struct.pack("<HH", value, 0) if typ == 3 else struct.pack("<I", value)
        )
    ifd += struct.pack("<I", 0)
    path.write_bytes(b"II*\x00" + struct.pack("<I", 16) + bytes(8) + ifd)


def gif_many_frames(path: Path, frames: int = 500) -> None:
    """A 4000 x 4000 GIF screen with 500 one-pixel frames (8 gigapixels of canvas to composite)."""
    out = bytearray(b"GIF89a" + struct.pack("<HHBBB", 4000, 4000, 0x80, 0, 0) + bytes(6))
    for _ in range(frames):
        out += b"\x21\xf9\x04\x00\x00\x00\x00\x00"  # graphic control extension
        out += b"\x2c" + struct.pack("<HHHHB", 0, 0, 1, 1, 0) + b"\x02\x02\x44\x01\x00"
    out += b"\x3b"
    path.write_bytes(bytes(out))


def jpeg_huge(path: Path) -> None:
    """A baseline JPEG header declaring 60000 x 60000 (10.8 GB of RGB) with a few bytes of scan."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (16, 16), (10, 20, 30)).save(buf, "JPEG")
    data = bytearray(buf.getvalue())
    at = data.find(b"\xff\xc0")
    data[at + 5 : at + 9] = struct.pack(">HH", 60000, 60000)
    path.write_bytes(bytes(data))


CORPUS: dict[str, Callable[[Path], None]] = {
    # just under Pillow's own bomb limit (89.5 MP): Pillow would decode these
    "zeros-9400.png": lambda p: png_zeros(p, 9400, 9400),
    "solid-9000.webp": lambda p: webp_solid_lossless(p, 9000),
    "zeros-12000.png": png_zeros,
    "huge-ihdr.png": png_huge_ihdr,
    "text-bomb.png": png_text_bomb,
    "apng-1000-frames.png": apng_many_frames,
    "solid-16383.webp": webp_solid_lossless,
    "huge.tif": tiff_huge,
    "frames-500.gif": gif_many_frames,
    "huge.jpg": jpeg_huge,
}


def write_corpus(out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, make in CORPUS.items():
        make(out_dir / name)
        paths.append(out_dir / name)
    return paths


if __name__ == "__main__":
    for p in write_corpus(Path(sys.argv[1] if len(sys.argv) > 1 else "hostile-corpus")):
        print(f"{p.stat().st_size:>10} {p}")
