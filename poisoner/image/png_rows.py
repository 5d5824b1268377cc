"""PNG without re-encoding every pixel: the source's filtered rows are kept, only the rows the mark
touches (and the row below them, whose filter reads the row above) are filtered again, each with
the filter type the source chose for it, and the one zlib stream is compressed again.

Why: the whole re-encode (Pillow: an adaptive filter choice per row, then deflate at level 6) was
~110 ms of a 800x800 RGBA file's ~125 ms of codec work; here the rows are untouched bytes and the
deflate runs first with a fast setting (level 1, Z_RLE: ~15-25 ms per 800x800 file, measured on the
lego views and on camera-like noise). Its output is kept only while the new IDAT stays within
SIZE_BOUND of the source's IDAT; past that, the stream is compressed again at level 6 with
Z_FILTERED (what reproduces Pillow's own output size), so a file never grows much for the speed.

Lossless like the re-encode: the decoded pixels are the patched picture exactly (tests). Every
chunk but IDAT is copied byte for byte, in its place. Only 8-bit, non-interlaced grey, grey+alpha,
RGB and RGBA files without tRNS take this path; any other PNG returns None (the caller re-encodes:
poisoner.image.png.poison_png).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np
from PIL import Image

from poisoner.image.png import PNG_SIGNATURE, png_chunks
from poisoner.image.write import paste_patch
from poisoner.spec import PatchPlacement

SIZE_BOUND = 1.05  # the fast deflate is kept while the new IDAT is at most this x the source's
FAST = (1, zlib.Z_RLE)  # (level, strategy)
FALLBACK = (6, zlib.Z_FILTERED)  # gives exactly Pillow's own IDAT size on its rows (measured)
_BYTES_PER_PIXEL = {0: 1, 2: 3, 4: 2, 6: 4}  # colour type -> bytes per 8-bit pixel
_MODES = {0: "L", 2: "RGB", 4: "LA", 6: "RGBA"}
_NOT_HERE = {b"tRNS", b"acTL", b"fcTL", b"fdAT", b"PLTE"}  # colour keys, animation, palettes


def filter_rows(kinds: np.ndarray, rows: np.ndarray, above: np.ndarray, bpp: int) -> np.ndarray:
    """PNG-filter `rows` (n x stride, uint8, unfiltered) with one filter type per row (`kinds`,
    0-4: None, Sub, Up, Average, Paeth); `above` holds each row's unfiltered row above (zeros for
    a picture's first row). The filtered bytes, n x stride uint8."""
    x = rows.astype(np.int16)
    b = above.astype(np.int16)
    pad = np.zeros((x.shape[0], bpp), dtype=np.int16)
    a = np.concatenate([pad, x[:, :-bpp]], axis=1)  # left
    c = np.concatenate([pad, b[:, :-bpp]], axis=1)  # upper left
    pa, pb, pc = np.abs(b - c), np.abs(a - c), np.abs(a + b - 2 * c)
    paeth = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
    predicted = np.select(
        [kinds[:, None] == k for k in (1, 2, 3, 4)], [a, b, (a + b) >> 1, paeth], default=0
    )
    return ((x - predicted) & 0xFF).astype(np.uint8)


def _chunk(ctype: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + ctype + body + struct.pack(">I", zlib.crc32(ctype + body))


def _deflate(raw: bytes, setting: tuple[int, int]) -> bytes:
    level, strategy = setting
    co = zlib.compressobj(level, zlib.DEFLATED, 15, 9, strategy)
    return co.compress(raw) + co.flush()


def poison_png_rows(
    im: Image.Image, data: bytes, lanes: list[PatchPlacement], keep_out: np.ndarray | None = None
) -> tuple[bytes, list[str], list[str]] | None:
    """The patched PNG (bytes, kept chunk types, notes) with the source's filtered rows re-used,
    or None when this file needs the whole re-encode (see the module docstring). `im` is the
    decoded source (patched in place, as poisoner.image.png.poison_png does); `lanes` the mark's
    placements, each pasted on its own (poisoner.formats.lane_placements)."""
    chunks = png_chunks(data)
    ihdr = chunks[0][1]
    width, height, depth, colour, interlace = struct.unpack(">IIBB2xB", ihdr)
    if depth != 8 or interlace or colour not in _BYTES_PER_PIXEL or im.mode != _MODES[colour]:
        return None
    if any(t in _NOT_HERE for t, _ in chunks) or im.size != (width, height):
        return None
    idat = b"".join(body for t, body in chunks if t == b"IDAT")
    bpp = _BYTES_PER_PIXEL[colour]
    stride = width * bpp
    try:
        raw = zlib.decompress(idat)
    except zlib.error:
        return None
    if len(raw) != height * (stride + 1):
        return None
    filtered = np.frombuffer(raw, dtype=np.uint8).reshape(height, stride + 1).copy()
    kinds = filtered[:, 0]
    if (kinds > 4).any():
        return None
    for lane in lanes:
        paste_patch(im, lane, keep_out)
    top = max(0, min(lane.box[1] for lane in lanes))
    end = min(height, max(lane.box[3] for lane in lanes) + 1)  # + the row whose filter reads the last
    pixels = np.asarray(im.crop((0, max(0, top - 1), width, end))).reshape(-1, stride)
    rows = pixels[1:] if top > 0 else pixels
    above = pixels[:-1] if top > 0 else np.concatenate([np.zeros((1, stride), np.uint8), pixels[:-1]])
    filtered[top:end, 1:] = filter_rows(kinds[top:end], rows, above, bpp)
    new_raw = filtered.tobytes()
    setting = FAST
    compressed = _deflate(new_raw, FAST)
    if len(compressed) > SIZE_BOUND * len(idat):
        setting = FALLBACK
        compressed = _deflate(new_raw, FALLBACK)
    parts = [PNG_SIGNATURE]
    for ctype, body in chunks:
        if ctype == b"IDAT":
            if compressed:
                parts.append(_chunk(b"IDAT", compressed))
                compressed = b""
            continue
        parts.append(_chunk(ctype, body))
    if chunks[-1][0] != b"IEND":
        parts.append(_chunk(b"IEND", b""))
    kept = [t.decode("latin-1") for t, _ in chunks if t not in (b"IHDR", b"IDAT", b"IEND")]
    how = "level 1, run-length" if setting == FAST else f"level {setting[0]} (level 1 passed {SIZE_BOUND}x)"
    notes = [f"PNG: only rows {top}..{end - 1} filtered again (every other row's bytes kept); deflate {how}"]
    return b"".join(parts), [f"PNG {t}" for t in kept], notes
