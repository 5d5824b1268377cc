"""Location in a JPEG's Extended XMP and in PNG text chunks keyed by an XMP property (black-box review
9, F1 and F2): ppd said "location (GPS) removed" while both still published the GPS position.

The files are built byte by byte as Photoshop, exiftool and converters write them; every test looks
for each coordinate and place name anywhere in the output, and checks what a reader would merge."""

from __future__ import annotations

import hashlib
import io
import struct
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner import location
from poisoner.formats import png_chunks, poison_file
from poisoner.spec import PatchSpec

SPEC = PatchSpec(patch_size=40, block_size=4, position="top-left", offset=(8, 8))
EXTENSION = b"http://ns.adobe.com/xmp/extension/\x00"
XAP = b"http://ns.adobe.com/xap/1.0/\x00"
NOTE = "{http://ns.adobe.com/xmp/note/}HasExtendedXMP"
LAT, LON, ALT = "48,51.4978N", "2,17.6705E", "3512/100"
CITY, PLACE = "ExtCity-ppd-test", "ExtSublocation-ppd-test"
PLACE_VALUES = [v.encode() for v in (LAT, LON, ALT, CITY, PLACE)]
NAMESPACES = (
    ' xmlns:exif="http://ns.adobe.com/exif/1.0/" xmlns:photoshop="http://ns.adobe.com/photoshop/1.0/"'
    ' xmlns:Iptc4xmpExt="http://iptc.org/std/Iptc4xmpExt/2008-02-29/" xmlns:dc="http://purl.org/dc/elements/1.1/"'
)
RDF = '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
KEPT = "kept-extended-description " * 4000  # ~100 KB: the packet spans two segments


def extended_packet(kept: bool = True) -> bytes:
    """Location in attribute and element form, the structure (LocationCreated) after the large kept
    property, so in the packet's last segment."""
    description = f"<dc:description>{KEPT}</dc:description>" if kept else ""
    return (
        RDF + '<rdf:Description rdf:about=""' + NAMESPACES
        + f' exif:GPSLatitude="{LAT}" exif:GPSLongitude="{LON}" photoshop:City="{CITY}">'
        + f"<exif:GPSAltitude>{ALT}</exif:GPSAltitude>{description}"
        + '<Iptc4xmpExt:LocationCreated><rdf:Bag><rdf:li rdf:parseType="Resource">'
        + f"<Iptc4xmpExt:Sublocation>{PLACE}</Iptc4xmpExt:Sublocation>"
        + "</rdf:li></rdf:Bag></Iptc4xmpExt:LocationCreated>"
        + "</rdf:Description></rdf:RDF></x:xmpmeta>"
    ).encode()  # fmt: skip


def main_packet(guid: bytes, element: bool) -> bytes:
    pointer = f"<xmpNote:HasExtendedXMP>{guid.decode()}</xmpNote:HasExtendedXMP>" if element else ""
    attribute = "" if element else f' xmpNote:HasExtendedXMP="{guid.decode()}"'
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>' + RDF
        + '<rdf:Description rdf:about="" xmlns:xmpNote="http://ns.adobe.com/xmp/note/"' + NAMESPACES
        + f' exif:GPSLatitude="{LAT}"{attribute}>'
        + f"{pointer}<dc:creator><rdf:Seq><rdf:li>kept-creator</rdf:li></rdf:Seq></dc:creator>"
        + '</rdf:Description></rdf:RDF></x:xmpmeta><?xpacket end="w"?>'
    ).encode()  # fmt: skip


def extension_segments(packet: bytes, guid: bytes, chunk: int = 65000) -> list[bytes]:
    head = EXTENSION + guid + struct.pack(">I", len(packet))
    return [head + struct.pack(">I", at) + packet[at : at + chunk] for at in range(0, len(packet), chunk)]


def jpeg_with(payloads: list[bytes]) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(3).integers(0, 256, (240, 320, 3), dtype=np.uint8)).save(
        buf, "JPEG", quality=90
    )
    data = buf.getvalue()
    segments = b"".join(b"\xff\xe1" + struct.pack(">H", len(p) + 2) + p for p in payloads)
    return data[:2] + segments + data[2:]


def md5_guid(packet: bytes) -> bytes:
    return hashlib.md5(packet, usedforsecurity=False).hexdigest().upper().encode()


def header_app1(data: bytes) -> tuple[list[bytes], list[bytes]]:
    """(main XMP packets, Extended XMP segment payloads) of a JPEG's header."""
    segments, _ = location.jpeg_header_segments(data)
    mains = [p[len(XAP) :] for m, p in segments if m == 0xE1 and p.startswith(XAP)]
    return mains, [p for m, p in segments if m == 0xE1 and p.startswith(EXTENSION)]


def read_back(parts: list[bytes]) -> tuple[bytes, bytes]:
    """(GUID, packet) of Extended XMP segments, checked as a reader checks them: one GUID, one full
    length, offsets that follow one another from 0 to that length."""
    fields = [(p[35:67], *struct.unpack(">II", p[67:75]), p[75:]) for p in parts]
    assert len({f[0] for f in fields}) == 1 and len({f[1] for f in fields}) == 1
    packet = b""
    for _, _, offset, chunk in sorted(fields, key=lambda f: f[2]):
        assert offset == len(packet)
        packet += chunk
    assert len(packet) == fields[0][1]
    return fields[0][0], packet


def joined(notes: list[str]) -> str:
    return " ".join(" ".join(notes).split())


def poisoned(tmp_path: Path, data: bytes, **options: bool) -> tuple[bytes, list[str], list[str]]:
    src, dst = tmp_path / "a.jpg", tmp_path / ("k.jpg" if options else "out.jpg")
    src.write_bytes(data)
    report = poison_file(src, dst, SPEC, **options)
    return dst.read_bytes(), report.location_removed, report.notes


@pytest.mark.parametrize("element", [False, True], ids=["pointer-attribute", "pointer-element"])
def test_location_in_extended_xmp_is_removed_and_the_packet_written_again(
    tmp_path: Path, element: bool
) -> None:
    packet = extended_packet()
    guid = md5_guid(packet)
    parts = extension_segments(packet, guid)
    source = jpeg_with([XAP + main_packet(guid, element), *parts])
    assert len(parts) == 2 and PLACE.encode() in parts[1]  # the fixture spans segments, a place in each
    out, removed, notes = poisoned(tmp_path, source)
    for value in PLACE_VALUES:
        assert value not in out, value
    (main,), extension = header_app1(out)
    new_guid, new_packet = read_back(extension)
    assert new_guid == md5_guid(new_packet) != guid  # the GUID is the MD5 of the packet written
    pointers = [e.get(NOTE) or e.text for e in ET.fromstring(main).iter() if NOTE in (e.tag, *e.attrib)]
    assert [p.strip() for p in pointers if p] == [new_guid.decode()]  # the main packet names it
    assert b"kept-creator" in main
    assert KEPT.encode() in new_packet and b"rdf:Description" in ET.tostring(ET.fromstring(new_packet))
    assert all(len(p) + 2 <= 0xFFFF for p in extension)
    expected = [f"Extended XMP {q}" for q in ("Iptc4xmpExt:LocationCreated", "Iptc4xmpExt:Sublocation",
                                             "exif:GPSAltitude", "exif:GPSLatitude", "exif:GPSLongitude",
                                             "photoshop:City")]  # fmt: skip
    assert set(expected) <= set(removed) and "XMP exif:GPSLatitude" in removed
    assert all(e in joined(notes) for e in expected) and "location removed" in joined(notes)
    kept, kept_removed, _ = poisoned(tmp_path, source, keep_location=True)
    assert all(value in kept for value in PLACE_VALUES) and kept_removed == []
    assert header_app1(kept)[1] == parts  # kept as they were


def test_extended_xmp_holding_only_location_goes_with_its_pointer(tmp_path: Path) -> None:
    packet = extended_packet(kept=False)
    guid = md5_guid(packet)
    out, removed, notes = poisoned(
        tmp_path, jpeg_with([XAP + main_packet(guid, True), *extension_segments(packet, guid)])
    )
    for value in [*PLACE_VALUES, EXTENSION, b"HasExtendedXMP", guid]:
        assert value not in out, value
    (main,), _ = header_app1(out)
    ET.fromstring(main)
    assert b"kept-creator" in main
    assert {"Extended XMP exif:GPSLatitude", "Extended XMP photoshop:City"} <= set(removed)
    assert "Extended XMP exif:GPSLongitude" in joined(notes)


def _gap(parts: list[bytes]) -> list[bytes]:
    return [parts[0], parts[2]]


def _lengths(parts: list[bytes]) -> list[bytes]:
    return [parts[0], parts[1][:67] + struct.pack(">I", 5) + parts[1][71:], parts[2]]


def _not_xml(parts: list[bytes]) -> list[bytes]:
    return [parts[0], parts[1].replace(b"kept-extended", b"<<<<<<<<<<<<<", 1), parts[2]]


@pytest.mark.parametrize("broken", [_gap, _lengths, _not_xml], ids=["gap", "lengths-disagree", "not-xml"])
def test_unreadable_extended_xmp_is_dropped_whole_and_said(tmp_path: Path, broken: object) -> None:
    packet = extended_packet()
    guid = md5_guid(packet)
    parts = extension_segments(packet, guid, chunk=40000)
    assert len(parts) == 3
    source = jpeg_with([XAP + main_packet(guid, False), *broken(parts)])  # type: ignore[operator]
    out, removed, notes = poisoned(tmp_path, source)
    for value in [*PLACE_VALUES, EXTENSION, b"HasExtendedXMP", b"kept-extended"]:
        assert value not in out, value
    (main,), _ = header_app1(out)
    ET.fromstring(main)
    assert any(r.startswith("Extended XMP dropped: unreadable, could hold location") for r in removed)
    assert "Extended XMP dropped: unreadable" in joined(notes)


def _text(ctype: bytes, key: bytes, value: bytes) -> tuple[bytes, bytes]:
    if ctype == b"zTXt":
        return ctype, key + b"\x00\x00" + zlib.compress(value)
    if ctype == b"iTXt":
        return ctype, key + b"\x00\x00\x00\x00\x00" + value
    return ctype, key + b"\x00" + value


PNG_PLACES = [
    _text(b"tEXt", b"exif:GPSLatitude", b"48/1, 51/1, 2987/100"),
    _text(b"zTXt", b"exif:GPSLongitude", b"2/1, 17/1, 4023/100"),
    _text(b"tEXt", b"exif:GPSAltitude", b"3512/100"),
    _text(b"iTXt", b"photoshop:City", CITY.encode()),
]
PNG_KEPT = [_text(b"tEXt", b"Title", b"kept-title"), _text(b"tEXt", b"exif:Make", b"kept-make")]


def test_png_text_chunks_keyed_by_a_location_property_are_removed(tmp_path: Path) -> None:
    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(4).integers(0, 256, (120, 160, 3), dtype=np.uint8)).save(buf, "PNG")
    chunks = png_chunks(buf.getvalue())
    extra = b"".join(struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b))
                     for t, b in PNG_PLACES + PNG_KEPT)  # fmt: skip
    data = buf.getvalue()
    cut = 8 + 12 + len(chunks[0][1])  # after IHDR
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    src.write_bytes(data[:cut] + extra + data[cut:])
    assert {"exif:GPSLatitude", "exif:GPSLongitude", "photoshop:City"} <= set(Image.open(src).info)
    report = poison_file(src, dst, SPEC)
    out = dst.read_bytes()
    for value in (b"2987/100", b"4023/100", b"3512/100", CITY.encode(), b"GPS", b"photoshop:City"):
        assert value not in out, value
    assert zlib.compress(b"2/1, 17/1, 4023/100") not in out
    info = Image.open(dst).info
    assert info["Title"] == "kept-title" and info["exif:Make"] == "kept-make"
    expected = ["PNG tEXt: exif:GPSLatitude", "PNG zTXt: exif:GPSLongitude", "PNG tEXt: exif:GPSAltitude",
                "PNG iTXt: photoshop:City"]  # fmt: skip
    assert set(expected) <= set(report.location_removed)
    assert all(e in joined(report.notes) for e in expected)
    kept = poison_file(src, tmp_path / "k.png", SPEC, keep_location=True)
    kept_info = Image.open(tmp_path / "k.png").info
    assert kept_info["exif:GPSLatitude"] == "48/1, 51/1, 2987/100" and kept_info["photoshop:City"] == CITY
    assert kept_info["exif:GPSLongitude"] == "2/1, 17/1, 4023/100" and kept.location_removed == []
