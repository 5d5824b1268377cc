"""Location privacy: remove where a picture was taken from its metadata, change nothing else.

Pure byte-level functions, one per metadata carrier; poisoner.formats and poisoner.video call
them on the protected output (docs/FORMATS.md, "Location"). What counts as location:
- EXIF: the GPS IFD (IFD0 tag 0x8825). The pointer entry is taken out of IFD0 and the GPS IFD
  with its out-of-line values is overwritten with zeros, *in place*: every other offset in the
  block stays valid and the block keeps its length (so a JPEG keeps its segment sizes).
- XMP: every property whose local name starts with "GPS" (exif:GPSLatitude, Iptc4xmpExt:GPS...,
  DJI's drone-dji:GpsLatitude), and the named-place properties of photoshop (City, State,
  Country), Iptc4xmpCore (Location, CountryCode), Iptc4xmpExt (LocationCreated, LocationShown,
  City, ProvinceState, CountryName, ...) and DJI's altitudes. Removed as text, the rest of the
  packet is untouched (no re-serialisation, so prefixes and layout stay as the source had them).
  A JPEG's Extended XMP (poisoner.xmp_extension) too: its packet written again in segments under
  its new GUID, the main packet's pointer with it; dropped with the pointer when nothing else is
  left in it, or when it cannot be read back.
- IPTC-IIM (JPEG APP13 "Photoshop 3.0" resource 0x0404, TIFF tag 33723): datasets 2:26, 2:27
  (content location), 2:90 City, 2:92 Sublocation, 2:95 Province/State, 2:100/2:101 Country.
- PNG: eXIf, iTXt "XML:com.adobe.xmp", and ImageMagick's "Raw profile type exif/APP1/xmp" text;
  text chunks keyed by such an XMP property (exif:GPSLatitude, photoshop:City), as converters write
  EXIF/XMP properties.
- Video: container and stream tags whose key names a place (location, ©xyz, ISO6709, GPS).

A carrier that cannot be parsed is dropped whole (fail closed: a block we cannot read could hold
GPS); the caller reports it.
"""

from __future__ import annotations

import re
import struct
import zlib
from collections.abc import Callable

from poisoner import xmp_extension
from poisoner.errors import ExitStatus, PpdError

EXIF_HEADER = b"Exif\x00\x00"
GPS_IFD_TAG = 0x8825
XMP_JPEG_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
XMP_PNG_KEYWORD = b"XML:com.adobe.xmp"

# Cap on decompressing a PNG text chunk (a deflate bomb must not decide our memory).
MAX_TEXT_INFLATE = 8 * 1024 * 1024

TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4}


class MetadataParseError(PpdError, ValueError):
    """A metadata block too malformed to edit safely."""

    exit_status = ExitStatus.FAILED


# ---- EXIF ----------------------------------------------------------------------------------------
def exif_has_gps(exif: bytes) -> bool:
    try:
        return _find_gps(exif) is not None
    except MetadataParseError:
        return False


def tiff_base(exif: bytes) -> tuple[int, str]:
    base = len(EXIF_HEADER) if exif.startswith(EXIF_HEADER) else 0
    order = exif[base : base + 2]
    if order == b"II":
        return base, "<"
    if order == b"MM":
        return base, ">"
    raise MetadataParseError("EXIF without a TIFF header")


def _find_gps(exif: bytes) -> tuple[int, str, int, int, int] | None:
    """(tiff base, byte order, IFD0 offset, IFD0 entry count, index of the GPS entry) or None."""
    base, bo = tiff_base(exif)
    if len(exif) < base + 8:
        raise MetadataParseError("EXIF header truncated")
    (ifd0,) = struct.unpack(bo + "I", exif[base + 4 : base + 8])
    start = base + ifd0
    if start + 2 > len(exif):
        raise MetadataParseError("EXIF IFD0 outside the block")
    (count,) = struct.unpack(bo + "H", exif[start : start + 2])
    if start + 2 + 12 * count + 4 > len(exif):
        raise MetadataParseError("EXIF IFD0 truncated")
    for i in range(count):
        (tag,) = struct.unpack(bo + "H", exif[start + 2 + 12 * i : start + 4 + 12 * i])
        if tag == GPS_IFD_TAG:
            return base, bo, start, count, i
    return None


def strip_exif_gps(exif: bytes) -> tuple[bytes, bool]:
    """(EXIF without its GPS IFD, whether one was removed); same length, other bytes unchanged.
    Raises MetadataParseError when the block cannot be parsed."""
    found = _find_gps(exif)
    if found is None:
        return exif, False
    base, bo, start, count, index = found
    out = bytearray(exif)
    entry = start + 2 + 12 * index
    (gps_offset,) = struct.unpack(bo + "I", exif[entry + 8 : entry + 12])
    zero_ifd(out, base, bo, base + gps_offset)
    # Take the entry out of IFD0: later entries and the next-IFD pointer move up 12 bytes;
    # the freed 12 bytes at the end become zeros (nothing points there).
    tail_end = start + 2 + 12 * count + 4
    out[entry:tail_end] = exif[entry + 12 : tail_end] + bytes(12)
    out[start : start + 2] = struct.pack(bo + "H", count - 1)
    return bytes(out), True


def zero_ifd(buf: bytearray, base: int, bo: str, pos: int) -> None:
    if pos + 2 > len(buf):
        return  # a dangling pointer: nothing there to erase
    (count,) = struct.unpack(bo + "H", buf[pos : pos + 2])
    end = min(pos + 2 + 12 * count + 4, len(buf))
    for i in range(count):
        e = pos + 2 + 12 * i
        if e + 12 > len(buf):
            break
        typ, n = struct.unpack(bo + "HI", buf[e + 2 : e + 8])
        size = TYPE_SIZES.get(typ, 1) * n
        if size > 4:
            (off,) = struct.unpack(bo + "I", buf[e + 8 : e + 12])
            lo, hi = base + off, min(base + off + size, len(buf))
            if lo < hi:
                buf[lo:hi] = bytes(hi - lo)
    buf[pos:end] = bytes(end - pos)


def clean_exif(exif: bytes) -> tuple[bytes | None, list[str]]:
    """EXIF for the protected file: GPS removed; None (drop the block) when it cannot be parsed."""
    try:
        out, removed = strip_exif_gps(exif)
    except MetadataParseError as exc:
        return None, [f"EXIF dropped: unreadable, could hold GPS ({exc})"]
    return out, ["EXIF GPS IFD"] if removed else []


# ---- XMP -----------------------------------------------------------------------------------------
_NS_EXIF = "http://ns.adobe.com/exif/1.0/"
_NS_PHOTOSHOP = "http://ns.adobe.com/photoshop/1.0/"
_NS_IPTC_CORE = "http://iptc.org/std/Iptc4xmpCore/1.0/xmlns/"
_NS_IPTC_EXT = "http://iptc.org/std/Iptc4xmpExt/2008-02-29/"
_NS_DJI = "http://www.dji.com/drone-dji/1.0/"
_XMP_PLACE_PROPS: dict[str, frozenset[str]] = {
    _NS_PHOTOSHOP: frozenset({"City", "State", "Country"}),
    _NS_IPTC_CORE: frozenset({"Location", "CountryCode"}),
    _NS_IPTC_EXT: frozenset(
        {
            "LocationCreated",
            "LocationShown",
            "City",
            "CountryName",
            "CountryCode",
            "ProvinceState",
            "Sublocation",
            "WorldRegion",
            "LocationName",
            "LocationId",
        }
    ),
    _NS_DJI: frozenset({"AbsoluteAltitude", "RelativeAltitude"}),
}
_XMLNS = re.compile(rb"""xmlns:([A-Za-z_][\w.-]*)\s*=\s*["']([^"']*)["']""")
_QNAME = rb"[A-Za-z_][\w.-]*:[A-Za-z_][\w.-]*"


def _place(namespace: str, local: str) -> bool:
    """Whether the property namespace:local carries a location."""
    return local.lower().startswith("gps") or local in _XMP_PLACE_PROPS.get(namespace, ())


def _location_qnames(xmp: bytes) -> set[bytes]:
    """Qualified names (prefix:local) in this packet that carry a location."""
    return xmp_qnames(xmp, _place)


def xmp_qnames(xmp: bytes, wanted: Callable[[str, str], bool]) -> set[bytes]:
    """Qualified names (prefix:local) of elements and attributes in this packet for which
    wanted(namespace URI, local name) holds (the prefix as the packet binds it)."""
    names: set[bytes] = set()
    prefixes: dict[bytes, str] = {p: uri.decode("latin-1") for p, uri in _XMLNS.findall(xmp)}
    for qname in set(re.findall(rb"<(" + _QNAME + rb")|\s(" + _QNAME + rb")\s*=", xmp)):
        q = qname[0] or qname[1]
        prefix, local = q.split(b":", 1)
        if prefix in (b"xmlns", b"xml", b"rdf", b"x"):
            continue
        if wanted(prefixes.get(prefix, ""), local.decode("latin-1")):
            names.add(q)
    return names


def strip_xmp_location(xmp: bytes) -> tuple[bytes, list[str]]:
    """(XMP without location properties, the qualified names removed). Elements are removed with
    their content; attribute-form properties with their value."""
    names = sorted(_location_qnames(xmp))
    return strip_xmp_names(xmp, names), [f"XMP {q.decode('latin-1')}" for q in names]


def strip_xmp_names(xmp: bytes, names: list[bytes]) -> bytes:
    """The packet without these qualified names' elements (with their content) and attributes."""
    out = xmp
    for q in names:
        qe = re.escape(q)
        out = re.sub(rb"<" + qe + rb"(?:\s[^>]*)?/>", b"", out)
        out = re.sub(rb"<" + qe + rb"(?:\s[^>]*)?>.*?</" + qe + rb"\s*>", b"", out, flags=re.S)
        out = re.sub(rb"\s" + qe + rb"""\s*=\s*(?:"[^"]*"|'[^']*')""", b"", out)
    return out


# ---- IPTC-IIM ------------------------------------------------------------------------------------
IIM_LOCATION_DATASETS = frozenset({26, 27, 90, 92, 95, 100, 101})  # record 2
PHOTOSHOP_HEADER = b"Photoshop 3.0\x00"


def strip_iim_location(iim: bytes) -> tuple[bytes, list[str]]:
    """IPTC-IIM datasets without record 2's location datasets. Raises MetadataParseError."""
    out = bytearray()
    removed: list[str] = []
    pos = 0
    while pos < len(iim):
        if iim[pos] != 0x1C:
            if not iim[pos:].strip(b"\x00"):
                out += iim[pos:]  # trailing padding
                break
            raise MetadataParseError("IPTC-IIM dataset marker expected")
        if pos + 5 > len(iim):
            raise MetadataParseError("IPTC-IIM truncated")
        record, dataset = iim[pos + 1], iim[pos + 2]
        (length,) = struct.unpack(">H", iim[pos + 3 : pos + 5])
        head = 5
        if length & 0x8000:  # extended dataset: the length's length
            n = length & 0x7FFF
            if n > 8 or pos + 5 + n > len(iim):
                raise MetadataParseError("IPTC-IIM extended length malformed")
            length = int.from_bytes(iim[pos + 5 : pos + 5 + n], "big")
            head += n
        end = pos + head + length
        if end > len(iim):
            raise MetadataParseError("IPTC-IIM dataset runs past the block")
        if record == 2 and dataset in IIM_LOCATION_DATASETS:
            removed.append(f"IPTC 2:{dataset}")
        else:
            out += iim[pos:end]
        pos = end
    return bytes(out), removed


def strip_photoshop_location(block: bytes) -> tuple[bytes, list[str]]:
    """A Photoshop image-resource block (JPEG APP13 payload, with or without its header) with the
    IPTC resource (0x0404) cleaned. Raises MetadataParseError."""
    head = PHOTOSHOP_HEADER if block.startswith(PHOTOSHOP_HEADER) else b""
    pos = len(head)
    out = bytearray(head)
    removed: list[str] = []
    while pos < len(block):
        if block[pos : pos + 4] != b"8BIM":
            if not block[pos:].strip(b"\x00"):
                out += block[pos:]
                break
            raise MetadataParseError("Photoshop resource signature expected")
        if pos + 7 > len(block):
            raise MetadataParseError("Photoshop resource truncated")
        (rid,) = struct.unpack(">H", block[pos + 4 : pos + 6])
        name_len = block[pos + 6]
        name_end = pos + 6 + ((1 + name_len + 1) & ~1)
        if name_end + 4 > len(block):
            raise MetadataParseError("Photoshop resource truncated")
        (size,) = struct.unpack(">I", block[name_end : name_end + 4])
        data = block[name_end + 4 : name_end + 4 + size]
        if len(data) != size:
            raise MetadataParseError("Photoshop resource runs past the block")
        end = name_end + 4 + size + (size & 1)
        if rid == 0x0404:
            data, gone = strip_iim_location(data)
            removed += gone
            out += block[pos:name_end] + struct.pack(">I", len(data)) + data + b"\x00" * (len(data) & 1)
        else:
            out += block[pos:end]
        pos = end
    return bytes(out), removed


# ---- JPEG ----------------------------------------------------------------------------------------
def jpeg_header_segments(data: bytes) -> tuple[list[tuple[int, bytes]], int]:
    """([(marker, payload)] of every segment before the first SOS, offset of that SOS).
    Raises MetadataParseError on a malformed header."""
    if data[:2] != b"\xff\xd8":
        raise MetadataParseError("not a JPEG")
    pos = 2
    segments: list[tuple[int, bytes]] = []
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            raise MetadataParseError(f"JPEG marker expected at byte {pos}")
        marker = data[pos + 1]
        if marker == 0xFF:
            pos += 1
            continue
        if marker in (0xDA, 0xD9):
            return segments, pos
        (length,) = struct.unpack(">H", data[pos + 2 : pos + 4])
        if length < 2 or pos + 2 + length > len(data):
            raise MetadataParseError("JPEG header truncated")
        segments.append((marker, data[pos + 4 : pos + 2 + length]))
        pos += 2 + length
    raise MetadataParseError("JPEG without a scan")


def jpeg_assemble(segments: list[tuple[int, bytes]], data: bytes, sos: int) -> bytes:
    parts = [b"\xff\xd8"]
    for marker, payload in segments:
        if len(payload) + 2 > 0xFFFF:
            raise MetadataParseError(f"JPEG segment 0x{marker:02X} over 64 KB")
        parts.append(bytes((0xFF, marker)) + struct.pack(">H", len(payload) + 2) + payload)
    parts.append(data[sos:])
    return b"".join(parts)


def clean_jpeg_segments(segments: list[tuple[int, bytes]]) -> tuple[list[tuple[int, bytes]], list[str]]:
    """Segments with location removed from EXIF (APP1), XMP (APP1, Extended XMP too) and IPTC (APP13)."""
    out: list[tuple[int, bytes]] = []
    written, pointers, removed = _clean_extended_xmp(segments)
    for marker, payload in segments:
        guid = xmp_extension.guid_of(payload) if marker == 0xE1 else None
        if guid is not None and guid in written:
            out += [(0xE1, part) for part in written.pop(guid)]  # at its first segment, once
            continue
        if guid is not None and guid in pointers:
            continue  # a later segment of an extended packet written again (or dropped)
        if marker == 0xE1 and payload.startswith(EXIF_HEADER):
            cleaned, gone = clean_exif(payload)
            removed += gone
            if cleaned is None:
                continue
            payload = cleaned
        elif marker == 0xE1 and payload.startswith(XMP_JPEG_HEADER):
            body, gone = strip_xmp_location(payload[len(XMP_JPEG_HEADER) :])
            removed += gone
            pointer = sorted(xmp_qnames(body, _extension_pointer))
            for old, new in pointers.items():
                body = xmp_extension.repoint(body, pointer, old, new)
            payload = XMP_JPEG_HEADER + body
        elif marker == 0xED and payload.startswith(PHOTOSHOP_HEADER):
            try:
                payload, gone = strip_photoshop_location(payload)
            except MetadataParseError as exc:
                removed.append(f"IPTC/Photoshop segment dropped: unreadable, could hold a place ({exc})")
                continue
            removed += gone
        out.append((marker, payload))
    return out, removed


def _clean_extended_xmp(
    segments: list[tuple[int, bytes]],
) -> tuple[dict[bytes, list[bytes]], dict[bytes, bytes | None], list[str]]:
    """The Extended XMP packets that held location, without it: (by old GUID, the APP1 payloads that
    replace its segments, none when it goes; by old GUID, what the main packet's pointer names now,
    None when it goes; what was removed). A packet that cannot be read back goes whole (it could
    hold GPS), and one left with no property goes with its pointer."""
    written: dict[bytes, list[bytes]] = {}
    pointers: dict[bytes, bytes | None] = {}
    removed: list[str] = []
    for guid, packet in xmp_extension.packets(segments).items():
        if isinstance(packet, str):
            written[guid], pointers[guid] = [], None
            removed.append(f"Extended XMP dropped: unreadable, could hold location ({packet})")
            continue
        body, gone = strip_xmp_location(packet)
        if not gone:
            continue
        removed += [f"Extended {g}" for g in gone]
        problem = xmp_extension.xml_error(body)
        if problem is not None or not xmp_extension.has_properties(body):
            written[guid], pointers[guid] = [], None
            if problem is not None:
                removed.append(f"Extended XMP dropped: not XML once location was removed ({problem})")
            continue
        pointers[guid], written[guid] = xmp_extension.segments_of(body)
    return written, pointers, removed


def _extension_pointer(namespace: str, local: str) -> bool:
    return namespace == xmp_extension.NS_XMP_NOTE and local == "HasExtendedXMP"


def strip_jpeg_location(data: bytes) -> tuple[bytes, list[str]]:
    """The JPEG with location removed from its header segments; the scans are copied verbatim."""
    segments, sos = jpeg_header_segments(data)
    cleaned, removed = clean_jpeg_segments(segments)
    if not removed:
        return data, []
    return jpeg_assemble(cleaned, data, sos), removed


# ---- PNG -----------------------------------------------------------------------------------------
def inflate_bounded(data: bytes, limit: int = MAX_TEXT_INFLATE) -> bytes:
    d = zlib.decompressobj()
    out = d.decompress(data, limit)
    if d.unconsumed_tail:
        raise MetadataParseError(f"compressed text over {limit} bytes")
    return out


def parse_itxt(body: bytes) -> tuple[bytes, int, bytes, bytes]:
    """(keyword, compression flag, the bytes between keyword and text, text (decompressed))."""
    key, _, rest = body.partition(b"\x00")
    if len(rest) < 2:
        raise MetadataParseError("iTXt truncated")
    flag = rest[0]
    lang, _, rest2 = rest[2:].partition(b"\x00")
    tkey, _, text = rest2.partition(b"\x00")
    middle = rest[:2] + lang + b"\x00" + tkey + b"\x00"
    return key, flag, middle, inflate_bounded(text) if flag else text


def build_itxt(key: bytes, flag: int, middle: bytes, text: bytes) -> bytes:
    # level 9, fixed: deterministic output for the same text
    return key + b"\x00" + middle + (zlib.compress(text, 9) if flag else text)


# Text chunks keyed by an XMP property's name (ImageMagick and other converters write EXIF and XMP
# properties so: "exif:GPSLatitude"); the prefix read as XMP conventionally binds it.
PNG_TEXT_CHUNKS = (b"tEXt", b"zTXt", b"iTXt")
_TEXT_KEY_NAMESPACES = {
    "exif": _NS_EXIF,
    "photoshop": _NS_PHOTOSHOP,
    "iptc4xmpcore": _NS_IPTC_CORE,
    "iptc4xmpext": _NS_IPTC_EXT,
    "drone-dji": _NS_DJI,
}


def location_text_key(ctype: bytes, body: bytes) -> str | None:
    """The keyword of a PNG text chunk that names a location property (exif:GPSLatitude,
    photoshop:City), as XMP's rules say; None for any other chunk."""
    if ctype not in PNG_TEXT_CHUNKS:
        return None
    key = body.partition(b"\x00")[0].decode("latin-1")
    prefix, colon, local = key.partition(":")
    if not colon or not local or not _place(_TEXT_KEY_NAMESPACES.get(prefix.lower(), ""), local):
        return None
    return key


_RAW_PROFILE = re.compile(rb"\A\s*(\w+)\s*\n\s*(\d+)\s*\n(.*)\Z", re.S)


# What a PNG text chunk's EXIF and XMP go through: location removed (clean_png_chunk's default), or
# (poisoner.image.previews) the original's thumbnails made the patched picture's.
ExifCleaner = Callable[[bytes], tuple[bytes | None, list[str]]]
XmpCleaner = Callable[[bytes], tuple[bytes, list[str]]]


def _clean_raw_profile(
    kind: bytes, text: bytes, exif_fn: ExifCleaner = clean_exif, xmp_fn: XmpCleaner = strip_xmp_location
) -> tuple[bytes | None, list[str]]:
    """ImageMagick's hex "Raw profile type exif/APP1/xmp" text, location removed (or what the
    cleaners do)."""
    m = _RAW_PROFILE.match(text)
    if not m:
        return None, [f"PNG raw {kind.decode()} profile dropped: unreadable"]
    try:
        blob = bytes.fromhex(m.group(3).decode("ascii"))
    except ValueError:
        return None, [f"PNG raw {kind.decode()} profile dropped: unreadable"]
    if kind == b"xmp":
        new, gone = xmp_fn(blob)
    else:
        exif, gone = exif_fn(blob)
        if exif is None:
            return None, gone
        new = exif
    if not gone:
        return text, []
    hexed = new.hex()
    lines = "\n".join(hexed[i : i + 72] for i in range(0, len(hexed), 72))
    return f"\n{m.group(1).decode()}\n{len(new):8d}\n{lines}\n".encode(), gone


def clean_png_chunk(
    ctype: bytes, body: bytes, exif_fn: ExifCleaner = clean_exif, xmp_fn: XmpCleaner = strip_xmp_location
) -> tuple[bytes | None, list[str]]:
    """A PNG ancillary chunk without location (None: drop the chunk); with other cleaners, their
    work on its EXIF (eXIf, a raw exif/APP1 profile) and XMP (iTXt, a raw xmp profile)."""
    if ctype == b"eXIf":
        return exif_fn(body)
    if ctype not in (b"iTXt", b"zTXt", b"tEXt"):
        return body, []
    try:
        if ctype == b"iTXt":
            key, flag, middle, text = parse_itxt(body)
        else:
            key, _, raw = body.partition(b"\x00")
            flag, middle = 0, b""
            text = inflate_bounded(raw[1:]) if ctype == b"zTXt" else raw
    except (MetadataParseError, zlib.error) as exc:
        key = body.partition(b"\x00")[0]
        if key == XMP_PNG_KEYWORD or key.lower().startswith(b"raw profile type "):
            return None, [f"PNG {ctype.decode()} {key.decode('latin-1')} dropped: unreadable ({exc})"]
        return body, []
    if key == XMP_PNG_KEYWORD:
        new, gone = xmp_fn(text)
    elif key.lower().startswith(b"raw profile type "):
        kind = key[len(b"raw profile type ") :].lower()
        if kind not in (b"exif", b"app1", b"xmp"):
            return body, []
        cleaned, gone = _clean_raw_profile(b"xmp" if kind == b"xmp" else b"exif", text, exif_fn, xmp_fn)
        if cleaned is None:
            return None, gone
        new = cleaned
    else:
        return body, []
    if not gone:
        return body, []
    if ctype == b"iTXt":
        return build_itxt(key, flag, middle, new), gone
    if ctype == b"zTXt":
        return key + b"\x00\x00" + zlib.compress(new, 9), gone
    return key + b"\x00" + new, gone


# ---- video ---------------------------------------------------------------------------------------
_VIDEO_LOCATION_KEY = re.compile(r"location|gps|iso6709|xyz|coordinates|latitude|longitude", re.I)


def is_location_tag(key: str) -> bool:
    """Whether a container/stream metadata key carries a place (MP4 ©xyz is 'location' in FFmpeg,
    Apple's com.apple.quicktime.location.ISO6709, Matroska RECORDING_LOCATION, ...)."""
    return bool(_VIDEO_LOCATION_KEY.search(key))


# Timed-metadata streams that carry GPS tracks: GoPro GPMF, Google CAMM, Apple mebx.
LOCATION_DATA_CODEC_TAGS = frozenset({"gpmd", "camm", "mebx"})
