"""Provenance seal: a patched file says that ppd wrote exactly these bytes, to ppd and nobody else.

What a patched file carries is one opaque token (its *seal*), the same ASCII text in every carrier:

    MAGIC NN BODY TAG      NN: two hex digits, BODY's length in bytes; BODY and TAG in hex
    BODY = version (1 byte) || id (16 bytes) || ciphertext of "original sha256 \\0 spec id"
    id   = HMAC(key, "id" || plaintext)[:16]; ciphertext = plaintext XOR an HMAC keystream from id
           (a deterministic SIV construction: the same inputs give the same token, so poisoning
           stays deterministic and an interrupted run can be redone and compared byte for byte)
    TAG  = HMAC-SHA256(key, "mac" || id || the file's bytes without TAG's own 64 characters and,
           in a PNG, without the CRC of the chunk that holds it)

The key is the installation's secret (daemon.store.sealkey, 0600 in the data folder). Without it the
token names no tool and no hash, and cannot be made: a token copied into another photo, or left in
a cropped or edited one, does not fit the other bytes, so such a file is a new photo. MAGIC, NS and
the carriers' names are the same in every installation, so that a file sealed with another key is
told from a new photo (never marked twice): they tell whoever knows ppd that a file is ppd's output
(a black-box review; said in the README), never its original or its hash.

Writing is two steps: the poisoners embed a placeholder (`Marker`: TAG all zeros); the caller then
seals the finished file in place (`seal_file`: one read of the file, 64 bytes written, a PNG
chunk's CRC rewritten). Reading (`read_seal`) finds the token by its magic anywhere in the file
(mmap; no format parsing, so every carrier is read alike), checks the id first (cheap: a random
or foreign token fails there) and then the tag over the whole file (one pass, about a sha256).

Where the token lives:
- JPEG, WebP, TIFF, HEIC/AVIF: XMP, one `rdf:Description` in the namespace NS with one attribute,
  added to the source's packet (the rest kept as it was) or a new minimal packet; a JPEG packet with
  no room left in its 64 KB segment: its padding, else a comment (COM) segment (embed_jpeg);
- PNG: an uncompressed iTXt chunk (keyword PNG_KEYWORD) right after IHDR;
- MP4/MOV: a top-level `uuid` box (MP4_UUID) appended after the last box (no offset moves);
- Matroska/WebM: a container tag MKV_TAG.
Markers of earlier versions (a clear "ppd:" description, iTXt "ppd:provenance", tag
PPD_PROVENANCE) are never trusted; they are removed when a file is patched.
"""

from __future__ import annotations

import hashlib
import hmac
import mmap
import os
import re
import stat
import struct
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from poisoner.errors import ExitStatus, PpdError

_Bytes = mmap.mmap | bytearray  # a file's bytes: mapped (a file sealed or read in place) or in memory

NS = "urn:uuid:5e1f0c3a-92d4-4b7e-8a61-3c0f9d2b7e14"
PNG_KEYWORD = b"sl"
MKV_TAG = "SL"
MP4_UUID = bytes.fromhex("5e1f0c3a92d44b7e8a613c0f9d2b7e14")
LEGACY_NS = "http://ns.ppd.invalid/provenance/1.0/"  # earlier versions' clear marker (removed)
LEGACY_PNG_KEYWORD = b"ppd:provenance"
MKV_TAGS = (MKV_TAG, "PPD_PROVENANCE")  # a tag with one of these names is never copied

MAGIC = b"zQ7kS1"
VERSION = 1
KEY_BYTES = 32
_ID = 16
_TAG_HEX = 64
_ZERO_TAG = b"0" * _TAG_HEX
_MAX_TOKENS = 8  # tokens tried per file: each costs one pass over it
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_XMP_JPEG_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
_HEX = frozenset(b"0123456789abcdef")


class SealError(PpdError, ValueError):
    """A file that should carry a seal placeholder does not (nothing was written)."""

    exit_status = ExitStatus.FAILED


@dataclass(frozen=True)
class Marker:
    """What the poisoners embed: the seal's placeholder text (TAG all zeros), opaque to them."""

    text: str

    @staticmethod
    def placeholder(key: bytes, spec_id: str, original_sha256: str) -> Marker:
        plain = original_sha256.encode() + b"\0" + spec_id.encode()
        ident = _mac(key, b"id", plain)[:_ID]
        body = bytes([VERSION]) + ident + _xor(plain, _keystream(key, ident, len(plain)))
        if len(body) > 255:
            raise ValueError("spec id too long for a seal")
        return Marker((MAGIC + b"%02x" % len(body) + body.hex().encode() + _ZERO_TAG).decode())


@dataclass(frozen=True)
class Seal:
    """What a verified seal says: the original ppd kept in the vault and the spec it used."""

    original_sha256: str
    spec_id: str


def _mac(key: bytes, label: bytes, data: bytes) -> bytes:
    return hmac.new(key, label + data, hashlib.sha256).digest()


def _keystream(key: bytes, ident: bytes, n: int) -> bytes:
    out = b"".join(_mac(key, b"ks", ident + struct.pack(">I", i)) for i in range((n + 31) // 32))
    return out[:n]


def _xor(a: bytes, b: bytes) -> bytes:
    return bytes(x ^ y for x, y in zip(a, b, strict=True))


# ---- the token in a file -------------------------------------------------------------------------
@dataclass(frozen=True)
class _Token:
    body: bytes
    tag_start: int  # offset of TAG's 64 hex characters in the file
    tag: bytes  # those characters


def _tokens(mm: _Bytes, start: int = 0, end: int | None = None) -> Iterator[_Token]:
    """The well-formed tokens in the file (or those starting in [start, end)), in order (at most
    _MAX_TOKENS), found as they are asked for: sealing stops at its placeholder (in the header)
    instead of searching the rest."""
    found = 0
    end = len(mm) if end is None else end
    at = mm.find(MAGIC, start, end)
    while at >= 0 and found < _MAX_TOKENS:
        pos = at + len(MAGIC)
        head = mm[pos : pos + 2]
        if len(head) == 2 and set(head) <= _HEX:
            n = int(head, 16)
            text = bytes(mm[pos + 2 : pos + 2 + 2 * n + _TAG_HEX])
            if len(text) == 2 * n + _TAG_HEX and set(text) <= _HEX:
                found += 1
                yield _Token(bytes.fromhex(text[: 2 * n].decode()), pos + 2 + 2 * n, text[2 * n :])
        at = mm.find(MAGIC, at + 1, end)


def _open_body(key: bytes, body: bytes) -> Seal | None:
    """The seal's content when BODY was made with this key (its id checks), else None."""
    if len(body) < 1 + _ID or body[0] != VERSION:
        return None
    ident, cipher = body[1 : 1 + _ID], body[1 + _ID :]
    plain = _xor(cipher, _keystream(key, ident, len(cipher)))
    if not hmac.compare_digest(_mac(key, b"id", plain)[:_ID], ident):
        return None
    original, sep, spec_id = plain.partition(b"\0")
    if not sep:
        return None
    try:
        return Seal(original.decode(), spec_id.decode())
    except UnicodeDecodeError:
        return None


def _left_out(mm: _Bytes, tok: _Token) -> list[tuple[int, int]]:
    """The byte ranges the tag does not cover: its own text, and the checksum that covers the
    text's place (a PNG chunk's CRC, a Matroska element's CRC-32), rewritten after sealing."""
    ranges = [(tok.tag_start, tok.tag_start + _TAG_HEX)]
    check = _png_crc_of(mm, tok.tag_start) if mm[:8] == _PNG_SIGNATURE else None
    if check is None and mm[:4] == _EBML_MAGIC:
        check = _ebml_crc_of(mm, tok.tag_start)
    if check is not None:
        ranges.append((check.at, check.at + 4))
    return sorted(ranges)


@dataclass(frozen=True)
class _Checksum:
    at: int  # where its 4 bytes are
    start: int  # the bytes it covers: [start, end)
    end: int
    little_endian: bool


_EBML_MAGIC = b"\x1a\x45\xdf\xa3"


def _png_crc_of(mm: _Bytes, offset: int) -> _Checksum | None:
    """The CRC of the PNG chunk whose data holds offset (over the chunk's type and data)."""
    pos, size = 8, len(mm)
    while pos + 12 <= size:
        (length,) = struct.unpack(">I", mm[pos : pos + 4])
        crc_at = pos + 8 + length
        if pos + 8 <= offset < crc_at:
            return _Checksum(crc_at, pos + 4, crc_at, False) if crc_at + 4 <= size else None
        pos = crc_at + 4
    return None


def _vint(mm: _Bytes, pos: int, keep_marker: bool) -> tuple[int, int]:
    """(value, position after it) of an EBML variable-size integer; value -1 for an unknown size."""
    b0 = mm[pos]
    length = 1
    while length <= 8 and not b0 & (0x80 >> (length - 1)):
        length += 1
    if length > 8:
        raise ValueError("bad EBML vint")
    value = b0 if keep_marker else b0 & (0xFF >> length)
    for byte in mm[pos + 1 : pos + length]:
        value = (value << 8) | byte
    if not keep_marker and value == (1 << (7 * length)) - 1:
        value = -1
    return value, pos + length


def _ebml_crc_of(mm: _Bytes, offset: int) -> _Checksum | None:
    """The CRC-32 child (ID 0xBF) of the Segment's top-level element holding offset, if it has
    one (FFmpeg writes one in each): little-endian, over the rest of the element's data."""
    try:
        _, pos = _vint(mm, 0, True)
        size, pos = _vint(mm, pos, False)
        pos += size  # past the EBML header
        seg_id, pos = _vint(mm, pos, True)
        if seg_id != 0x18538067:
            return None
        _, pos = _vint(mm, pos, False)
        while pos < len(mm):
            _, data = _vint(mm, pos, True)
            size, data = _vint(mm, data, False)
            if size < 0:
                return None
            end = data + size
            if data <= offset < end:
                if mm[data] == 0xBF and mm[data + 1] == 0x84:
                    return _Checksum(data + 2, data + 6, end, True)
                return None
            pos = end
    except (ValueError, IndexError):
        return None
    return None


def _file_tag(key: bytes, mm: _Bytes, tok: _Token) -> bytes:
    h = hmac.new(key, b"mac" + tok.body[1 : 1 + _ID], hashlib.sha256)
    with memoryview(mm) as view:  # no copy of the file's bytes
        pos = 0
        for start, end in _left_out(mm, tok):
            h.update(view[pos:start])
            pos = end
        h.update(view[pos:])
    return h.hexdigest().encode()


def _fix_checksum(mm: _Bytes, tok: _Token) -> None:
    """Rewrite the checksum over the token's place (a PNG chunk's CRC, a Matroska CRC-32)."""
    check = _png_crc_of(mm, tok.tag_start) if mm[:8] == _PNG_SIGNATURE else None
    if check is None and mm[:4] == _EBML_MAGIC:
        check = _ebml_crc_of(mm, tok.tag_start)
    if check is not None:
        crc = zlib.crc32(mm[check.start : check.end])
        mm[check.at : check.at + 4] = struct.pack("<I" if check.little_endian else ">I", crc)


def seal_file(path: Path, key: bytes) -> None:
    """Seal ppd's finished output in place: the placeholder's TAG becomes the file's tag.
    SealError when the file holds no placeholder made with this key. Not fsynced: the caller
    copies the sealed file to its final place and fsyncs that (daemon.protect.stages)."""
    fd = os.open(path, os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        if os.fstat(fd).st_size == 0:
            raise SealError(f"{Path(path).name}: empty file, nothing to seal")
        with mmap.mmap(fd, 0) as mm:
            _seal(mm, key, Path(path).name)
    finally:
        os.close(fd)


def seal_bytes(data: bytearray, key: bytes, name: str) -> None:
    """seal_file for a finished output held in memory, sealed in place (name: the file's, for the
    error): data then holds the bytes seal_file leaves in a file that held them."""
    if not data:
        raise SealError(f"{name}: empty file, nothing to seal")
    _seal(data, key, name)


def _seal(mm: _Bytes, key: bytes, name: str) -> None:
    for tok in _tokens(mm):
        if tok.tag == _ZERO_TAG and _open_body(key, tok.body) is not None:
            mm[tok.tag_start : tok.tag_start + _TAG_HEX] = _file_tag(key, mm, tok)
            _fix_checksum(mm, tok)
            return
    raise SealError(f"{name}: no seal placeholder in the patched file")


def read_seal(path: Path, key: bytes | None) -> Seal | None:
    """The seal of a file ppd wrote with this key, when the file's bytes are exactly those it
    sealed; None for anything else (no token, another key, a copied token, an edited file, an
    unreadable file, no key)."""
    return read_seal_and_claim(path, key)[0]


@dataclass(frozen=True)
class SealScan:
    """What one scan of a file's tokens says (scan_seals)."""

    seal: Seal | None  # read_seal's answer
    claim: Seal | None  # the first token this key opens, verified or not
    other_key: bool  # a token this key does not open: ppd's output sealed with another key


def read_seal_and_claim(path: Path, key: bytes | None) -> tuple[Seal | None, Seal | None]:
    """(read_seal, the claim) from one scan of the file. The claim: what the first token made with this
    key says (the original and spec ppd patched from), whether or not the file's bytes are still those
    it sealed: not proof, a token can be copied onto another photo; the caller checks the picture
    before trusting it (daemon.protect.edited)."""
    scan = scan_seals(path, key)
    return scan.seal, scan.claim


def scan_seals(path: Path, key: bytes | None) -> SealScan:
    """read_seal_and_claim's answers, and whether a token is there that this key does not open. The
    protect stages ask all three of every new file, and a file without a token is read once (1.5 ms of
    a 12 MP JPEG)."""
    if not key:
        return SealScan(None, None, False)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return SealScan(None, None, False)
    claim: Seal | None = None
    other = False
    try:
        if os.fstat(fd).st_size == 0:
            return SealScan(None, None, False)
        with mmap.mmap(fd, 0, access=mmap.ACCESS_READ) as mm:
            for tok in _tokens(mm):
                seal = _open_body(key, tok.body)
                if seal is None:
                    other = True
                    continue
                if hmac.compare_digest(_file_tag(key, mm, tok), tok.tag):
                    return SealScan(seal, seal, False)
                claim = claim or seal
    except (OSError, ValueError):
        return SealScan(None, claim, other)
    finally:
        os.close(fd)
    return SealScan(None, claim, other and claim is None)


_ENDS = 1 << 20  # where a seal is: in a header (photos, Matroska) or the last box (MP4)


def sealing_key(path: Path, keys: Sequence[bytes]) -> int | None:
    """Which of keys made the file's seal (its index), by the token in the file's first or last MB:
    who sealed it, not whether its bytes are still those sealed (no pass over the whole file, so
    cheap on a large store). -1: a token none of keys opens; None: no token there, or no file."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    found: int | None = None
    try:
        with mmap.mmap(fd, 0, access=mmap.ACCESS_READ) as mm:
            for tok in _end_tokens(mm):
                opens = [i for i, key in enumerate(keys) if _open_body(key, tok.body) is not None]
                if opens:
                    return opens[0]
                found = -1
    except (OSError, ValueError):  # an empty file, a FIFO, unreadable
        return found
    finally:
        os.close(fd)
    return found


def _end_tokens(mm: _Bytes) -> Iterator[_Token]:
    """The tokens in the file's first and last _ENDS bytes (the whole file when it is no larger)."""
    size = len(mm)
    spans = [(0, size)] if size <= 2 * _ENDS else [(0, _ENDS), (size - _ENDS, size)]
    return (tok for start, end in spans for tok in _tokens(mm, start, end))


def read_seal_at_ends(path: Path, key: bytes | None) -> tuple[Seal | None, int]:
    """read_seal, for a file whose token (one this key opens) is where ppd puts it, in its first or
    last MB; (None, the bytes looked at) at once for any other: a photo with no token costs at most
    2 MB, not a pass over it (`ppd status` asks it of the files no row names). Also the bytes read: those
    looked at, and the whole file when the tag was checked."""
    if not key:
        return None, 0
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None, 0
    try:
        if not stat.S_ISREG((st := os.fstat(fd)).st_mode) or st.st_size == 0:
            return None, 0
        looked = min(st.st_size, 2 * _ENDS)
        with mmap.mmap(fd, 0, access=mmap.ACCESS_READ) as mm:
            for tok in _end_tokens(mm):
                if (seal := _open_body(key, tok.body)) is None:
                    continue
                looked = st.st_size  # the tag over the whole file decides (one pass), as scan_seals
                if hmac.compare_digest(_file_tag(key, mm, tok), tok.tag):
                    return seal, looked
    except (OSError, ValueError):
        return None, 0
    finally:
        os.close(fd)
    return None, looked


def sealed_for(path: Path, key: bytes | None, original_sha256: str, spec_id: str) -> bool:
    """Whether path is ppd's finished output of that original under that spec: its seal verifies over
    exactly its bytes (read_seal) and names both."""
    seal = read_seal(path, key)
    return seal is not None and (seal.original_sha256, seal.spec_id) == (original_sha256, spec_id)


def has_token(path: Path) -> bool:
    """Whether the file carries anything shaped like a seal (verified or not, any key): tests, benches,
    and `ppd restore`, which says of such a file that another key sealed it."""
    try:
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            return next(_tokens(mm), None) is not None
    except (OSError, ValueError):
        return False


# ---- XMP -----------------------------------------------------------------------------------------
def _description_pattern(ns: str) -> re.Pattern[bytes]:
    return re.compile(rb"<rdf:Description\s[^>]*xmlns:\w+=\"" + re.escape(ns.encode()) + rb"\"[^>]*/>\s*")


_OWN_DESCRIPTIONS = (_description_pattern(NS), _description_pattern(LEGACY_NS))
_RDF_CLOSE = re.compile(rb"</([A-Za-z_][\w.-]*:)?RDF\s*>")


def quoteattr(text: str) -> str:
    """xml.sax.saxutils.quoteattr(text), the same characters (tests/poisoner/test_provenance.py):
    importing xml.sax.saxutils pulls in urllib.request, http.client and ssl (~10 ms of every `ppd
    poison` process) for these few lines."""
    for raw, entity in (("&", "&amp;"), (">", "&gt;"), ("<", "&lt;"), ("\n", "&#10;"), ("\r", "&#13;"),
                        ("\t", "&#9;")):  # fmt: skip
        text = text.replace(raw, entity)
    if '"' not in text:
        return f'"{text}"'
    if "'" not in text:
        return f"'{text}'"
    return '"{}"'.format(text.replace('"', "&quot;"))


def marker_description(marker: Marker) -> bytes:
    return f'<rdf:Description rdf:about="" xmlns:sl="{NS}" sl:k={quoteattr(marker.text)}/>'.encode()


def fresh_xmp(marker: Marker) -> bytes:
    return (
        b'<?xpacket begin="\xef\xbb\xbf" id="W5M0MpCehiHzreSzNTczkc9d"?>'
        b'<x:xmpmeta xmlns:x="adobe:ns:meta/">'
        b'<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        + marker_description(marker)
        + b'</rdf:RDF></x:xmpmeta><?xpacket end="w"?>'
    )


def xmp_without_marker(xmp: bytes) -> bytes:
    """The packet without any seal or earlier clear marker."""
    for pattern in _OWN_DESCRIPTIONS:
        xmp = pattern.sub(b"", xmp)
    return xmp


def xmp_with_marker(xmp: bytes | None, marker: Marker) -> bytes:
    """The packet with the seal's description (replacing an older one or an earlier version's
    clear marker); a new packet when there is none or it has no rdf:RDF element to add to."""
    if not xmp:
        return fresh_xmp(marker)
    xmp = xmp_without_marker(xmp)
    closes = list(_RDF_CLOSE.finditer(xmp))
    if not closes or (closes[-1].group(1) or b"rdf:") != b"rdf:":
        return fresh_xmp(marker)
    at = closes[-1].start()
    return xmp[:at] + marker_description(marker) + xmp[at:]


# ---- embedding -----------------------------------------------------------------------------------
_SEGMENT_MAX = 0xFFFF - 2  # a JPEG segment's payload, at most
_PACKET_END = re.compile(rb"(\s*)<\?xpacket\s+end=")


def embed_jpeg(data: bytes, marker: Marker) -> bytes:
    """The JPEG with the seal in its XMP APP1 segment; the scans are copied verbatim. A packet with
    no room left in its 64 KB segment gives up the padding its writer left for in-place edits (the
    whitespace before `<?xpacket end`, 2 KB from Adobe's writers); one with too little padding is
    kept as it is and the seal goes into a comment (COM) segment after it. A seal an earlier run put
    in a comment is removed either way."""
    from poisoner.location import jpeg_assemble, jpeg_header_segments

    segments, sos = jpeg_header_segments(data)
    segments = [(m, p) for m, p in segments if not (m == 0xFE and p.startswith(MAGIC))]
    room = _SEGMENT_MAX - len(_XMP_JPEG_HEADER)
    for i, (m, payload) in enumerate(segments):
        if m == 0xE1 and payload.startswith(_XMP_JPEG_HEADER):
            xmp = payload[len(_XMP_JPEG_HEADER) :]
            body = _within(xmp_with_marker(xmp, marker), room)
            if body is None:  # the user's packet stays whole (an earlier seal taken out of it)
                segments[i] = (m, _XMP_JPEG_HEADER + xmp_without_marker(xmp))
                segments.insert(i + 1, (0xFE, marker.text.encode()))
            else:
                segments[i] = (m, _XMP_JPEG_HEADER + body)
            break
    else:
        # after the leading APP0/APP1 run (JFIF, EXIF): where XMP conventionally sits
        at = 0
        while at < len(segments) and segments[at][0] in (0xE0, 0xE1):
            at += 1
        segments.insert(at, (0xE1, _XMP_JPEG_HEADER + fresh_xmp(marker)))
    return jpeg_assemble(segments, data, sos)


def _within(xmp: bytes, room: int) -> bytes | None:
    """The packet in `room` bytes, taking what it needs from its trailing padding; None when the
    padding is too short."""
    over = len(xmp) - room
    if over <= 0:
        return xmp
    ends = list(_PACKET_END.finditer(xmp))
    if not ends or len(ends[-1].group(1)) < over:
        return None
    pad_end = ends[-1].end(1)
    return xmp[: pad_end - over] + xmp[pad_end:]


def _png_chunk(ctype: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + ctype + body + struct.pack(">I", zlib.crc32(ctype + body))


def embed_png(data: bytes, marker: Marker) -> bytes:
    """The PNG with an iTXt seal chunk right after IHDR (older seals and earlier clear markers
    removed); every other chunk is copied byte for byte."""
    if not data.startswith(_PNG_SIGNATURE):
        raise ValueError("not a PNG")
    parts = [_PNG_SIGNATURE]
    pos = len(_PNG_SIGNATURE)
    own = (PNG_KEYWORD + b"\x00", LEGACY_PNG_KEYWORD + b"\x00")
    while pos + 12 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        ctype = data[pos + 4 : pos + 8]
        end = pos + 12 + length
        if not (ctype == b"iTXt" and data[pos + 8 : pos + 8 + length].startswith(own)):
            parts.append(data[pos:end])
        if ctype == b"IHDR":
            parts.append(_png_chunk(b"iTXt", own[0] + b"\x00\x00\x00\x00" + marker.text.encode()))
        pos = end
        if ctype == b"IEND":
            break
    return b"".join(parts)


def mp4_box(marker: Marker) -> bytes:
    body = MP4_UUID + marker.text.encode()
    return struct.pack(">I", 8 + len(body)) + b"uuid" + body


__all__ = [
    "Marker", "Seal", "SealError", "NS", "read_seal", "seal_file", "xmp_with_marker", "embed_jpeg",
    "embed_png", "mp4_box",
]  # fmt: skip
