"""Photos that carry a picture of themselves in their metadata, as cameras and phones write them: an
EXIF block with IFD0 (Make, Artist), an EXIF sub-IFD (DateTimeOriginal, a maker note) and IFD1 with
a JPEG thumbnail (or uncompressed RGB strips), built by hand so every offset is known; a Photoshop
APP13 thumbnail resource; an XMP packet with `xmp:Thumbnails`; FlashPix APP2 segments holding a
camera's ScreenNail."""

from __future__ import annotations

import base64
import io
import struct
from dataclasses import dataclass

import numpy as np
from PIL import Image

MAKER_NOTE = b"ppd-test-maker-note\x00" + bytes(range(40))  # vendor bytes: kept as they are
ARTIST = b"ppd-test-artist\x00"


def camera_picture(size: tuple[int, int] = (640, 480), seed: int = 3) -> Image.Image:
    """A photo-like picture: smooth gradients and a few shapes plus a little noise (compresses as a
    photo does, so a thumbnail of it is of a camera's size)."""
    w, h = size
    y, x = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(seed)
    rgb = np.stack([x * 255 // w, y * 255 // h, (x + y) * 127 // (w + h) + 60], axis=-1).astype(np.int32)
    for _ in range(6):
        cx, cy, r = rng.integers(0, w), rng.integers(0, h), rng.integers(h // 12, h // 4)
        rgb[(x - cx) ** 2 + (y - cy) ** 2 < r * r] = rng.integers(0, 256, 3)
    rgb += rng.integers(-6, 7, rgb.shape)
    return Image.fromarray(np.clip(rgb, 0, 255).astype(np.uint8))


def jpeg_of(im: Image.Image, quality: int = 75) -> bytes:
    buf = io.BytesIO()
    im.save(buf, "JPEG", quality=quality)
    return buf.getvalue()


@dataclass
class ExifWithThumbnail:
    block: bytes  # "Exif\0\0" + TIFF
    thumbnail_at: int  # where the thumbnail's bytes start in block
    thumbnail: bytes  # the thumbnail's bytes (a JPEG, or RGB strips)
    length_at: int  # where IFD1's JPEGInterchangeFormatLength (or StripByteCounts) value is
    next_ifd_at: int  # where IFD0's next-IFD pointer is


def exif_with_thumbnail(
    thumbnail: bytes,
    order: str = "<",
    strips: tuple[int, int] | None = None,
    orientation: bool = True,
    maker_note: bytes = MAKER_NOTE,
) -> ExifWithThumbnail:
    """An EXIF block whose IFD1 holds `thumbnail`: a JPEG, or with strips=(width, height) uncompressed
    8-bit RGB of that size in one strip. order: "<" (II) or ">" (MM). orientation=False: no
    Orientation tag (a DNG-like writer's; Pillow's AVIF writer re-serialises a block that has one,
    without IFD1). maker_note: the vendor's bytes (a Nikon's hold a 640 px preview JPEG). Layout:
    header | IFD0 | EXIF sub-IFD | IFD1 | values (Artist, Make, DateTimeOriginal, maker note,
    BitsPerSample) | thumbnail."""
    bo = order

    def entry(tag: int, typ: int, count: int, value: bytes) -> bytes:
        return struct.pack(bo + "HHI", tag, typ, count) + value.ljust(4, b"\x00")

    def long(v: int) -> bytes:
        return struct.pack(bo + "I", v)

    def short(v: int) -> bytes:
        return struct.pack(bo + "H", v)

    def ifd(entries: list[bytes], next_at: int) -> bytes:
        return struct.pack(bo + "H", len(entries)) + b"".join(entries) + long(next_at)

    make, date = b"ppd-test-camera\x00", b"2026:12:07 10:00:00\x00"
    n_ifd1 = 8 if strips else 3
    ifd0_at = 8
    n_ifd0 = 4 if orientation else 3
    exif_at = ifd0_at + 2 + 12 * n_ifd0 + 4
    ifd1_at = exif_at + 2 + 12 * 2 + 4
    artist_at = ifd1_at + 2 + 12 * n_ifd1 + 4
    make_at = artist_at + len(ARTIST)
    date_at = make_at + len(make)
    note_at = date_at + len(date)
    bits_at = note_at + len(maker_note)
    thumb_at = bits_at + 6
    turned = [entry(0x0112, 3, 1, short(1))] if orientation else []
    ifd0 = ifd([entry(0x010F, 2, len(make), long(make_at)), *turned,
                entry(0x013B, 2, len(ARTIST), long(artist_at)), entry(0x8769, 4, 1, long(exif_at))],
               ifd1_at)  # fmt: skip
    exif_ifd = ifd([entry(0x9003, 2, len(date), long(date_at)),
                    entry(0x927C, 7, len(maker_note), long(note_at))], 0)  # fmt: skip
    if strips:
        w, h = strips
        ifd1 = ifd([entry(0x0100, 3, 1, short(w)), entry(0x0101, 3, 1, short(h)),
                    entry(0x0102, 3, 3, long(bits_at)), entry(0x0103, 3, 1, short(1)),
                    entry(0x0106, 3, 1, short(2)), entry(0x0111, 4, 1, long(thumb_at)),
                    entry(0x0115, 3, 1, short(3)), entry(0x0117, 4, 1, long(len(thumbnail)))], 0)  # fmt: skip
        length_entry = 7
    else:
        ifd1 = ifd([entry(0x0103, 3, 1, short(6)), entry(0x0201, 4, 1, long(thumb_at)),
                    entry(0x0202, 4, 1, long(len(thumbnail)))], 0)  # fmt: skip
        length_entry = 2
    tiff = (b"II*\x00" if bo == "<" else b"MM\x00*") + long(ifd0_at) + ifd0 + exif_ifd + ifd1
    assert len(tiff) == artist_at
    tiff += ARTIST + make + date + maker_note + struct.pack(bo + "HHH", 8, 8, 8) + thumbnail
    head = len(b"Exif\x00\x00")
    return ExifWithThumbnail(
        b"Exif\x00\x00" + tiff,
        thumbnail_at=head + thumb_at,
        thumbnail=thumbnail,
        length_at=head + ifd1_at + 2 + 12 * length_entry + 8,
        next_ifd_at=head + exif_at - 4,
    )


def with_app_segment(jpeg: bytes, marker: int, payload: bytes) -> bytes:
    """The JPEG with one more APPn segment right after SOI."""
    return jpeg[:2] + bytes((0xFF, marker)) + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


def photoshop_thumbnail_block(thumbnail: bytes, size: tuple[int, int], iptc: bytes) -> bytes:
    """An APP13 "Photoshop 3.0" payload: an IPTC resource (0x0404) and a thumbnail (0x040C)."""

    def resource(rid: int, data: bytes) -> bytes:
        padded = data + b"\x00" * (len(data) & 1)
        return b"8BIM" + struct.pack(">H", rid) + b"\x00\x00" + struct.pack(">I", len(data)) + padded

    w, h = size
    row = (w * 24 + 31) // 32 * 4
    head = struct.pack(">IIIIIIHH", 1, w, h, row, row * h, len(thumbnail), 24, 1)
    return b"Photoshop 3.0\x00" + resource(0x0404, iptc) + resource(0x040C, head + thumbnail)


def xmp_with_thumbnail(thumbnail: bytes) -> bytes:
    """An XMP packet with an `xmp:Thumbnails` entry (base64 JPEG) and a creator to keep."""
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>'
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        '<rdf:Description rdf:about="" xmlns:xmp="http://ns.adobe.com/xap/1.0/"'
        ' xmlns:xmpGImg="http://ns.adobe.com/xap/1.0/g/img/" xmlns:dc="http://purl.org/dc/elements/1.1/">'
        '<xmp:Thumbnails><rdf:Alt><rdf:li rdf:parseType="Resource"><xmpGImg:width>160</xmpGImg:width>'
        "<xmpGImg:format>JPEG</xmpGImg:format><xmpGImg:image>"
        + base64.b64encode(thumbnail).decode()
        + "</xmpGImg:image></rdf:li></rdf:Alt></xmp:Thumbnails>"
        "<dc:creator><rdf:Seq><rdf:li>kept-creator</rdf:li></rdf:Seq></dc:creator>"
        "</rdf:Description></rdf:RDF></x:xmpmeta>"
        '<?xpacket end="w"?>'
    ).encode()


def extended_xmp_segments(picture_jpeg: bytes, guid: bytes = b"0123456789ABCDEF" * 2) -> list[bytes]:
    """APP1 payloads of an Extended XMP packet holding Google's GImage:Data (base64 JPEG; Google
    Camera's Lens Blur keeps the original there), split as the XMP spec says (at most 65400 bytes a
    segment, each with the GUID, the full length and its offset), and the main packet that names it."""
    packet = (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        '<rdf:Description rdf:about="" xmlns:GImage="http://ns.google.com/photos/1.0/image/"'
        ' GImage:Mime="image/jpeg" GImage:Data="' + base64.b64encode(picture_jpeg).decode() + '"/>'
        "</rdf:RDF></x:xmpmeta>"
    ).encode()
    head = b"http://ns.adobe.com/xmp/extension/\x00" + guid + struct.pack(">I", len(packet))
    parts = [head + struct.pack(">I", at) + packet[at : at + 65400] for at in range(0, len(packet), 65400)]
    main = (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        '<rdf:Description rdf:about="" xmlns:xmpNote="http://ns.adobe.com/xmp/note/"'
        ' xmlns:dc="http://purl.org/dc/elements/1.1/" xmpNote:HasExtendedXMP="' + guid.decode() + '">'
        "<dc:creator><rdf:Seq><rdf:li>kept-creator</rdf:li></rdf:Seq></dc:creator>"
        "</rdf:Description></rdf:RDF></x:xmpmeta>"
    ).encode()
    return [b"http://ns.adobe.com/xap/1.0/\x00" + main, *parts]


def flashpix_segments(preview: bytes, chunk: int = 4000) -> list[bytes]:
    """APP2 payloads of FlashPix extension data holding `preview` (a JPEG) as a Kodak camera's
    ScreenNail, laid out as exiftool's FlashPix.pm reads them: "FPXR\\0", version 0, then a contents
    list (type 1: entry count; per entry its stream's size, a default byte and its UTF-16LE path)
    naming one stream, and that stream (a 28-byte OLE stream header, then the JPEG) in stream-data
    segments (type 2: contents-list index, offset, `chunk` bytes of it)."""
    stream = bytes(0x1C) + preview
    path = "/\x05Screen Nail_bd0100609719a180".encode("utf-16-le") + b"\x00\x00"
    contents = b"FPXR\x00\x00\x01" + struct.pack(">HI", 1, len(stream)) + b"\x00" + path
    parts = [
        b"FPXR\x00\x00\x02" + struct.pack(">HI", 0, at) + stream[at : at + chunk]
        for at in range(0, len(stream), chunk)
    ]
    return [contents, *parts]
