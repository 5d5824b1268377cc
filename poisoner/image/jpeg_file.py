"""What a JPEG file carries besides the picture ppd patches: the metadata the output keeps, the bytes
after the picture (no JPEG path of ppd's writes them), and a coding Pillow cannot decode, refused
in words. Pure: the bytes in, facts out."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

from PIL import Image

from poisoner.completeness import jpeg_end
from poisoner.errors import ImageFormatError, one_line
from poisoner.jpeg import JpegLayout, jpegtran_binary, read_layout


def preserved(layout: JpegLayout, info: dict[str | tuple[int, int], Any]) -> list[str]:
    """What of the source the written JPEG keeps (the report's `preserved`)."""
    kept = ["JPEG quantisation tables", f"JPEG sampling {layout.sampling}"]
    names = {
        b"Exif\x00\x00": "EXIF",
        b"ICC_PROFILE\x00": "ICC",
        b"http://ns.adobe.com/xap/1.0/\x00": "XMP",
        b"Photoshop 3.0\x00": "IPTC/Photoshop",
    }
    for seg in layout.segments:
        if seg.marker == 0xFE:
            kept.append("JPEG comment")
        for prefix, name in names.items():
            if seg.payload.startswith(prefix) and f"JPEG {name}" not in kept:
                kept.append(f"JPEG {name}")
    if layout.progressive:
        kept.append("progressive")
    if layout.restart_interval:
        kept.append(f"restart interval {layout.restart_interval}")
    return kept


def check_arithmetic(src: Path, data: bytes) -> None:
    """An arithmetic-coded JPEG Pillow's libjpeg cannot decode (some that djpeg reads: found testing
    an installed wheel) fails saying so, not as "broken data stream". Only such files pay the trial
    decode; a broken header is left to the paths that judge it."""
    try:
        arithmetic = read_layout(data).arithmetic
    except ValueError:
        return
    if arithmetic:
        try:
            with Image.open(io.BytesIO(data)) as im:
                im.load()
        except (OSError, ValueError, SyntaxError) as exc:
            why = f"arithmetic-coded JPEG that Pillow cannot decode ({one_line(exc)})"
            hint = "saved with Huffman coding (the usual) it can be"
            raise ImageFormatError(f"{src.name}: {why}; {hint}") from exc


def arithmetic_coding(data: bytes) -> JpegLayout | None:
    """The layout of an arithmetic-coded JPEG that jpegtran can code again (huffman_coded), else None
    (another JPEG, a header that does not parse, or no jpegtran: check_arithmetic judges it then)."""
    try:
        layout = read_layout(data)
    except ValueError:
        return None
    return layout if layout.arithmetic and jpegtran_binary() is not None else None


def huffman_coded(src: Path, data: bytes) -> bytes:
    """An arithmetic-coded JPEG losslessly coded again with Huffman tables by jpegtran (the same
    coefficients, every marker copied; the bytes after its picture are not): a picture Pillow and
    ppd's bit-level splice read, where Pillow's libjpeg may not decode arithmetic coding at all.
    ImageFormatError (one line) when jpegtran refuses it (damaged or truncated data)."""
    return _transcoded(src, data, [])


def coded_like(src: Path, data: bytes, layout: JpegLayout) -> bytes:
    """The patched JPEG `data` coded again as the source (`layout`) was: arithmetic, progressive,
    its restart interval (jpegtran; lossless, every marker copied)."""
    options = ["-arithmetic"] if layout.arithmetic else []
    if layout.progressive:
        options.append("-progressive")
    if layout.restart_interval:
        options += ["-restart", f"{layout.restart_interval}B"]
    return _transcoded(src, data, options)


def _transcoded(src: Path, data: bytes, options: list[str]) -> bytes:
    from poisoner.jpeg import SpliceUnavailable, _jpegtran

    binary = jpegtran_binary()
    if binary is None:
        raise ImageFormatError(f"{src.name}: arithmetic-coded JPEG needs jpegtran (libjpeg-turbo-progs)")
    try:
        return _jpegtran([binary, "-copy", "all", *options], src, "transcode", stdin=data)
    except SpliceUnavailable as exc:
        raise ImageFormatError(f"{src.name}: arithmetic-coded JPEG jpegtran cannot read ({exc})") from exc


def trailer_bytes(data: bytes) -> int:
    """How many bytes follow the JPEG's picture (its first EOI): no JPEG path of ppd's writes them."""
    end = jpeg_end(data)
    return 0 if end is None else len(data) - end


MPF_HEADER = b"MPF\x00"  # APP2: the Multi-Picture Format index of the images after the picture


def without_mpf(data: bytes) -> tuple[bytes, bool]:
    """The JPEG with its MPF (APP2) segment taken out, and whether it had one. MPF gives the offsets
    of images appended after the picture (a phone's Ultra HDR gain map, a camera's preview or second
    view): ppd never writes those (an unprotected view of the scene), so an index kept would point at
    bytes that are not there. A header that does not parse is returned as it is."""
    from poisoner.location import MetadataParseError, jpeg_assemble, jpeg_header_segments

    try:
        segments, sos = jpeg_header_segments(data)
    except MetadataParseError:
        return data, False
    kept = [(m, p) for m, p in segments if not (m == 0xE2 and p.startswith(MPF_HEADER))]
    if len(kept) == len(segments):
        return data, False
    return jpeg_assemble(kept, data, sos), True


def same_coded_picture(before: bytes, after: bytes) -> bool:
    """Whether two JPEGs hold the very same scans from their first SOS on (their headers may differ:
    ppd's marker, location removed): the mark changed no pixel. A header that cannot be read: False."""
    from poisoner.location import MetadataParseError, jpeg_header_segments

    try:
        _, start_before = jpeg_header_segments(before)
        _, start_after = jpeg_header_segments(after)
    except MetadataParseError:
        return False
    # to each picture's end (EOI): bytes after it (an appended image, a trailer) are not written
    return before[start_before : jpeg_end(before)] == after[start_after : jpeg_end(after)]
