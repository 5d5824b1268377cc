"""Pictures of the original inside a patched file's metadata, never published as they were (a
black-box review, F3: every patched JPEG from a camera carried its unmarked EXIF thumbnail):

- EXIF IFD1 thumbnail, and any other JPEG inside the EXIF block (a maker note's preview), in a
  JPEG, PNG eXIf, WebP, HEIC or AVIF: rewritten in place from the patched picture at its own size
  and quality, else removed (poisoner.image.exif_thumb);
- Photoshop thumbnail (JPEG APP13 image resources 0x0409, 0x040C, Photoshop and Bridge write it):
  rewritten from the patched picture at its own size, else the resource removed;
- XMP thumbnails (`xmp:Thumbnails`, whose `xmpGImg:image` is a base64 JPEG): removed; a JPEG's
  Extended XMP that holds a picture (Google's GImage:Data: the whole original) removed with its
  pointer (xmpNote:HasExtendedXMP);
- FlashPix extension data (JPEG APP2 "FPXR", Kodak, Casio, Fujifilm, HP, Sanyo): its streams hold
  a camera's preview JPEG (ScreenNail, Fuji's PreviewImage): every FPXR segment removed, unparsed.

A viewer that shows the thumbnail so shows the marked photo. An EXIF block that does not parse is
dropped whole, as for location (it could hold the picture). Each function returns the notes that
say what was done; `ppd poison`'s summary counts them (daemon.cli.poison_cmd.CHANGE_NOTES).
"""

from __future__ import annotations

import io
import struct
from collections.abc import Callable

import numpy as np
from PIL import Image

from poisoner import location
from poisoner.errors import ImageFormatError
from poisoner.image.exif_thumb import REPLACED, Render, jpeg_within, rewrite_previews
from poisoner.image.png import PNG_SIGNATURE, png_chunk, png_chunks

_NS_XMP = "http://ns.adobe.com/xap/1.0/"
_NS_XMP_IMAGE = "http://ns.adobe.com/xap/1.0/g/img/"  # xmpGImg: image, format, width, height
_PHOTOSHOP_THUMBNAILS = {0x0409: "BGR", 0x040C: "RGB"}  # Photoshop 4's was stored BGR
_PS_HEADER = struct.Struct(">IIIIIIHH")  # format, width, height, row bytes, total, compressed, bits, planes
_NS_XMP_NOTE = "http://ns.adobe.com/xmp/note/"  # xmpNote:HasExtendedXMP: the extension's GUID
_NS_GIMAGE = "http://ns.google.com/photos/1.0/image/"  # GImage:Data: Google's copy of the original
_XMP_EXTENSION = b"http://ns.adobe.com/xmp/extension/\x00"  # then GUID (32), length (4), offset (4)
REMOVED = "thumbnail removed"
EXTENSION_REMOVED = "Extended XMP holding a picture of the original (GImage:Data, a thumbnail) removed"
XMP_REMOVED = "XMP thumbnail removed"
# APP2 FlashPix extension data: a contents list naming OLE streams, then each stream's bytes spread
# over segments by index and offset. Not parsed to find the preview: readers reassemble them by
# conventions (a first offset that is not 0, overlaps; Fujifilm's preview with no contents list at
# all, exiftool's FlashPix.pm), and a picture may be a JPEG or raw tiles; the rest is camera settings
# (much as in EXIF) and voice notes. So every FPXR segment of a patched JPEG goes.
FPXR_HEADER = b"FPXR\x00"
FLASHPIX_REMOVED = (
    "FlashPix data (FPXR APP2, {n} segment(s)) removed: cameras keep a preview of the original there"
)


# ---- the patched picture, small --------------------------------------------------------------------
def render_bytes(data: bytes) -> Render:
    """Render from the patched file's bytes (decoded when a thumbnail asks; a JPEG at a reduced
    scale, libjpeg's draft)."""

    def render(size: tuple[int, int]) -> Image.Image:
        with Image.open(io.BytesIO(data)) as im:
            if im.format == "JPEG":
                im.draft("RGB", size)
            return fitted(im, size)

    return render


def render_image(picture: Callable[[], Image.Image]) -> Render:
    """Render from the patched picture in memory (picture(): made only when a thumbnail asks)."""
    return lambda size: fitted(picture(), size)


def fitted(im: Image.Image, size: tuple[int, int]) -> Image.Image:
    """im (RGB) fitted into size, centred on black where the shapes differ (a camera's 160x120 of a
    16:9 photo is letterboxed so)."""
    rgb = _as_rgb(im)
    scale = min(size[0] / rgb.width, size[1] / rgb.height)
    inner = (max(1, min(size[0], round(rgb.width * scale))), max(1, min(size[1], round(rgb.height * scale))))
    small = rgb.resize(inner, Image.Resampling.LANCZOS, reducing_gap=3.0)
    if inner == size:
        return small
    canvas = Image.new("RGB", size)
    canvas.paste(small, ((size[0] - inner[0]) // 2, (size[1] - inner[1]) // 2))
    return canvas


def _as_rgb(im: Image.Image) -> Image.Image:
    if im.mode.startswith("I;16") or im.mode == "I":  # 16-bit grey: its top 8 bits, not clipped
        return Image.fromarray((np.asarray(im).astype(np.uint32) >> 8).astype(np.uint8)).convert("RGB")
    return im.convert("RGB")


# ---- one carrier at a time -------------------------------------------------------------------------
def exif_previews(exif: bytes, render: Render) -> tuple[bytes | None, list[str]]:
    """The EXIF block with its thumbnail rewritten or removed; None (drop it) when it does not parse."""
    try:
        return rewrite_previews(exif, render)
    except location.MetadataParseError as exc:
        return None, [f"EXIF dropped: unreadable, could hold a thumbnail of the original ({exc})"]


def xmp_previews(xmp: bytes) -> tuple[bytes, list[str]]:
    """The XMP packet without its thumbnails (xmp:Thumbnails and any xmpGImg property)."""

    names = sorted(location.xmp_qnames(xmp, _thumbnail))
    if not names:
        return xmp, []
    return location.strip_xmp_names(xmp, names), [XMP_REMOVED]


def _thumbnail(namespace: str, local: str) -> bool:
    return (namespace == _NS_XMP and local == "Thumbnails") or namespace == _NS_XMP_IMAGE


def photoshop_previews(block: bytes, render: Render) -> tuple[bytes, list[str]]:
    """A Photoshop image-resource block (APP13 payload) with its thumbnails rewritten from the patched
    picture, or taken out. Raises MetadataParseError."""
    head = location.PHOTOSHOP_HEADER if block.startswith(location.PHOTOSHOP_HEADER) else b""
    out, notes = bytearray(head), []
    for rid, head_bytes, data, raw in _resources(block, len(head)):
        if rid not in _PHOTOSHOP_THUMBNAILS:
            out += raw
            continue
        new = _photoshop_thumbnail(data, _PHOTOSHOP_THUMBNAILS[rid], render)
        if isinstance(new, str):
            notes.append(f"Photoshop {REMOVED} ({new})")
            continue
        body, (w, h) = new
        out += head_bytes + struct.pack(">I", len(body)) + body + b"\x00" * (len(body) & 1)
        notes.append(f"Photoshop thumbnail ({w}x{h}) {REPLACED}")
    return bytes(out), notes


def _resources(block: bytes, pos: int) -> list[tuple[int, bytes, bytes, bytes]]:
    """(id, its signature/id/name bytes, its data, the whole resource) for each; padding kept."""
    found = []
    while pos < len(block):
        if block[pos : pos + 4] != b"8BIM":
            if not block[pos:].strip(b"\x00"):
                found.append((-1, b"", b"", block[pos:]))
                break
            raise location.MetadataParseError("Photoshop resource signature expected")
        if pos + 7 > len(block):
            raise location.MetadataParseError("Photoshop resource truncated")
        (rid,) = struct.unpack(">H", block[pos + 4 : pos + 6])
        name_end = pos + 6 + ((1 + block[pos + 6] + 1) & ~1)
        (size,) = struct.unpack(">I", block[name_end : name_end + 4])
        if name_end + 4 + size > len(block):
            raise location.MetadataParseError("Photoshop resource runs past the block")
        end = name_end + 4 + size + (size & 1)
        found.append((rid, block[pos:name_end], block[name_end + 4 : name_end + 4 + size], block[pos:end]))
        pos = end
    return found


def _photoshop_thumbnail(data: bytes, order: str, render: Render) -> tuple[bytes, tuple[int, int]] | str:
    """A thumbnail resource's data (28-byte header, then JFIF) showing the patched picture at the old
    one's size, in no more bytes than it had; why not otherwise."""
    if len(data) < _PS_HEADER.size:
        return "truncated"
    fmt, *_ = _PS_HEADER.unpack(data[: _PS_HEADER.size])
    if fmt != 1:  # 0: raw pixels, never seen in a file
        return "not a JPEG"

    def in_order(size: tuple[int, int]) -> Image.Image:
        picture = render(size)
        return picture if order == "RGB" else Image.merge("RGB", picture.split()[::-1])

    new = jpeg_within(data[_PS_HEADER.size :], len(data) - _PS_HEADER.size, in_order)
    if isinstance(new, str):
        return new
    jpeg, (w, h) = new
    row = (w * 24 + 31) // 32 * 4
    return _PS_HEADER.pack(1, w, h, row, row * h, len(jpeg), 24, 1) + jpeg, (w, h)


# ---- whole files -----------------------------------------------------------------------------------
def jpeg_previews(name: str, data: bytes) -> tuple[bytes, list[str]]:
    """The patched JPEG (spliced or re-encoded: every JPEG path's output) with the original's
    thumbnails (EXIF, Photoshop, XMP) made the patched picture's or removed, its FlashPix data
    removed; the scans copied verbatim. ImageFormatError when the header does not parse."""
    try:
        segments, sos = location.jpeg_header_segments(data)
    except location.MetadataParseError as exc:
        raise ImageFormatError(f"{name}: cannot read the JPEG header for its thumbnails ({exc})") from exc
    render = render_bytes(data)
    kept: list[tuple[int, bytes]] = []
    pictured = _extensions_with_pictures(segments)
    notes = [EXTENSION_REMOVED] if pictured else []
    flashpix = 0  # FPXR segments dropped (FPXR_HEADER says why all of them)
    for marker, payload in segments:
        new: bytes | None = payload
        said: list[str] = []
        if marker == 0xE1 and _extension_guid(payload) in pictured:
            continue
        if marker == 0xE2 and payload.startswith(FPXR_HEADER):
            flashpix += 1
            continue
        if marker == 0xE1 and payload.startswith(location.EXIF_HEADER):
            new, said = exif_previews(payload, render)
        elif marker == 0xE1 and payload.startswith(location.XMP_JPEG_HEADER):
            body, said = xmp_previews(payload[len(location.XMP_JPEG_HEADER) :])
            if pictured:  # the extension it names is gone
                body = location.strip_xmp_names(body, sorted(location.xmp_qnames(body, _extension_pointer)))
            new = location.XMP_JPEG_HEADER + body
        elif marker == 0xED and payload.startswith(location.PHOTOSHOP_HEADER):
            try:
                new, said = photoshop_previews(payload, render)
            except location.MetadataParseError as exc:
                new, said = None, [f"Photoshop segment dropped: unreadable, could hold a thumbnail ({exc})"]
        notes += said
        if new is not None:
            kept.append((marker, new))
    notes += [FLASHPIX_REMOVED.format(n=flashpix)] if flashpix else []
    return (location.jpeg_assemble(kept, data, sos), notes) if notes else (data, [])


def _extension_guid(payload: bytes) -> bytes | None:
    """The GUID of an Extended XMP segment (its part of a packet too large for one segment)."""
    if not payload.startswith(_XMP_EXTENSION) or len(payload) < len(_XMP_EXTENSION) + 40:
        return None
    return payload[len(_XMP_EXTENSION) : len(_XMP_EXTENSION) + 32]


def _extensions_with_pictures(segments: list[tuple[int, bytes]]) -> set[bytes]:
    """GUIDs of the Extended XMP packets that hold a picture: Google's GImage:Data (Lens Blur and
    other depth photos keep the original, whole, there as base64) or an xmpGImg thumbnail."""
    parts: dict[bytes, list[tuple[int, bytes]]] = {}
    head = len(_XMP_EXTENSION)
    for marker, payload in segments:
        if marker == 0xE1 and (guid := _extension_guid(payload)) is not None:
            (offset,) = struct.unpack(">I", payload[head + 36 : head + 40])
            parts.setdefault(guid, []).append((offset, payload[head + 40 :]))
    return {
        guid for guid, chunks in parts.items()
        if location.xmp_qnames(b"".join(c for _, c in sorted(chunks)), _a_picture)
    }  # fmt: skip


def _a_picture(namespace: str, local: str) -> bool:
    return (namespace == _NS_GIMAGE and local == "Data") or _thumbnail(namespace, local)


def _extension_pointer(namespace: str, local: str) -> bool:
    return namespace == _NS_XMP_NOTE and local == "HasExtendedXMP"


def png_previews(data: bytes) -> tuple[bytes, list[str]]:
    """The patched PNG with the thumbnails of its EXIF (eXIf, ImageMagick's raw exif/APP1 profile
    text) rewritten or the chunk dropped, and its XMP's (iTXt, raw xmp profile) removed; every other
    chunk copied byte for byte."""
    render = render_bytes(data)

    def exif_fn(exif: bytes) -> tuple[bytes | None, list[str]]:
        return exif_previews(exif, render)

    parts, notes = [PNG_SIGNATURE], []
    for ctype, body in png_chunks(data):
        new: bytes | None = body
        if ctype in (b"eXIf", b"iTXt", b"zTXt", b"tEXt"):
            new, said = location.clean_png_chunk(ctype, body, exif_fn, xmp_previews)
            notes += said
        if new is not None:
            parts.append(png_chunk(ctype, new))
    return (b"".join(parts), notes) if notes else (data, [])
