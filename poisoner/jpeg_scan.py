"""A baseline JPEG patched at the bit level: one Huffman decode of the picture, no re-encode of it.

The fastest of ppd's JPEG paths (poisoner/jpeg.py lists the others). The entropy-coded data is
indexed once (`index`: every MCU's first bit and every block's DC value, poisoner/_jpeg_entropy.c);
the luma DCs are the 1/8 thumbnail per-photo placement judges (`luma_thumbnail`, the very pixels
libjpeg's 1/8 greyscale decode gives); the MCUs around the mark are written out as a small JPEG for
Pillow to decode (`crop_jpeg`); the patched part is encoded with the source's quantisation tables
and sampling (jpeg.encode_like) and its MCUs are spliced into the source's bits (`splice`): every
other MCU's bits are copied as they are, shifted, and the MCU after each new run is re-coded for its
DC predictor. So the output holds the source's coefficients everywhere outside the mark's MCUs, coded
with the source's own Huffman tables, behind the source's own header bytes.

Scope (`Unsupported` otherwise, and the caller takes libjpeg-turbo's path): 8-bit sequential Huffman
(SOF0/SOF1), one interleaved scan of 1 or 3 components, chroma 1x1, no restart markers, nothing but
EOI after the scan. Data after EOI (e.g. a phone's appended preview image) is not written, as
libjpeg-turbo's paths do not write it. PPD_JPEG_SCAN="" turns this path off (tests, benchmarks).
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from poisoner.jpeg_parts import crop_box, mcu_box, parts_cover

SCAN_ENV = "PPD_JPEG_SCAN"
JPEGTRAN_ENV = "PPD_JPEGTRAN"
THUMBNAIL_SCALE = 8  # the DCs are a 1/8 decode
MAX_DIMENSION = 65500  # libjpeg's JPEG_MAX_DIMENSION

Box = tuple[int, int, int, int]


class Unsupported(Exception):
    """This file (or this machine) cannot take the bit-level path; the reason says why."""


def _codec() -> Any:
    if os.environ.get(SCAN_ENV) == "":
        raise Unsupported(f"{SCAN_ENV} is empty: bit-level path off")
    if os.environ.get(JPEGTRAN_ENV) == "":  # "no coefficient splice", whichever way (poisoner/jpeg.py)
        raise Unsupported(f"{JPEGTRAN_ENV} is empty: coefficient splice off")
    try:
        from poisoner import _jpeg_entropy  # type: ignore[attr-defined]
    except ImportError as exc:  # the extension was not built (no C compiler at install)
        raise Unsupported(f"poisoner._jpeg_entropy not built ({exc})") from exc
    return _jpeg_entropy


def available() -> str | None:
    """None when the bit-level path can run here, else why not."""
    try:
        _codec()
    except Unsupported as exc:
        return str(exc)
    return None


@dataclass(frozen=True)
class ScanLayout:
    """What the header says about the one scan this path handles."""

    width: int
    height: int
    frame: bytes  # SOF payload from its component count on (ids, sampling, table selectors)
    sampling: tuple[tuple[int, int], ...]
    coding: tuple[tuple[int, int, int, int], ...]  # (h, v, DC table, AC table) per component, scan order
    tables: tuple[bytes | None, ...]  # DC 0-3, AC 0-3: 16 counts + values
    quant: tuple[bytes, ...]  # each component's quantisation table (its 64 entries as stored)
    dqt: bytes  # the DQT segments, whole
    scan_header: bytes  # the SOS segment, whole
    scan_start: int

    @property
    def mcu_size(self) -> tuple[int, int]:
        if len(self.sampling) == 1:
            return (8, 8)
        return (8 * max(h for h, _ in self.sampling), 8 * max(v for _, v in self.sampling))

    @property
    def mcus(self) -> tuple[int, int]:
        """(columns, rows) of MCUs."""
        mw, mh = self.mcu_size
        return (-(-self.width // mw), -(-self.height // mh))

    @property
    def components(self) -> int:
        return len(self.sampling)


# SOF0/SOF1, DHT, SOS, DQT, DRI, APPn, COM: the only markers this path reads or copies.
_KNOWN = frozenset({0xC0, 0xC1, 0xC4, 0xDA, 0xDB, 0xDD, 0xFE, *range(0xE0, 0xF0)})


def parse(data: bytes) -> ScanLayout:
    """The header up to the scan, or Unsupported (the reason) when this path cannot take it."""
    from poisoner.location import MetadataParseError, jpeg_header_segments

    try:
        segments, sos = jpeg_header_segments(data)
    except MetadataParseError as exc:
        raise Unsupported(str(exc)) from exc
    tables: list[bytes | None] = [None] * 8
    quant: dict[int, bytes] = {}
    dqt: list[bytes] = []
    frame: bytes | None = None
    for marker, payload in segments:
        if marker not in _KNOWN:  # libjpeg's path judges anything else (other codings, odd markers)
            raise Unsupported(f"marker 0x{marker:02X} (progressive, lossless, arithmetic or unknown)")
        if marker in (0xC0, 0xC1):
            if frame is not None:
                raise Unsupported("two frame headers")
            frame = payload
        elif marker == 0xDD and (len(payload) != 2 or struct.unpack(">H", payload)[0]):
            raise Unsupported("restart markers")
        elif marker == 0xEE and payload.startswith(b"Adobe") and len(payload) >= 12 and payload[11] == 0:
            raise Unsupported("RGB-coded (Adobe transform 0)")
        elif marker == 0xDB:
            dqt.append(b"\xff\xdb" + struct.pack(">H", len(payload) + 2) + payload)
            _read_dqt(payload, quant)
        elif marker == 0xC4:
            _read_dht(payload, tables)
    if data[sos + 1 : sos + 2] != b"\xda" or len(data) < sos + 4:
        raise Unsupported("no scan")
    if frame is None:
        raise Unsupported("scan before the frame header")
    (length,) = struct.unpack(">H", data[sos + 2 : sos + 4])
    header = data[sos : sos + 2 + length]
    if len(header) != 2 + length or length < 2:
        raise Unsupported("scan header truncated")
    return _layout(frame, header[4:], tables, quant, b"".join(dqt), header, sos + 2 + length)


def _read_dqt(payload: bytes, quant: dict[int, bytes]) -> None:
    i = 0
    while i < len(payload):
        precision, table = payload[i] >> 4, payload[i] & 15
        size = 128 if precision else 64
        if i + 1 + size > len(payload) or table > 3:
            raise Unsupported("bad DQT segment")
        quant[table] = payload[i : i + 1 + size]
        i += 1 + size


def _read_dht(payload: bytes, tables: list[bytes | None]) -> None:
    i = 0
    while i + 17 <= len(payload):
        cls, ident = payload[i] >> 4, payload[i] & 15
        end = i + 17 + sum(payload[i + 1 : i + 17])
        if cls > 1 or ident > 3 or end > len(payload):
            raise Unsupported("bad DHT segment")
        tables[cls * 4 + ident] = payload[i + 1 : end]
        i = end
    if i != len(payload):  # bytes left over: libjpeg refuses the segment's length
        raise Unsupported("bad DHT segment")


def _layout(
    frame: bytes, sos: bytes, tables: list[bytes | None], quant: dict[int, bytes], dqt: bytes,
    scan_header: bytes, start: int,
) -> ScanLayout:  # fmt: skip
    if len(frame) < 6 or frame[0] != 8:
        raise Unsupported("not 8-bit")
    height, width = struct.unpack(">HH", frame[1:5])
    n = frame[5]
    if n not in (1, 3) or len(frame) != 6 + 3 * n:
        raise Unsupported(f"{n} components or a frame header of another length")
    if not 0 < width <= MAX_DIMENSION or not 0 < height <= MAX_DIMENSION:  # libjpeg's limit
        raise Unsupported(f"size {width}x{height}")
    ids = [frame[6 + 3 * i] for i in range(n)]
    sampling = tuple((frame[7 + 3 * i] >> 4, frame[7 + 3 * i] & 15) for i in range(n))
    if any(not (1 <= h <= 4 and 1 <= v <= 4) for h, v in sampling):
        raise Unsupported(f"sampling factors {sampling}")
    if n == 3 and any(s != (1, 1) for s in sampling[1:]):
        raise Unsupported(f"unusual sampling factors {sampling}")
    if not sos or sos[0] != n or len(sos) != 1 + 2 * n + 3 or sos[1 + 2 * n :] != b"\x00\x3f\x00":
        raise Unsupported("not one sequential scan of every component")
    if [sos[1 + 2 * i] for i in range(n)] != ids:
        raise Unsupported("scan components in another order than the frame's")
    if n == 3 and bytes(ids) == b"RGB":
        raise Unsupported("RGB-coded (component ids R, G, B)")
    if any(frame[8 + 3 * i] not in quant for i in range(n)):
        raise Unsupported("quantisation table missing")
    coding = []
    for i in range(n):
        h, v = (1, 1) if n == 1 else sampling[i]
        td, ta = sos[2 + 2 * i] >> 4, sos[2 + 2 * i] & 15
        if td > 3 or ta > 3 or tables[td] is None or tables[4 + ta] is None:
            raise Unsupported("Huffman table missing")
        coding.append((h, v, td, ta))
    tables_of = tuple(quant[frame[8 + 3 * i]] for i in range(n))
    # only the tables the scan uses are built (as libjpeg builds them): another one may hold anything
    used = {td for _, _, td, _ in coding} | {4 + ta for _, _, _, ta in coding}
    scan_tables = tuple(t if i in used else None for i, t in enumerate(tables))
    return ScanLayout(width, height, frame[5:], sampling, tuple(coding), tuple(scan_tables), tables_of, dqt,
                      scan_header, start)  # fmt: skip


@dataclass(frozen=True)
class Indexed:
    """A source JPEG's scan, indexed: its clean (unstuffed) bits, every MCU's first bit, every
    block's DC value (MCU order)."""

    layout: ScanLayout
    clean: bytes
    nbytes: int
    offsets: np.ndarray  # int64, MCUs + 1
    dc: np.ndarray  # int16, (MCUs, blocks per MCU)


_last: tuple[bytes, Indexed] | None = None


def index(data: bytes) -> Indexed:
    """The indexed scan of data (one Huffman decode of the picture). The last file's is kept, so the
    placement's thumbnail and the splice share one decode. Unsupported when this path cannot take it
    (corrupt or truncated data included: libjpeg-turbo's path then judges the file)."""
    global _last
    if _last is not None and _last[0] is data:
        return _last[1]
    indexed = _index(data)
    _last = (data, indexed)
    return indexed


def _index(data: bytes) -> Indexed:
    codec = _codec()
    layout = parse(data)
    try:
        clean, nbytes, end = codec.unstuff(data, layout.scan_start)
    except ValueError as exc:
        raise Unsupported(str(exc)) from exc
    if data[end : end + 2] != b"\xff\xd9":
        raise Unsupported("more than one scan")
    cols, rows = layout.mcus
    blocks = sum(h * v for h, v, _, _ in layout.coding)
    offsets = np.empty(cols * rows + 1, dtype=np.int64)
    dc = np.empty((cols * rows, blocks), dtype=np.int16)
    try:
        used = codec.index(clean, nbytes, layout.coding, layout.tables, cols * rows, offsets, dc)
    except ValueError as exc:
        raise Unsupported(str(exc)) from exc
    if (used + 7) // 8 < nbytes - 1:  # more than a byte's padding left over: not what the header says
        raise Unsupported("scan longer than its picture")
    return Indexed(layout, clean, nbytes, offsets, dc)


def forget() -> None:
    """Drop the kept index (its bytes are the size of the file)."""
    global _last
    _last = None


def thumbnail_scale(width: int, height: int, size: int) -> int:
    """The scale Pillow's JPEG draft decodes at for a thumbnail of `size` (JpegImagePlugin.draft)."""
    scale = min(width // size, height // size)
    return next((s for s in (8, 4, 2) if scale >= s), 1)


def luma_thumbnail(ix: Indexed) -> np.ndarray:
    """The 1/8 greyscale picture (uint8, ceil(h/8) x ceil(w/8)) from the luma DCs: what libjpeg's
    scaled decode to greyscale gives (its 1x1 IDCT: (DC x q + 4) >> 3 through its range-limit table,
    which clamps within -512..511 and wraps beyond, as a damaged DC can be)."""
    lay = ix.layout
    h, v = lay.coding[0][:2]
    cols, rows = lay.mcus
    grid = ix.dc[:, : h * v].reshape(rows, cols, v, h).transpose(0, 2, 1, 3).reshape(rows * v, cols * h)
    q = lay.quant[0]
    dc_step = struct.unpack(">H", q[1:3])[0] if q[0] >> 4 else q[1]
    value = ((grid.astype(np.int64) * dc_step + 4) >> 3) & 1023  # libjpeg's RANGE_MASK
    return _RANGE_LIMIT[value][: -(-lay.height // 8), : -(-lay.width // 8)]


# libjpeg's post-IDCT range-limit table (jdmaster.c prepare_range_limit_table), indexed by value & 1023:
# 0..127 -> 128..255, up to 511 -> 255, up to 895 -> 0, 896..1023 (-128..-1) -> 0..127.
_RANGE_LIMIT = np.concatenate(
    [np.arange(128, 256), np.full(384, 255), np.zeros(384), np.arange(0, 128)]
).astype(np.uint8)


def decode_mcus(ix: Indexed, which: np.ndarray) -> np.ndarray:
    """The coefficients (MCUs, blocks per MCU, 64; natural order) of the MCUs numbered `which`."""
    which = np.ascontiguousarray(which, dtype=np.int64)
    out = np.empty((len(which), ix.dc.shape[1], 64), dtype=np.int16)
    lay = ix.layout
    try:
        _codec().decode(ix.clean, ix.nbytes, lay.coding, lay.tables, ix.offsets, ix.dc, which, out)
    except (LookupError, ValueError) as exc:  # damaged data in these MCUs
        raise Unsupported(str(exc)) from exc
    return out


def _mcu_numbers(ix: Indexed, box: Box) -> np.ndarray:
    """The MCU numbers (scan order) of an MCU-aligned box, row by row."""
    mw, mh = ix.layout.mcu_size
    cols = ix.layout.mcus[0]
    c0, r0, c1, r1 = box[0] // mw, box[1] // mh, -(-box[2] // mw), -(-box[3] // mh)
    return (np.arange(r0, r1)[:, None] * cols + np.arange(c0, c1)[None, :]).ravel()


def crop_jpeg(ix: Indexed, box: Box) -> bytes:
    """A JPEG of the box (its top-left on an MCU corner; its other edges on one or on the picture's)
    holding the source's very coefficients: a lossless crop, coded with the standard Huffman tables."""
    lay = ix.layout
    x0, y0, x1, y1 = box
    coef = decode_mcus(ix, _mcu_numbers(ix, box))
    return _jpeg_of(lay, x1 - x0, y1 - y0, coef)


_standard: tuple[bytes | None, ...] | None = None


def _standard_coding(
    lay: ScanLayout,
) -> tuple[tuple[tuple[int, int, int, int], ...], tuple[bytes | None, ...]]:
    """libjpeg's standard Huffman tables (JPEG Annex K.3: every symbol an 8-bit baseline file can
    need), as its encoder writes them (read from a tiny Pillow file), and a coding that uses table 0
    for the luma and 1 for the chroma."""
    global _standard
    if _standard is None:
        from PIL import Image

        buf = io.BytesIO()
        Image.new("RGB", (16, 16)).save(buf, "JPEG")
        _standard = parse(buf.getvalue()).tables
    coding = tuple((h, v, min(i, 1), min(i, 1)) for i, (h, v, _, _) in enumerate(lay.coding))
    return coding, _standard


def _jpeg_of(lay: ScanLayout, width: int, height: int, coef: np.ndarray) -> bytes:
    coding, tables = _standard_coding(lay)
    try:
        scan = _codec().encode(np.ascontiguousarray(coef), coding, tables)
    except (LookupError, ValueError) as exc:  # a coefficient no baseline table codes (damaged data)
        raise Unsupported(str(exc)) from exc
    frame = bytearray(lay.frame)
    sof = b"\x08" + struct.pack(">HH", height, width) + bytes(frame)
    dht = b"".join(bytes([(i // 4) << 4 | i % 4]) + t for i, t in enumerate(tables) if t is not None)
    n = lay.components
    sos = bytes([n]) + b"".join(bytes([frame[1 + 3 * i], (min(i, 1) << 4) | min(i, 1)]) for i in range(n))
    sos += b"\x00\x3f\x00"

    def segment(marker: int, payload: bytes) -> bytes:
        return bytes((0xFF, marker)) + struct.pack(">H", len(payload) + 2) + payload

    return (
        b"\xff\xd8"
        + lay.dqt
        + segment(0xC0, sof)
        + segment(0xC4, dht)
        + segment(0xDA, sos)
        + scan
        + b"\xff\xd9"
    )


def splice(ix: Indexed, data: bytes, which: np.ndarray, coef: np.ndarray) -> bytes:
    """The source (data) with the MCUs numbered `which` (increasing) holding coef instead: its header
    bytes as they are, every other MCU's bits copied. Unsupported when the source's Huffman tables
    lack a symbol the new blocks need (an optimised table)."""
    lay = ix.layout
    try:
        which, coef = np.ascontiguousarray(which, dtype=np.int64), np.ascontiguousarray(coef)
        scan = _codec().splice(ix.clean, ix.nbytes, lay.coding, lay.tables, ix.offsets, ix.dc, which, coef)
    except (LookupError, ValueError) as exc:
        raise Unsupported(str(exc)) from exc
    return data[: lay.scan_start] + scan + b"\xff\xd9"


def patch_in_place(
    data: bytes,
    encode: Callable[[np.ndarray], bytes],
    box: Box,
    patch: Callable[[np.ndarray, Box], np.ndarray],
    keep_mcus: np.ndarray | None = None,
    parts: Sequence[Box] | None = None,
) -> bytes:
    """The source JPEG with only the MCUs of the MCU-aligned `box` replaced (those in keep_mcus, the
    box's MCU rows x columns, True = keep, excepted): each part (MCU-aligned boxes inside box holding
    every MCU not kept; default the whole box) is decoded from a lossless crop grown by one MCU (so
    its pixels are a whole-picture decode's), patched (patch(pixels, part)), encoded alone with the
    source's tables and sampling (encode: pixels -> JPEG bytes) and spliced in. The same blocks as
    libjpeg-turbo's path (poisoner.jpeg.patch_in_one_pass) writes. Unsupported when it cannot."""
    from PIL import Image

    ix = index(data)
    lay = ix.layout
    if box != mcu_box(box, lay):
        raise ValueError(f"box {box} is not MCU-aligned")
    if parts is None or not parts_cover(lay, box, parts, keep_mcus):
        parts = [box]
    mw, mh = lay.mcu_size
    numbers, blocks = [], []
    for part in parts:
        ring = crop_box(part, lay)
        with Image.open(io.BytesIO(crop_jpeg(ix, ring))) as cropped:
            cropped.load()
            x0, y0, x1, y1 = part
            pixels = np.asarray(cropped.crop((x0 - ring[0], y0 - ring[1], x1 - ring[0], y1 - ring[1])))
        drop = _index(encode(np.ascontiguousarray(patch(pixels, part))))
        if drop.layout.sampling != lay.sampling or drop.layout.mcus != (
            -(-(x1 - x0) // mw),
            -(-(y1 - y0) // mh),
        ):
            raise Unsupported("patched part coded on another MCU grid")
        if [q[1:] for q in drop.layout.quant] != [q[1:] for q in lay.quant]:
            raise Unsupported("patched part quantised with other tables")
        new = decode_mcus(drop, np.arange(len(drop.offsets) - 1))
        mine = _mcu_numbers(ix, part)
        if keep_mcus is not None:
            rows, cols = (y0 - box[1]) // mh, (x0 - box[0]) // mw
            cw, ch = drop.layout.mcus
            taken = ~keep_mcus[rows : rows + ch, cols : cols + cw].ravel()
            new, mine = new[taken], mine[taken]
        numbers.append(mine)
        blocks.append(new)
    # Two parts may share an MCU (squares closer than an MCU): each part's pixels were patched with
    # every square there, so both give the same blocks; one is taken.
    which, first = np.unique(np.concatenate(numbers), return_index=True)
    return splice(ix, data, which, np.concatenate(blocks)[first])
