"""PNG without re-encoding every pixel: the source's filtered rows are kept, only the rows the mark
touches (and the row below them, whose filter reads the row above) are filtered again, each with
the filter type the source chose for it, and the one zlib stream is compressed again.

Why: the whole re-encode (Pillow: an adaptive filter choice per row, then deflate at level 6) was
~110 ms of a 800x800 RGBA file's ~125 ms of codec work; here the rows are untouched bytes and the
deflate runs first with a fast setting (level 1, Z_RLE: ~15-25 ms per 800x800 file, measured on the
lego views and on camera-like noise). Its output is kept only while the new IDAT stays within
SIZE_BOUND of the source's IDAT; past that, the stream is compressed again at level 6, first with
zlib's default strategy (a photograph's size, 0.84x the CPU), then with Z_FILTERED (what reproduces
Pillow's own output size on renders), so a file never grows much for the speed. A setting that
runs past the bound on the rows so far is given up there, not at the end.

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

from poisoner.blend import apply_patch_at
from poisoner.image.png import PNG_SIGNATURE, png_chunks
from poisoner.spec import PatchPlacement

SIZE_BOUND = 1.05  # a deflate setting is kept while the new IDAT is at most this x the source's
FAST = (1, zlib.Z_RLE)  # (level, strategy)
# Photographs (sensor noise): run-length coding grows them ~19%, zlib's default strategy at level 6
# keeps their size (1.00x) at 0.84x Z_FILTERED's CPU; renders with flat areas (lego) are the other
# way round (default 1.08x, filtered 1.01x). Tried in this order, each given up as soon as its output
# runs past the bound on the rows so far; FALLBACK always ends it.
MIDDLE = (6, zlib.Z_DEFAULT_STRATEGY)
FALLBACK = (6, zlib.Z_FILTERED)  # gives exactly Pillow's own IDAT size on its rows (measured)
SETTINGS = (FAST, MIDDLE, FALLBACK)
# Given up early once the output passes SIZE_BOUND x the source bytes its rows came from by more
# than this (deflate holds back up to a block of output; a few early rows may compress worse).
EARLY_SLACK_BYTES, EARLY_SLACK_SHARE = 64 << 10, 0.02
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


ROWS_PER_STEP = 64  # rows inflated, filtered and deflated at a time: the picture is never held twice


class _Refused(Exception):
    """The stream is not what the header says (the caller re-encodes the file instead)."""


def _chunk(ctype: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + ctype + body + struct.pack(">I", zlib.crc32(ctype + body))


def _restream(
    idat: bytes, height: int, top: int, band: tuple[np.ndarray, np.ndarray], bpp: int,
    setting: tuple[int, int], bound: float | None,
) -> list[bytes] | None:
    """The IDAT stream again, ROWS_PER_STEP rows at a time: inflated, the band's rows (from `top`:
    band = (their new unfiltered rows, the row above each)) filtered again with the filter type each
    had, deflated with `setting`. With a bound (x the source's IDAT size), None once the output
    passes it, or passes bound x the source bytes of the rows so far by more than the early slack
    (the caller tries the next setting). _Refused when the stream does not hold exactly height rows
    of the band's width with filter types 0-4, or fails its checksum."""
    level, strategy = setting
    inflate, deflate = zlib.decompressobj(), zlib.compressobj(level, zlib.DEFLATED, 15, 9, strategy)
    current, above = band
    row_len = current.shape[1] + 1
    end = top + current.shape[0]
    parts: list[bytes] = []
    size = 0
    tail: bytes = idat
    give_up_at = float("inf") if bound is None else bound * len(idat)
    slack = EARLY_SLACK_BYTES + EARLY_SLACK_SHARE * len(idat)
    for y in range(0, height, ROWS_PER_STEP):
        n = min(ROWS_PER_STEP, height - y)
        want = n * row_len
        try:
            block = inflate.decompress(tail, want)
            while len(block) < want and inflate.unconsumed_tail:
                block += inflate.decompress(inflate.unconsumed_tail, want - len(block))
        except zlib.error as exc:
            raise _Refused(str(exc)) from None
        tail = inflate.unconsumed_tail
        if len(block) != want:
            raise _Refused("fewer rows than the header says")
        rows = np.frombuffer(block, dtype=np.uint8).reshape(n, row_len)
        if (rows[:, 0] > 4).any():
            raise _Refused("a row with an unknown filter type")
        lo, hi = max(top, y), min(end, y + n)
        if lo < hi:  # the band's rows in this step, filtered again as the source filtered them
            rows = rows.copy()
            rows[lo - y : hi - y, 1:] = filter_rows(
                rows[lo - y : hi - y, 0], current[lo - top : hi - top], above[lo - top : hi - top], bpp
            )
            block = rows.tobytes()
        out = deflate.compress(block)
        parts.append(out)
        size += len(out)
        if size > give_up_at or (bound is not None and size > bound * (len(idat) - len(tail)) + slack):
            return None
    try:
        rest = inflate.decompress(tail) + inflate.flush()
    except zlib.error as exc:
        raise _Refused(str(exc)) from None
    if rest or not inflate.eof:  # more data than rows, or a stream cut short (its checksum unread)
        raise _Refused("the stream does not end after the last row")
    parts.append(deflate.flush())
    return parts


def poison_png_rows(
    im: Image.Image, data: bytes, lanes: list[PatchPlacement], keep_out: np.ndarray | None = None
) -> tuple[bytes, list[str], list[str]] | None:
    """The patched PNG (bytes, kept chunk types, notes) with the source's filtered rows re-used,
    or None when this file needs the whole re-encode (see the module docstring). `im` is the
    decoded source, left as it is (only the band's rows are patched, as a copy); `lanes` the
    mark's placements, each blended on its own (poisoner.blend.lane_placements). Memory: the decoded
    picture, the source and the output; the inflated rows pass ROWS_PER_STEP at a time."""
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
    top = max(0, min(lane.box[1] for lane in lanes))
    end = min(height, max(lane.box[3] for lane in lanes) + 1)  # + the row whose filter reads the last
    start = max(0, top - 1)  # the band and the row above it, patched as a copy: im stays the source
    pixels = np.asarray(im.crop((0, start, width, end)))
    for lane in lanes:
        pixels = apply_patch_at(pixels, lane, (0, start), None if keep_out is None else keep_out[start:end])
    pixels = pixels.reshape(-1, stride)
    current = pixels[1:] if top > 0 else pixels
    above = pixels[:-1] if top > 0 else np.concatenate([np.zeros((1, stride), np.uint8), pixels[:-1]])
    parts: list[bytes] | None = None
    try:
        for setting in SETTINGS:  # the last one always ends it (no bound)
            bound = None if setting == SETTINGS[-1] else SIZE_BOUND
            parts = _restream(idat, height, top, (current, above), bpp, setting, bound)
            if parts is not None:
                break
    except _Refused:
        return None
    assert parts is not None
    out = [PNG_SIGNATURE]
    for ctype, body in chunks:
        if ctype != b"IDAT":
            out.append(_chunk(ctype, body))
        elif parts:  # the first IDAT's place: the new stream as one chunk (its CRC over the parts)
            crc = zlib.crc32(b"IDAT")
            for part in parts:
                crc = zlib.crc32(part, crc)
            out += [struct.pack(">I", sum(map(len, parts))), b"IDAT", *parts, struct.pack(">I", crc)]
            parts = []
    if chunks[-1][0] != b"IEND":
        out.append(_chunk(b"IEND", b""))
    kept = [t.decode("latin-1") for t, _ in chunks if t not in (b"IHDR", b"IDAT", b"IEND")]
    names = {FAST: "level 1, run-length", MIDDLE: "level 6", FALLBACK: "level 6, filtered"}
    how = names[setting] + ("" if setting == FAST else f" (the faster settings passed {SIZE_BOUND}x)")
    notes = [f"PNG: only rows {top}..{end - 1} filtered again (every other row's bytes kept); deflate {how}"]
    return b"".join(out), [f"PNG {t}" for t in kept], notes
