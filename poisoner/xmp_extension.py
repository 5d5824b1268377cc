"""Extended XMP in a JPEG (XMP specification part 3, 1.1.3.1): a packet too large for one 64 KB APP1
segment continues in APP1 segments that begin "http://ns.adobe.com/xmp/extension/\\0", then the
extended packet's GUID (32 hex digits, the MD5 of the whole extended packet), its full length and
this segment's offset in it (4 bytes each, big-endian), then that part of the packet. The main
packet names the GUID in xmpNote:HasExtendedXMP; readers (exiftool, Adobe) merge the two.

Pure byte-level functions: read each extended packet back from its segments, write one as segments.
poisoner.location edits them (location removed).
"""

from __future__ import annotations

import hashlib
import re
import struct
import xml.etree.ElementTree as ET

HEADER = b"http://ns.adobe.com/xmp/extension/\x00"
_FIELDS = struct.Struct(">32sII")  # GUID, full length, offset
# The most of a packet one segment holds: a segment's 65533 bytes less the header and fields.
CHUNK_MAX = 0xFFFF - 2 - len(HEADER) - _FIELDS.size
NS_XMP_NOTE = "http://ns.adobe.com/xmp/note/"  # xmpNote:HasExtendedXMP: the main packet's pointer
_HEX_GUID = re.compile(rb"[0-9A-Fa-f]{32}\Z")
# Namespaces of the packet's frame (x:xmpmeta, rdf:RDF/Description/Bag/li, xml:lang), not properties.
_FRAME = ("{adobe:ns:meta/}", "{http://www.w3.org/1999/02/22-rdf-syntax-ns#}",
          "{http://www.w3.org/XML/1998/namespace}")  # fmt: skip


def guid_of(payload: bytes) -> bytes | None:
    """The GUID an Extended XMP segment gives (what it holds of it when truncated); None when the
    APP1 payload is not one."""
    if not payload.startswith(HEADER):
        return None
    return payload[len(HEADER) : len(HEADER) + 32]


def packets(segments: list[tuple[int, bytes]]) -> dict[bytes, bytes | str]:
    """Each extended packet in these JPEG header segments by GUID: its bytes, read back from its
    segments in offset order, or why it cannot be (segments that disagree, a gap, an overlap, a
    part missing, XML that does not parse)."""
    parts: dict[bytes, list[tuple[int, int, bytes]]] = {}
    broken: dict[bytes, str] = {}
    for marker, payload in segments:
        guid = guid_of(payload) if marker == 0xE1 else None
        if guid is None:
            continue
        fields = payload[len(HEADER) : len(HEADER) + _FIELDS.size]
        if len(fields) < _FIELDS.size:
            broken[guid] = "a segment truncated"
            continue
        _, full, offset = _FIELDS.unpack(fields)
        parts.setdefault(guid, []).append((full, offset, payload[len(HEADER) + _FIELDS.size :]))
    found: dict[bytes, bytes | str] = dict(broken)
    for guid, chunks in parts.items():
        if guid not in broken:
            found[guid] = _reassembled(guid, chunks)
    return found


def _reassembled(guid: bytes, chunks: list[tuple[int, int, bytes]]) -> bytes | str:
    if not _HEX_GUID.match(guid):
        return "its GUID is not 32 hex digits"
    lengths = {full for full, _, _ in chunks}
    if len(lengths) != 1:
        return "its segments disagree on the packet's length"
    (full,) = lengths
    packet = bytearray()
    for _, offset, chunk in sorted(chunks, key=lambda c: c[1]):
        if offset != len(packet):
            return f"a segment at offset {offset} where {len(packet)} was due (a gap or an overlap)"
        packet += chunk
    if len(packet) != full:
        return f"{len(packet)} of its {full} bytes present"
    problem = xml_error(bytes(packet))
    return f"not well-formed XML ({problem})" if problem else bytes(packet)


def xml_error(packet: bytes) -> str | None:
    """Why the packet does not parse as XML; None when it does. (Expat, 2.4 on: entity expansion is
    bounded, no external entity is fetched.)"""
    try:
        ET.fromstring(packet)
    except (ET.ParseError, ValueError, LookupError) as exc:
        return str(exc)
    return None


def has_properties(packet: bytes) -> bool:
    """Whether a packet that parses holds any property (an element or attribute outside the frame)."""
    for element in ET.fromstring(packet).iter():
        if not element.tag.startswith(_FRAME) or any(not a.startswith(_FRAME) for a in element.attrib):
            return True
    return False


def segments_of(packet: bytes) -> tuple[bytes, list[bytes]]:
    """(the packet's GUID: the MD5 of its bytes as the spec says, the APP1 payloads that carry it)."""
    guid = hashlib.md5(packet, usedforsecurity=False).hexdigest().upper().encode()
    return guid, [
        HEADER + _FIELDS.pack(guid, len(packet), at) + packet[at : at + CHUNK_MAX]
        for at in range(0, len(packet), CHUNK_MAX)
    ]


def repoint(xmp: bytes, qnames: list[bytes], old: bytes, new: bytes | None) -> bytes:
    """The main packet with its pointer (xmpNote:HasExtendedXMP, by the qualified names it uses)
    naming `new` where it named `old`; without that pointer when new is None."""
    out = xmp
    for q in qnames:
        qe, guid = re.escape(q), re.escape(old)
        attr = rb"""(\s""" + qe + rb"""\s*=\s*["'])\s*""" + guid + rb"""\s*(["'])"""
        element = rb"(<" + qe + rb"(?:\s[^>]*)?>)\s*" + guid + rb"\s*(</" + qe + rb"\s*>)"
        for pattern in (attr, element):
            out = re.sub(pattern, b"" if new is None else rb"\g<1>" + new + rb"\g<2>", out, flags=re.I)
    return out
