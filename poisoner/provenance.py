"""Provenance marker: a protected file says, in its own metadata, that ppd wrote it.

The marker carries the spec id, the original's sha256 and the tool, so a lost store never leads
to poisoning a file twice and originals can be found in the vault by hash alone.

Where it lives (deterministic bytes: the same inputs give the same file):
- JPEG, WebP, TIFF, HEIC/AVIF: XMP, one `rdf:Description` in the namespace `ppd:` (NS below) with
  attributes SpecId, OriginalSha256, Tool; added to the source's XMP packet (the rest of the
  packet is kept as it was) or a new minimal packet.
- PNG: an iTXt chunk, keyword "ppd:provenance", right after IHDR (read without touching IDAT).
- MP4/MOV: a top-level `uuid` box (UUID below) appended after the last box: no offset in the
  file moves, players ignore it.
- Matroska/WebM: a container tag PPD_PROVENANCE (a SimpleTag).
The non-XMP carriers hold the same three fields as compact JSON with sorted keys.

`read_marker` reads structure only (never pixels): a few header reads and seeks per file.
"""

from __future__ import annotations

import json
import re
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr, unescape

NS = "http://ns.ppd.invalid/provenance/1.0/"
PNG_KEYWORD = b"ppd:provenance"
MKV_TAG = "PPD_PROVENANCE"
MP4_UUID = bytes.fromhex("8f2c3e1a5b7d4c6e9a0b1c2d3e4f5a6b")  # ppd's provenance box

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_XMP_JPEG_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
_MAX_META_READ = 16 * 1024 * 1024  # no metadata block we read is larger: anything more is refused
_FIELDS = ("SpecId", "OriginalSha256", "Tool")


@dataclass(frozen=True)
class Marker:
    spec_id: str
    original_sha256: str
    tool: str

    def to_json(self) -> bytes:
        doc = {"original_sha256": self.original_sha256, "spec_id": self.spec_id, "tool": self.tool}
        return json.dumps(doc, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()

    @staticmethod
    def from_json(data: bytes | str) -> Marker | None:
        try:
            doc = json.loads(data)
            m = Marker(str(doc["spec_id"]), str(doc["original_sha256"]), str(doc["tool"]))
        except (ValueError, KeyError, TypeError):
            return None
        return m


# ---- XMP -----------------------------------------------------------------------------------------
_OWN_DESCRIPTION = re.compile(
    rb"<rdf:Description\s[^>]*xmlns:ppd=\"" + re.escape(NS.encode()) + rb"\"[^>]*/>\s*"
)
_RDF_CLOSE = re.compile(rb"</([A-Za-z_][\w.-]*:)?RDF\s*>")


def marker_description(marker: Marker) -> bytes:
    attrs = " ".join(
        f"ppd:{name}={quoteattr(value)}"
        for name, value in zip(_FIELDS, (marker.spec_id, marker.original_sha256, marker.tool), strict=True)
    )
    return f'<rdf:Description rdf:about="" xmlns:ppd="{NS}" {attrs}/>'.encode()


def fresh_xmp(marker: Marker) -> bytes:
    return (
        b'<?xpacket begin="\xef\xbb\xbf" id="W5M0MpCehiHzreSzNTczkc9d"?>'
        b'<x:xmpmeta xmlns:x="adobe:ns:meta/">'
        b'<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        + marker_description(marker)
        + b'</rdf:RDF></x:xmpmeta><?xpacket end="w"?>'
    )


def xmp_with_marker(xmp: bytes | None, marker: Marker) -> bytes:
    """The packet with ppd's description (replacing an older one); a new packet when there is
    none or it has no rdf:RDF element to add to."""
    if not xmp:
        return fresh_xmp(marker)
    xmp = _OWN_DESCRIPTION.sub(b"", xmp)
    closes = list(_RDF_CLOSE.finditer(xmp))
    if not closes or (closes[-1].group(1) or b"rdf:") != b"rdf:":
        return fresh_xmp(marker)
    at = closes[-1].start()
    return xmp[:at] + marker_description(marker) + xmp[at:]


def marker_from_xmp(xmp: bytes) -> Marker | None:
    if NS.encode() not in xmp:
        return None
    values: list[str] = []
    for name in _FIELDS:
        m = re.search(rb"ppd:" + name.encode() + rb"""\s*=\s*(?:"([^"]*)"|'([^']*)')""", xmp)
        if not m:
            return None
        raw = m.group(1) if m.group(1) is not None else m.group(2)
        values.append(unescape(raw.decode("utf-8", "replace"), {"&quot;": '"', "&apos;": "'"}))
    return Marker(*values)


# ---- embedding -----------------------------------------------------------------------------------
def embed_jpeg(data: bytes, marker: Marker) -> bytes:
    """The JPEG with the marker in its XMP APP1 segment; the scans are copied verbatim."""
    from poisoner.location import jpeg_assemble, jpeg_header_segments

    segments, sos = jpeg_header_segments(data)
    for i, (m, payload) in enumerate(segments):
        if m == 0xE1 and payload.startswith(_XMP_JPEG_HEADER):
            body = xmp_with_marker(payload[len(_XMP_JPEG_HEADER) :], marker)
            segments[i] = (m, _XMP_JPEG_HEADER + body)
            break
    else:
        # after the leading APP0/APP1 run (JFIF, EXIF): where XMP conventionally sits
        at = 0
        while at < len(segments) and segments[at][0] in (0xE0, 0xE1):
            at += 1
        segments.insert(at, (0xE1, _XMP_JPEG_HEADER + fresh_xmp(marker)))
    return jpeg_assemble(segments, data, sos)


def _png_chunk(ctype: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + ctype + body + struct.pack(">I", zlib.crc32(ctype + body))


def embed_png(data: bytes, marker: Marker) -> bytes:
    """The PNG with an iTXt "ppd:provenance" right after IHDR (an older one removed); every other
    chunk is copied byte for byte."""
    if not data.startswith(_PNG_SIGNATURE):
        raise ValueError("not a PNG")
    parts = [_PNG_SIGNATURE]
    pos = len(_PNG_SIGNATURE)
    own = PNG_KEYWORD + b"\x00"
    while pos + 12 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        ctype = data[pos + 4 : pos + 8]
        end = pos + 12 + length
        if not (ctype == b"iTXt" and data[pos + 8 : pos + 8 + len(own)] == own):
            parts.append(data[pos:end])
        if ctype == b"IHDR":
            parts.append(_png_chunk(b"iTXt", own + b"\x00\x00\x00\x00" + marker.to_json()))
        pos = end
        if ctype == b"IEND":
            break
    return b"".join(parts)


def mp4_box(marker: Marker) -> bytes:
    body = MP4_UUID + marker.to_json()
    return struct.pack(">I", 8 + len(body)) + b"uuid" + body


# ---- reading -------------------------------------------------------------------------------------
def read_marker(path: Path) -> Marker | None:
    """The marker of a file ppd protected; None when there is none or the file cannot be read.
    Reads metadata structure only (a few small reads and seeks)."""
    try:
        with open(path, "rb") as f:
            head = f.read(16)
            if head.startswith(b"\xff\xd8"):
                return _read_jpeg(f)
            if head.startswith(_PNG_SIGNATURE):
                return _read_png(f)
            if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
                return _read_webp(f)
            if head[:4] in (b"II*\x00", b"MM\x00*"):
                return _read_tiff(f, head)
            if head[:4] == b"\x1a\x45\xdf\xa3":
                return _read_matroska(f)
            if head[4:8] == b"ftyp":
                return _read_isobmff(f, head)
    except (OSError, ValueError, struct.error, IndexError, zlib.error):
        return None
    return None


def _read_exact(f, n: int) -> bytes:  # noqa: ANN001 - a binary file
    if n > _MAX_META_READ:
        raise ValueError("metadata block too large")
    data = f.read(n)
    if len(data) != n:
        raise ValueError("truncated")
    return data


def _read_jpeg(f) -> Marker | None:  # noqa: ANN001
    f.seek(2)
    while True:
        b = f.read(2)
        if len(b) < 2 or b[0] != 0xFF:
            return None
        if b[1] == 0xFF:
            f.seek(-1, 1)
            continue
        if b[1] in (0xDA, 0xD9):
            return None
        (length,) = struct.unpack(">H", _read_exact(f, 2))
        if b[1] == 0xE1 and length > 2 + len(_XMP_JPEG_HEADER):
            payload = _read_exact(f, length - 2)
            if payload.startswith(_XMP_JPEG_HEADER):
                found = marker_from_xmp(payload)
                if found:
                    return found
        else:
            f.seek(length - 2, 1)


def _read_png(f) -> Marker | None:  # noqa: ANN001
    f.seek(len(_PNG_SIGNATURE))
    own = PNG_KEYWORD + b"\x00"
    while True:
        head = f.read(8)
        if len(head) < 8:
            return None
        length, ctype = struct.unpack(">I", head[:4])[0], head[4:]
        if ctype == b"IEND":
            return None
        if ctype == b"iTXt" and length < 65536:
            body = _read_exact(f, length)
            f.seek(4, 1)
            if body.startswith(own):
                return Marker.from_json(body[len(own) + 4 :])
        else:
            f.seek(length + 4, 1)


def _read_webp(f) -> Marker | None:  # noqa: ANN001
    f.seek(12)
    while True:
        head = f.read(8)
        if len(head) < 8:
            return None
        ctype, (size,) = head[:4], struct.unpack("<I", head[4:])
        if ctype == b"XMP ":
            return marker_from_xmp(_read_exact(f, size))
        f.seek(size + (size & 1), 1)


def _read_tiff(f, head: bytes) -> Marker | None:  # noqa: ANN001
    bo = "<" if head[:2] == b"II" else ">"
    (ifd,) = struct.unpack(bo + "I", head[4:8])
    f.seek(ifd)
    (count,) = struct.unpack(bo + "H", _read_exact(f, 2))
    entries = _read_exact(f, 12 * count)
    for i in range(count):
        tag, typ, n, value = struct.unpack(bo + "HHII", entries[12 * i : 12 * i + 12])
        if tag == 700:
            size = n * (1 if typ in (1, 2, 7) else 2 if typ == 3 else 4)
            if size <= 4:
                return None
            f.seek(value)
            return marker_from_xmp(_read_exact(f, size))
    return None


def _read_isobmff(f, head: bytes) -> Marker | None:  # noqa: ANN001
    """MP4/MOV: ppd's top-level uuid box. HEIF/AVIF: the XMP item, found by searching the file's
    bytes for ppd's description (HEIF files are small; no item-location parsing)."""
    brand = head[8:12]
    f.seek(0, 2)
    size = f.tell()
    if brand in (b"heic", b"heix", b"mif1", b"msf1", b"avif", b"avis", b"heim", b"heis"):
        if size > 64 * 1024 * 1024:
            return None
        f.seek(0)
        data = f.read()
        at = data.find(b'xmlns:ppd="' + NS.encode())
        if at < 0:
            return None
        start = data.rfind(b"<rdf:Description", 0, at)
        end = data.find(b"/>", at)
        return marker_from_xmp(data[start : end + 2]) if start >= 0 and end > 0 else None
    pos = 0
    while pos + 8 <= size:
        f.seek(pos)
        box = _read_exact(f, 8)
        (length,) = struct.unpack(">I", box[:4])
        if length == 1:
            (length,) = struct.unpack(">Q", _read_exact(f, 8))
        elif length == 0:
            length = size - pos
        if length < 8:
            return None
        if box[4:8] == b"uuid" and length < 65536:
            body = _read_exact(f, length - 8)
            if body.startswith(MP4_UUID):
                return Marker.from_json(body[16:])
        pos += length
    return None


def _vint(f, keep_marker: bool) -> tuple[int, int]:  # noqa: ANN001
    """(value, length) of an EBML variable-size integer; value -1 for an unknown size."""
    first = f.read(1)
    if not first:
        raise ValueError("EOF")
    b0 = first[0]
    length = 1
    while length <= 8 and not b0 & (0x80 >> (length - 1)):
        length += 1
    if length > 8:
        raise ValueError("bad EBML vint")
    rest = _read_exact(f, length - 1)
    value = b0 if keep_marker else b0 & (0xFF >> length)
    for byte in rest:
        value = (value << 8) | byte
    if not keep_marker and value == (1 << (7 * length)) - 1:
        return -1, length
    return value, length


def _read_matroska(f) -> Marker | None:  # noqa: ANN001
    f.seek(0)
    _vint(f, True)
    size, _ = _vint(f, False)
    f.seek(size, 1)
    seg_id, _ = _vint(f, True)
    if seg_id != 0x18538067:
        return None
    seg_size, _ = _vint(f, False)
    seg_start = f.tell()
    seg_end = seg_start + seg_size if seg_size >= 0 else None
    while seg_end is None or f.tell() < seg_end:
        try:
            eid, _ = _vint(f, True)
            esize, _ = _vint(f, False)
        except ValueError:
            return None
        if esize < 0:
            return None  # an element of unknown size (a live cluster): nothing to skip to
        if eid == 0x1254C367:  # Tags
            return _marker_in_tags(_read_exact(f, esize))
        f.seek(esize, 1)
    return None


def _ebml_children(data: bytes) -> list[tuple[int, bytes]]:
    import io

    out: list[tuple[int, bytes]] = []
    f = io.BytesIO(data)
    while f.tell() < len(data):
        eid, _ = _vint(f, True)
        size, _ = _vint(f, False)
        if size < 0:
            break
        out.append((eid, f.read(size)))
    return out


def _marker_in_tags(tags: bytes) -> Marker | None:
    for eid, tag in _ebml_children(tags):
        if eid != 0x7373:
            continue
        for sid, simple in _ebml_children(tag):
            if sid != 0x67C8:
                continue
            fields = dict(_ebml_children(simple))
            if fields.get(0x45A3, b"").decode("utf-8", "replace").upper() == MKV_TAG:
                return Marker.from_json(fields.get(0x4487, b""))
    return None


__all__ = ["Marker", "NS", "read_marker", "xmp_with_marker", "embed_jpeg", "embed_png", "mp4_box"]
