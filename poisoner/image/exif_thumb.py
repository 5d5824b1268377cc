"""EXIF's own picture of the photo: the IFD1 thumbnail (a JPEG at JPEGInterchangeFormat, or
uncompressed strips) that cameras and phones write at 160 to 512 px. Copied as it was, it put an
unmarked copy of the original into every patched file (a black-box review, F3).

The thumbnail is rewritten *in place* from the patched picture (`Render`), as poisoner.location
removes the GPS IFD: the block keeps its length and nothing moves, so every other offset (a maker
note's own included) stays valid and every other byte stays as it was. A new JPEG thumbnail that
does not fit in the old one's bytes at any quality, or a strip layout ppd does not write, is
removed instead: its bytes zeroed (a carver finds nothing) and IFD1 unlinked from IFD0.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Callable

import numpy as np
from PIL import Image, JpegImagePlugin

from poisoner.completeness import jpeg_end
from poisoner.location import TYPE_SIZES, MetadataParseError, tiff_base, zero_ifd

# The patched picture fitted into (width, height), RGB: what a new thumbnail shows.
Render = Callable[[tuple[int, int]], Image.Image]

JPEG_FORMAT, JPEG_LENGTH = 0x0201, 0x0202  # IFD1: where the thumbnail's JPEG lies, and its length
_STRIP_OFFSETS, _STRIP_COUNTS = 0x0111, 0x0117
_FALLBACK_QUALITIES = (75, 60, 45, 30, 15)  # tried in turn when the source's tables do not fit
_SOI = b"\xff\xd8\xff"  # a JPEG's start (SOI, then a marker)
REPLACED = "replaced by the patched picture's"  # the notes' words (ppd poison's summary finds them)


class _Ifd:
    """One IFD's entries: tag -> (type, count, position of the value field in the block)."""

    def __init__(self, exif: bytes, base: int, bo: str, pos: int) -> None:
        if pos + 2 > len(exif):
            raise MetadataParseError("EXIF IFD outside the block")
        (count,) = struct.unpack(bo + "H", exif[pos : pos + 2])
        if pos + 2 + 12 * count + 4 > len(exif):
            raise MetadataParseError("EXIF IFD truncated")
        self.exif, self.base, self.bo, self.pos, self.count = exif, base, bo, pos, count
        self.entries: dict[int, tuple[int, int, int]] = {}
        self.linked_at = -1  # where the pointer to this IFD is (IFD0's next-IFD field, for IFD1)
        for i in range(count):
            e = pos + 2 + 12 * i
            tag, typ, n = struct.unpack(bo + "HHI", exif[e : e + 8])
            self.entries[tag] = (typ, n, e + 8)

    @property
    def next_at(self) -> int:
        """Position of this IFD's next-IFD pointer."""
        return self.pos + 2 + 12 * self.count

    def values(self, tag: int) -> list[int]:
        """A SHORT or LONG tag's values (empty when absent or of another type)."""
        if tag not in self.entries:
            return []
        typ, n, field = self.entries[tag]
        if typ not in (3, 4):
            return []
        fmt = "H" if typ == 3 else "I"
        at = field
        if TYPE_SIZES[typ] * n > 4:
            (off,) = struct.unpack(self.bo + "I", self.exif[field : field + 4])
            at = self.base + off
        if at + TYPE_SIZES[typ] * n > len(self.exif):
            raise MetadataParseError(f"EXIF tag 0x{tag:04X} runs past the block")
        return list(struct.unpack(self.bo + fmt * n, self.exif[at : at + TYPE_SIZES[typ] * n]))


def _ifd1(exif: bytes) -> _Ifd | None:
    base, bo = tiff_base(exif)
    if len(exif) < base + 8:
        raise MetadataParseError("EXIF header truncated")
    (ifd0_at,) = struct.unpack(bo + "I", exif[base + 4 : base + 8])
    ifd0 = _Ifd(exif, base, bo, base + ifd0_at)
    (ifd1_at,) = struct.unpack(bo + "I", exif[ifd0.next_at : ifd0.next_at + 4])
    if ifd1_at == 0:
        return None
    ifd1 = _Ifd(exif, base, bo, base + ifd1_at)
    ifd1.linked_at = ifd0.next_at
    return ifd1


def has_thumbnail(exif: bytes) -> bool:
    """Whether the block has an IFD1 (a thumbnail); False for one that does not parse."""
    try:
        return _ifd1(exif) is not None
    except MetadataParseError:
        return False


def rewrite_previews(exif: bytes, render: Render) -> tuple[bytes, list[str]]:
    """(the block with IFD1's thumbnail and every other JPEG in it (a maker note's preview: Nikon,
    Sony, Olympus write one of 640 px and more) showing the patched picture, or removed; what was
    done). Same length; raises MetadataParseError when the block cannot be parsed."""
    out, note = rewrite_thumbnail(exif, render)
    notes = [] if note is None else [note]
    done = bytearray(out)
    for at, end in _embedded_jpegs(out, _ifd1_span(out)):
        new = jpeg_within(out[at:end], end - at, render)
        if isinstance(new, str):
            done[at:end] = bytes(end - at)  # its pointer (in a maker note we do not parse) finds zeros
            notes.append(f"EXIF maker-note thumbnail removed ({end - at} bytes: {new})")
        else:
            done[at:end] = new[0] + bytes(end - at - len(new[0]))
            notes.append(f"EXIF maker-note thumbnail ({new[1][0]}x{new[1][1]}) {REPLACED}")
    return bytes(done), notes


def _ifd1_span(exif: bytes) -> tuple[int, int]:
    """Where IFD1's (already rewritten) JPEG thumbnail lies in the block: (0, 0) when none."""
    ifd1 = _ifd1(exif)
    if ifd1 is None or JPEG_FORMAT not in ifd1.entries:
        return (0, 0)
    at, length = _thumbnail_spans(ifd1)[0]
    return (at, at + length)


def _embedded_jpegs(exif: bytes, skip: tuple[int, int]) -> list[tuple[int, int]]:
    """(start, end) of each complete JPEG picture inside the block outside `skip` that decodes."""
    found: list[tuple[int, int]] = []
    at = exif.find(_SOI)
    while at >= 0:
        if skip[0] <= at < skip[1]:
            at = exif.find(_SOI, skip[1])
            continue
        end = jpeg_end(exif[at:])
        if end is not None and _decodes(exif[at : at + end]):
            found.append((at, at + end))
            at = exif.find(_SOI, at + end)
        else:
            at = exif.find(_SOI, at + 3)
    return found


def _decodes(jpeg: bytes) -> bool:
    try:
        with Image.open(io.BytesIO(jpeg)) as im:
            im.load()
        return True
    except (OSError, ValueError, SyntaxError):
        return False


def rewrite_thumbnail(exif: bytes, render: Render) -> tuple[bytes, str | None]:
    """(the block with its thumbnail showing the patched picture, or removed; what was done, None
    when it had none). Same length; raises MetadataParseError when the block cannot be parsed."""
    ifd1 = _ifd1(exif)
    if ifd1 is None:
        return exif, None
    out = bytearray(exif)
    spans = _thumbnail_spans(ifd1)
    if not any(length for _, length in spans):  # an IFD1 of tags alone (some cameras): no picture
        return exif, None
    if JPEG_FORMAT in ifd1.entries:
        at, length = spans[0]
        new = jpeg_within(bytes(exif[at : at + length]), length, render)
        if not isinstance(new, str):
            jpeg, (w, h) = new
            out[at : at + length] = jpeg + bytes(length - len(jpeg))  # the rest zeros: nothing of the old
            _set_length(out, ifd1, len(jpeg))
            return bytes(out), f"EXIF thumbnail ({w}x{h}) {REPLACED}"
        why = new
    elif _rgb_strips(out, ifd1, spans, render):
        w, h = ifd1.values(0x0100)[0], ifd1.values(0x0101)[0]
        return bytes(out), f"EXIF thumbnail ({w}x{h}) {REPLACED}"
    else:
        why = "strips of a kind ppd does not write"
    for at, length in spans:
        out[at : at + length] = bytes(length)
    zero_ifd(out, ifd1.base, ifd1.bo, ifd1.pos)
    out[ifd1.linked_at : ifd1.linked_at + 4] = bytes(4)  # IFD0 points at no next IFD
    return bytes(out), f"EXIF thumbnail removed ({why})"


def _thumbnail_spans(ifd1: _Ifd) -> list[tuple[int, int]]:
    """Block positions and lengths of the thumbnail's bytes: the JPEG, else each strip."""
    if JPEG_FORMAT in ifd1.entries:
        offsets, lengths = ifd1.values(JPEG_FORMAT)[:1], ifd1.values(JPEG_LENGTH)[:1]
    else:
        offsets, lengths = ifd1.values(_STRIP_OFFSETS), ifd1.values(_STRIP_COUNTS)
    if len(offsets) != len(lengths):
        raise MetadataParseError("EXIF thumbnail offsets and lengths disagree")
    spans = []
    for off, length in zip(offsets, lengths, strict=True):
        at = ifd1.base + off
        if at + length > len(ifd1.exif):
            raise MetadataParseError("EXIF thumbnail runs past the block")
        spans.append((at, length))
    return spans


def _set_length(out: bytearray, ifd: _Ifd, length: int) -> None:
    """JPEGInterchangeFormatLength := length (a LONG; a SHORT from some writers, left-justified)."""
    typ, _, field = ifd.entries[JPEG_LENGTH]
    value = struct.pack(ifd.bo + "H", length) + bytes(2) if typ == 3 else struct.pack(ifd.bo + "I", length)
    out[field : field + 4] = value


def jpeg_within(old: bytes, budget: int, render: Render) -> tuple[bytes, tuple[int, int]] | str:
    """The patched picture as a JPEG of the old thumbnail's size in at most `budget` bytes, and that
    size: first with the old one's own tables and sampling (its quality), then at falling qualities.
    Why not, when the old one does not decode or nothing fits."""
    try:
        with Image.open(io.BytesIO(old)) as was:
            size, like, grey = was.size, _table_options(was), was.mode == "L"
    except (OSError, ValueError, SyntaxError):
        return "its JPEG does not decode"
    picture = render(size).convert("L") if grey else render(size)
    for opts in ([like] if like else []) + [{"quality": q} for q in _FALLBACK_QUALITIES]:
        buf = io.BytesIO()
        try:
            picture.save(buf, "JPEG", **opts)
        except (OSError, ValueError):  # tables Pillow will not take: the next option
            continue
        if buf.tell() <= budget:
            return buf.getvalue(), size
    return "the patched picture's does not fit in its bytes"


def _table_options(im: Image.Image) -> dict[str, object] | None:
    """Save options that code a JPEG with im's own quantisation tables and sampling."""
    tables = getattr(im, "quantization", None)
    if im.format != "JPEG" or not tables:
        return None
    opts: dict[str, object] = {"qtables": [list(tables[k]) for k in sorted(tables)]}
    sampling = JpegImagePlugin.get_sampling(im)
    if sampling >= 0:
        opts["subsampling"] = sampling
    return opts


def _rgb_strips(out: bytearray, ifd1: _Ifd, spans: list[tuple[int, int]], render: Render) -> bool:
    """Overwrite an uncompressed 8-bit RGB strip thumbnail with the patched picture; False when the
    strips are of another kind (removed then)."""
    width, height = (ifd1.values(0x0100) or [0])[0], (ifd1.values(0x0101) or [0])[0]
    plain = ifd1.values(0x0103) in ([1], []) and ifd1.values(0x0106) == [2]
    samples, bits, planar = ifd1.values(0x0115), set(ifd1.values(0x0102)), ifd1.values(0x011C)
    chunky = samples == [3] and bits == {8} and planar in ([1], [])
    if not (plain and chunky and width and height and sum(n for _, n in spans) == width * height * 3):
        return False
    pixels = np.asarray(render((width, height)).convert("RGB"), dtype=np.uint8).tobytes()
    done = 0
    for at, length in spans:
        out[at : at + length] = pixels[done : done + length]
        done += length
    return True
