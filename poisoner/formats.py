"""Image files, faithfully: read a photo, blend the dataset's patch in, write the same kind of file.

What "faithfully" means per format (docs/FORMATS.md has the measured details):
- JPEG: only the MCUs the patch writes in are re-encoded (DCT-coefficient splice, poisoner.jpeg; a
  mark of two squares placed apart leaves the MCUs between them as they were, lane_placements);
  if that is impossible, one re-encode with the source's own quantisation tables and chroma
  subsampling. EXIF, ICC, XMP, IPTC and comments are kept, their thumbnails the patched picture's.
- PNG: lossless; 8-bit files keep the source's filtered rows outside the mark's rows and are only
  deflated again (poisoner.image.png_rows); otherwise the new pixel data (IHDR/PLTE/tRNS/IDAT) is
  spliced between the source's own ancillary chunks, copied byte for byte (text, iCCP, eXIf, pHYs,
  gAMA, cHRM, sRGB, tIME, ...).
  16-bit colour PNGs go through FFmpeg's PNG codec (PyAV) because Pillow reads them as 8-bit.
- WebP: lossless stays lossless (exact, RGB under transparent pixels kept); lossy is re-encoded at
  the quality estimated from the source's VP8 quantiser. EXIF, ICC and XMP are kept.
- TIFF: same compression; descriptive tags, ICC, XMP and IPTC kept.
- HEIC (pillow-heif) and AVIF (Pillow): re-encoded at a high quality, EXIF/ICC/XMP kept.

Orientation: the patch is placed in the stored pixels, ignoring EXIF orientation, because that
is what COLMAP's feature extraction and 3DGS's PIL loaders read (docs/FORMATS.md, evidence).
The orientation tag itself is kept unchanged.

Location (GPS IFD, XMP/IPTC place names) is removed from the output unless keep_location
(poisoner.location: byte-level edits of the metadata, pixels untouched); a provenance marker is
embedded when given (poisoner.provenance). Before anything is decoded the header's declared size is
checked against max_pixels (poisoner.limits).

A keep-out mask (poison_file's keep_out: a subject mask, poisoner.subject) is honoured by every
writer: the mark is not written on it. JPEG leaves whole MCUs near it unwritten and splices only
the MCUs the mark writes; masked MCUs inside that box keep the source's coefficients wherever
libturbojpeg is there (poisoner.image.keep_out), so no decoded pixel on the mask changes.

Every input is fully decoded before anything is written, so a truncated file fails before dst
exists; errors are ImageFormatError with a one-line message, and src is never opened for writing.

The stages (poison_file runs them in order): read the bytes and check the header's size
(_read_source, poisoner.limits) -> open and decode (poisoner.image.read) -> place the patch
(_placement) -> the format's writer (_write_format: JPEG here, poisoner.image.png / webp / tiff /
heif) -> file-level notes -> dst.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict, Unpack

import numpy as np
from PIL import Image

from poisoner import jpeg as jpeg_codec
from poisoner import jpeg_scan, location, provenance
from poisoner.atomic import atomic_output
from poisoner.blend import apply_lanes_at, lane_placements, patch_coverage
from poisoner.errors import ImageFormatError, MarkNotWritten, one_line
from poisoner.image import jpeg_file, previews
from poisoner.image import png as png_file
from poisoner.image.heif import HEIF_QUALITY, poison_heif
from poisoner.image.keep_out import checked_keep_out, kept_out_note, mcu_keep_out, written_box, written_pixels
from poisoner.image.png import PNG_SIGNATURE, png_chunks, poison_png, splice_png, strip_png_location
from poisoner.image.png_rows import poison_png_rows
from poisoner.image.read import format_refusal, load_decoded, open_decoded
from poisoner.image.tiff import poison_tiff
from poisoner.image.webp import poison_webp, vp8_quantizers, webp_quality_from_quantizer
from poisoner.image.write import changes_a_pixel, image_from_array, paste_patch, save_explicit
from poisoner.limits import DEFAULT_MAX_PIXELS, check_decode_budget
from poisoner.mark_place import MarkPlace
from poisoner.media import is_image
from poisoner.orientation import display_size
from poisoner.placement import turned_to_stored
from poisoner.provenance import Marker
from poisoner.shrink import place_fitting
from poisoner.spec import PatchPlacement, PatchSpec, SpecError
from poisoner.subject import display_details, display_subject, shown_orientation

# Re-exported: importers of poisoner.formats keep finding these here.
__all__ = [
    "HEIF_QUALITY",
    "PNG_SIGNATURE",
    "ImageFormatError",
    "PoisonOptions",
    "PoisonReport",
    "image_from_array",
    "paste_patch",
    "png_chunks",
    "poison_bytes",
    "poison_file",
    "poison_in_place",
    "save_explicit",
    "splice_png",
    "strip_png_location",
    "vp8_quantizers",
    "webp_quality_from_quantizer",
]

log = logging.getLogger(__name__)

# JPEG: decode only a lossless crop around the patch's MCUs (poisoner.jpeg.decode_box) instead of
# the whole picture. Same output bytes either way (tests/poisoner/test_jpeg_region.py); False: whole decode.
JPEG_REGION_DECODE = True

# every mark (per photo, or a corner: issue 25) is placed as a viewer sees the photo
SHOWN_ORIENTATION_POLICY = "mark placed as the photo is shown, turned with it into the stored pixels"
PALETTE_POLICY = "patch colours appended to the palette when there is room, else written as RGB(A)"

_load_decoded = load_decoded  # the JPEG writer's name for it


@dataclass
class PoisonReport:
    format: str
    width: int
    height: int
    placement: PatchPlacement
    preserved: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    method: str = ""  # how the pixels were written, e.g. "jpeg-dct-splice", "png-lossless"
    lossless: bool = False  # True when every pixel outside the patch is bit-identical
    src_bytes: int = 0
    dst_bytes: int = 0
    location_removed: list[str] = field(default_factory=list)  # e.g. "EXIF GPS IFD", "XMP exif:GPSLatitude"
    written: int = 0  # pixels the mark writes (never 0: poison_file refuses that file, MarkNotWritten)
    place: MarkPlace | None = None  # a per-photo mark: where it shows and why (poisoner.placement)
    trailer_bytes: int = 0  # bytes after a JPEG's picture or a PNG's IEND (an appended image...): not written


# ---- JPEG ----------------------------------------------------------------------------------------
def _poison_jpeg(
    src: Path, im: Image.Image, data: bytes, placement: PatchPlacement, keep_out: np.ndarray | None, *,
    loaded: bool,
) -> tuple[bytes, list[str], list[str], str]:
    """The patched JPEG. With loaded=False im is only opened (header): every byte of the file is
    still entropy-decoded before anything is written (by jpegtran's crop and drop, whose warnings
    on corrupt or truncated data send it to the full decode), so a broken file fails as before."""
    try:
        layout = jpeg_codec.read_layout(data)
    except ValueError as exc:
        raise ImageFormatError(f"{src.name}: bad JPEG header ({exc})") from exc
    if (why := format_refusal(im)) is not None:
        raise ImageFormatError(f"{src.name}: {why}")
    preserved = jpeg_file.preserved(layout, im.info)
    notes: list[str] = []
    mark_box = jpeg_codec.mcu_box(placement.box, layout)
    keep = None
    if keep_out is not None:
        keep = mcu_keep_out(keep_out, mark_box, layout.mcu_size, _chroma_reach(layout))
    box = mark_box if keep is None else _splice_box(placement, mark_box, keep, layout)
    if box is None:
        notes.append("the keep-out mask reaches every MCU of the mark: pixels left unchanged")
        return data, preserved, notes, "jpeg-unchanged"

    lanes = lane_placements(placement)
    changed: list[bool] = []  # per patched part: whether the mark changed a decoded pixel's value

    def patch(pixels: np.ndarray, at: tuple[int, int, int, int] = box) -> np.ndarray:
        window = None if keep is None else keep[at[1] - mark_box[1] : at[3] - mark_box[1],
                                                 at[0] - mark_box[0] : at[2] - mark_box[0]]  # fmt: skip
        out = apply_lanes_at(pixels, placement, (at[0], at[1]), window, lanes)
        changed.append(not np.array_equal(out, pixels))
        return out

    def faint(out: bytes) -> bytes:
        # The mark left every decoded pixel as it was (--alpha 0 or 0.001 on a noisy photo): the
        # splice's re-encode still moves coefficients, so comparing the coded pictures called it patched.
        if not any(changed):
            raise MarkNotWritten(f"{src.name}: the mark is too faint to change any pixel of it: not patched")
        return out

    # The splice only needs the MCU box's pixels: with JPEG_REGION_DECODE they come from a
    # lossless crop around the box (jpeg_codec.decode_box), so the rest of the picture is never
    # decoded to pixels; otherwise (or when the crop is refused) from the whole decoded picture,
    # of which only the box is converted to an array.
    masked = None if keep is None else _kept_mcus(keep, mark_box, box, layout)
    # MCUs of the box where the mark writes no pixel (between two squares placed apart) keep
    # their coefficients too: never re-encoded, so never changed.
    idle = _idle_mcus(placement, keep, mark_box, box, layout, lanes)
    holes = masked if idle is None else idle if masked is None else masked | idle
    # Squares placed apart: each square's MCUs decoded, blended and encoded alone, not the box
    # between them (whose idle MCUs keep their coefficients anyway): the same blocks.
    parts = _lane_parts(lanes, box, layout) if lanes is not None and idle is not None else None
    try:
        out, kept_exactly = _splice_jpeg(src, data, im, layout, box, patch, loaded, holes, parts)
        faint(out)
        notes.append(f"DCT splice: only MCU box {box} re-encoded, all other coefficients copied")
        if masked is not None:
            how = "coefficients copied" if kept_exactly else "re-encoded from their own pixels, unpatched"
            notes.append(f"{int(masked.sum())} MCU(s) of the box reach the keep-out mask: {how}")
        return out, preserved, notes, "jpeg-dct-splice"
    except jpeg_codec.SpliceUnavailable as exc:
        notes.append(f"DCT splice impossible ({exc}): whole image re-encoded with the source tables")
        log.info("jpeg splice unavailable", extra={"path": str(src), "reason": str(exc)})
    _load_decoded(src, im)
    patched = np.array(im)
    x0, y0, x1, y1 = mark_box
    patched[y0:y1, x0:x1] = patch(patched[y0:y1, x0:x1], mark_box)
    if layout.components == 3 and "subsampling" not in jpeg_codec.table_options(im):
        notes.append(f"sampling {layout.sampling} not reproducible by Pillow: written 4:2:0")
    return faint(jpeg_codec.encode_like(patched, im, layout)), preserved, notes, "jpeg-reencode-same-tables"


def _chroma_reach(layout: jpeg_codec.JpegLayout) -> tuple[int, int]:
    """How far (x, y) beyond a re-encoded MCU a decoded pixel can move: one pixel in each direction
    the chroma is subsampled (libjpeg's fancy upsampling blends the neighbouring chroma sample)."""
    if layout.components == 1:
        return (0, 0)
    return (int(layout.mcu_size[0] > 8), int(layout.mcu_size[1] > 8))


def _splice_box(
    placement: PatchPlacement,
    mark_box: tuple[int, int, int, int],
    keep: np.ndarray,
    layout: jpeg_codec.JpegLayout,
) -> tuple[int, int, int, int] | None:
    """The MCU box around the pixels the mark still writes with `keep` left alone (None: none):
    MCUs of the mark's box that carry no written pixel keep their coefficients."""
    written = written_box(placement, mark_box, keep)
    return None if written is None else jpeg_codec.mcu_box(written, layout)


def _idle_mcus(
    placement: PatchPlacement, keep: np.ndarray | None, mark_box: tuple[int, int, int, int],
    box: tuple[int, int, int, int], layout: jpeg_codec.JpegLayout, lanes: list[PatchPlacement] | None = None,
) -> np.ndarray | None:
    """The splice box's MCUs (rows x columns, True) in which the mark writes no pixel (keep, over
    mark_box, left alone); None when it writes in every one. With lanes (lane_placements(placement):
    the same pixels written) only each square's pixels are looked at, not the whole box between
    squares placed apart (up to 7 MP on a 12 MP photo)."""
    x0, y0, x1, y1 = box
    mw, mh = layout.mcu_size
    rows, cols = -(-(y1 - y0) // mh), -(-(x1 - x0) // mw)
    idle = np.ones((rows, cols), dtype=bool)
    for part in lanes or [placement]:
        # the part's box clipped to the splice box (the picture's edge may cut both), then grown to
        # whole MCUs of the splice box's grid
        px0, py0, px1, py1 = part.box
        cx0, cy0, cx1, cy1 = max(px0, x0), max(py0, y0), min(px1, x1), min(py1, y1)
        if cx0 >= cx1 or cy0 >= cy1:
            continue
        r0, c0 = (cy0 - y0) // mh, (cx0 - x0) // mw
        r1, c1 = -(-(cy1 - y0) // mh), -(-(cx1 - x0) // mw)
        write = np.zeros(((r1 - r0) * mh, (c1 - c0) * mw), dtype=bool)
        covered = patch_coverage(part)[cy0 - py0 : cy1 - py0, cx0 - px0 : cx1 - px0]
        if keep is not None:
            kx, ky = mark_box[0], mark_box[1]
            covered = covered & ~keep[cy0 - ky : cy1 - ky, cx0 - kx : cx1 - kx]
        oy, ox = cy0 - y0 - r0 * mh, cx0 - x0 - c0 * mw
        write[oy : oy + cy1 - cy0, ox : ox + cx1 - cx0] = covered
        idle[r0:r1, c0:c1] &= ~write.reshape(r1 - r0, mh, c1 - c0, mw).any(axis=(1, 3))
    return idle if idle.any() else None


def _lane_parts(
    lanes: list[PatchPlacement], box: tuple[int, int, int, int], layout: jpeg_codec.JpegLayout
) -> list[tuple[int, int, int, int]] | None:
    """Each lane's MCU box clipped to the splice box (None when one of them misses it): where the
    JPEG writer decodes, blends and encodes a square alone. Two of them may share an MCU: each then
    blends every lane's pixels there (apply_lanes_at clips every lane to its window), so both write
    the same blocks."""
    parts = []
    for lane in lanes:
        x0, y0, x1, y1 = jpeg_codec.mcu_box(lane.box, layout)
        part = (max(x0, box[0]), max(y0, box[1]), min(x1, box[2]), min(y1, box[3]))
        if part[0] < part[2] and part[1] < part[3]:
            parts.append(part)
    return parts or None


def _kept_mcus(
    keep: np.ndarray, mark_box: tuple[int, int, int, int], box: tuple[int, int, int, int],
    layout: jpeg_codec.JpegLayout,
) -> np.ndarray | None:
    """The splice box's MCUs (rows x columns, True) the keep-out mask forbids; None when none. keep is
    MCU-granular over mark_box, so each MCU's top-left pixel speaks for it."""
    mw, mh = layout.mcu_size
    inner = keep[box[1] - mark_box[1] : box[3] - mark_box[1], box[0] - mark_box[0] : box[2] - mark_box[0]]
    holes = inner[::mh, ::mw]
    return holes if holes.any() else None


def _splice_jpeg(
    src: Path, data: bytes, im: Image.Image, layout: jpeg_codec.JpegLayout, box: tuple[int, int, int, int],
    patch: Callable[..., np.ndarray], loaded: bool, holes: np.ndarray | None = None,
    parts: list[tuple[int, int, int, int]] | None = None,
) -> tuple[bytes, bool]:
    """The patched JPEG with only the box's blocks re-encoded (patch: the box's pixels, patched), and
    whether the MCUs in `holes` kept their coefficients (wherever libturbojpeg is there; without it
    jpegtran's drop re-encodes them from their own pixels). Raises SpliceUnavailable.

    Cheapest first: the bit-level splice (poisoner/jpeg_scan.py: one Huffman decode, every other MCU's
    bits copied), else one in-process coefficient pass (libturbojpeg), else jpegtran's lossless crop of
    the box, else the box cut from the whole decoded picture; the four write the same coefficients."""
    exact = jpeg_codec.turbo_available() is None
    if loaded:
        return jpeg_codec.splice_patch(src, im, layout, patch(np.asarray(im.crop(box))), box, holes), exact
    try:
        def encode(pixels: np.ndarray) -> bytes:
            return jpeg_codec.encode_like(pixels, im, layout, metadata=False)

        return jpeg_scan.patch_in_place(data, encode, box, patch, holes, parts), True
    except jpeg_scan.Unsupported as exc:
        log.info("jpeg bit-level splice unavailable", extra={"path": str(src), "reason": str(exc)})
    try:
        return jpeg_codec.patch_in_one_pass(data, im, layout, box, patch, holes, parts), True
    except jpeg_codec.SpliceUnavailable as exc:
        log.info("jpeg in-process splice unavailable", extra={"path": str(src), "reason": str(exc)})
    try:
        box_pixels = jpeg_codec.decode_box(src, im, layout, box)
    except jpeg_codec.SpliceUnavailable as exc:
        log.info("jpeg region decode unavailable", extra={"path": str(src), "reason": str(exc)})
        _load_decoded(src, im)
        box_pixels = np.asarray(im.crop(box))
    return jpeg_codec.splice_patch(src, im, layout, patch(box_pixels), box, holes), exact


# ---- entry points --------------------------------------------------------------------------------
class PoisonOptions(TypedDict, total=False):
    """poison_file's keyword options (poison_in_place passes them on unchanged)."""

    marker: Marker | None
    keep_location: bool
    max_pixels: int | None
    keep_out: np.ndarray | None


def poison_file(
    src: Path,
    dst: Path,
    spec: PatchSpec,
    *,
    marker: Marker | None = None,
    keep_location: bool = False,
    max_pixels: int | None = None,
    keep_out: np.ndarray | None = None,
) -> PoisonReport:
    """Read src, write the complete poisoned file to dst (src is only read): poison_bytes, written.

    Location metadata (GPS, place names) is removed from dst unless keep_location; with a marker,
    dst carries it (poisoner.provenance). A file whose header declares more than max_pixels
    (None: poisoner.limits.DEFAULT_MAX_PIXELS) is refused before anything is decoded.
    keep_out (H x W of the stored picture, nonzero = never change this pixel; e.g. a subject mask
    from poisoner.subject): the mark is not written there (a JPEG keeps the whole MCUs that reach
    such a pixel); a mask of another size is an ImageFormatError."""
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ImageFormatError(f"{src.name}: dst must differ from src (use poison_in_place)")
    out, report = poison_bytes(src, spec, marker=marker, keep_location=keep_location, max_pixels=max_pixels,
                               keep_out=keep_out)  # fmt: skip
    dst.write_bytes(out)
    return report


def poison_bytes(
    src: Path,
    spec: PatchSpec,
    *,
    data: bytes | None = None,
    marker: Marker | None = None,
    keep_location: bool = False,
    max_pixels: int | None = None,
    keep_out: np.ndarray | None = None,
) -> tuple[bytes, PoisonReport]:
    """The complete poisoned file's bytes and the report, nothing written: poison_file's work, for a
    caller that writes the bytes itself (the daemon seals, hashes and writes them once). data: src's
    bytes when the caller holds them already (they must be src's: src names the file in messages
    and is what a decoder that reads by path reads)."""
    src = Path(src)
    data = source = _read_source(src, max_pixels, data)
    # An arithmetic-coded JPEG is read and patched as jpegtran codes it with Huffman tables (Pillow's
    # libjpeg may not decode it; the same coefficients), the output coded back as the source was.
    coding = jpeg_file.arithmetic_coding(data) if data[:2] == b"\xff\xd8" else None
    if coding is not None:
        data = jpeg_file.huffman_coded(src, data)
    elif data[:2] == b"\xff\xd8":  # no jpegtran: Pillow's libjpeg alone must decode it
        jpeg_file.check_arithmetic(src, data)
    # A JPEG need not be decoded to pixels whole (only the patch's MCUs, _poison_jpeg).
    region = JPEG_REGION_DECODE and data[:2] == b"\xff\xd8" and jpeg_codec.splice_available()
    im = open_decoded(src, data, load=not region)
    fmt = im.format or "unknown"
    if region and fmt != "JPEG":
        load_decoded(src, im)
    width, height = im.size
    keep = checked_keep_out(src.name, keep_out, (width, height))
    loaded = not region or fmt != "JPEG"  # a JPEG patched by region is not decoded whole
    placement, place = plan_mark(src.name, data, (width, height), spec, keep, im if loaded else None)
    lanes = lane_placements(placement)  # squares placed apart: counted a square at a time (the same pixels)
    written = sum(written_pixels(square, keep) for square in lanes or [placement])
    if written == 0:  # never "patched" with no changed pixel (issue 25): nothing is written to dst
        raise MarkNotWritten(
            # "the whole mark" read as the whole photo where a pocket too small for it was free (a review)
            f"{src.name}: the subject mask covers every pixel the mark would write (no free part of the "
            "photo holds its squares), no pixel would change: not patched"
        )
    if loaded and not changes_a_pixel(im, lanes or [placement], keep):  # a JPEG by region: its splice says
        raise MarkNotWritten(
            f"{src.name}: the mark's blocks match the photo's pixels where it goes, no pixel would change: "
            "not patched"
        )
    out, preserved, notes, method, lossless, removed = _write_format(
        src, im, data, fmt, placement, keep, keep_location=keep_location, marker=marker, loaded=not region,
        coding=coding,
    )
    jpeg_scan.forget()  # the source's index (as large as the file) is done with
    if method == "jpeg-unchanged":  # whole MCUs near the mask are kept: none left to write
        raise MarkNotWritten(
            f"{src.name}: the subject mask reaches every 8x8 block of the mark, no pixel would change: "
            "not patched"
        )
    if fmt == "JPEG" and coding is None:  # (an arithmetic-coded one: checked before it is coded back)
        _check_changed(src, data, out)
    notes += [n for n in [kept_out_note(placement, keep)] if n]
    notes += _file_notes(src, im, fmt, removed)
    after = {"JPEG": jpeg_file.trailer_bytes, "PNG": png_file.bytes_after_iend}.get(fmt)
    trailer = 0 if after is None else after(source)
    if trailer:
        notes.append(f"{trailer} bytes after the picture's end (an appended image or a trailer) not written")
    report = PoisonReport(
        fmt, width, height, placement, preserved, notes, method, lossless, len(source), len(out), removed,
        written, place, trailer,
    )
    log.info(
        "poisoned image",
        extra={"src": str(src), "format": fmt, "method": method, "size": f"{width}x{height}", "notes": notes},
    )
    return out, report


def _read_source(src: Path, max_pixels: int | None, held: bytes | None) -> bytes:
    """src's bytes (held: the caller's copy of them), once the header's size is within budget."""
    check_decode_budget(src, DEFAULT_MAX_PIXELS if max_pixels is None else max_pixels)
    if held is not None:
        return held
    try:
        return src.read_bytes()
    except OSError as exc:
        raise ImageFormatError(f"{src.name}: cannot read ({one_line(exc)})") from exc


def plan_mark(
    name: str,
    data: bytes,
    size: tuple[int, int],
    spec: PatchSpec,
    keep: np.ndarray | None = None,
    decoded: Image.Image | None = None,
) -> tuple[PatchPlacement, MarkPlace | None]:
    """Where the mark goes on this file (stored pixels) and, for a per-photo spec, where it shows
    and why. A per-photo spec judges the file's own display-oriented thumbnail and its keep-out
    (subject) mask (poisoner.placement.place_on_photo); any other spec (a corner, `--position`)
    resolves on the size a viewer sees, its corner the one the photo shows (EXIF orientation: a
    phone's portrait photo gets its top-left mark top-left as shown, issue 25), turned back to the
    stored pixels (the real name: moving specs, issue #9). What ppd preview calls too, so both agree.
    `decoded`: the file already loaded, so the thumbnail need not decode it again where that is exact."""
    width, height = size
    try:
        if not spec.per_photo:
            return _resolved_as_shown(spec, width, height, name, shown_orientation(data, decoded)), None
        detail, faint, orientation = display_details(data, name, decoded)
        subject = None if keep is None else display_subject(keep, orientation, detail.shape)
        # issue 25 round 3: squares cropped to fit where no plain place holds them whole
        return place_fitting(spec, width, height, name, orientation, detail, subject, faint=faint)
    except (SpecError, ValueError) as exc:
        raise ImageFormatError(f"{name}: {exc}") from exc


def _resolved_as_shown(
    spec: PatchSpec, width: int, height: int, name: str, orientation: int
) -> PatchPlacement:
    """spec resolved on the picture as shown (display size), turned back to stored pixels."""
    if orientation == 1:
        return spec.resolve(width, height, image_key=name)
    dw, dh = display_size(width, height, orientation)
    return turned_to_stored(spec.resolve(dw, dh, image_key=name), orientation, (dw, dh))


def _write_format(
    src: Path,
    im: Image.Image,
    data: bytes,
    fmt: str,
    placement: PatchPlacement,
    keep_out: np.ndarray | None,
    *,
    keep_location: bool,
    marker: Marker | None,
    loaded: bool,
    coding: jpeg_codec.JpegLayout | None = None,
) -> tuple[bytes, list[str], list[str], str, bool, list[str]]:
    """The format's writer: (bytes, preserved, notes, method, lossless, location removed). coding: an
    arithmetic-coded JPEG's own layout (data is its Huffman-coded copy): the output is coded so again."""
    removed: list[str] = []
    lossless = False
    if fmt == "JPEG":
        out, preserved, notes, method = _poison_jpeg(src, im, data, placement, keep_out, loaded=loaded)
        out, shown = previews.jpeg_previews(src.name, out)  # the original's thumbnails: the patched picture's
        notes += shown
        if coding is not None and method != "jpeg-unchanged":
            _check_changed(src, data, out)
            out = jpeg_file.coded_like(src, out, coding)
            notes.append("arithmetic coding: patched Huffman-coded, then coded back losslessly (jpegtran)")
        out, had_mpf = jpeg_file.without_mpf(out)
        if had_mpf:
            notes.append("MPF segment (the index of the images after the picture) not written")
        if not keep_location:
            out, removed = _strip_jpeg(src, out)
        if marker is not None:
            out = _jpeg_marker(src, out, marker)
    elif fmt == "PNG":
        # the source's filtered rows re-used where the file allows, else the whole re-encode
        fast = poison_png_rows(im, data, lane_placements(placement) or [placement], keep_out)
        out, preserved, notes = fast if fast is not None else poison_png(im, data, placement, keep_out)
        method, lossless = "png-lossless", True
        if not keep_location:
            out, removed = strip_png_location(out)
        out, shown = previews.png_previews(out)
        notes = [*notes, *shown]
        if marker is not None:
            out = provenance.embed_png(out, marker)
    elif fmt == "WEBP":
        out, preserved, notes, lossless, removed = poison_webp(
            im, data, placement, keep_location, marker, keep_out
        )
        method = "webp-lossless" if lossless else "webp-lossy"
    elif fmt == "TIFF":
        out, preserved, notes, lossless, removed = poison_tiff(im, placement, keep_location, marker, keep_out)
        method = "tiff"
    elif fmt in ("HEIF", "AVIF"):
        out, preserved, notes, removed = poison_heif(
            im, fmt, placement, keep_location, marker, keep_out, data
        )
        method = fmt.lower()
    else:
        raise ImageFormatError(f"{src.name}: {fmt} files are not supported")
    return out, preserved, notes, method, lossless, removed


def _check_changed(src: Path, data: bytes, out: bytes) -> None:
    """MarkNotWritten when the patched JPEG codes the very picture of the source (a mark too faint to
    change a coefficient, --alpha 0.001): such a file is never called patched."""
    if jpeg_file.same_coded_picture(data, out):
        raise MarkNotWritten(f"{src.name}: the mark is too faint to change any pixel of it: not patched")


def _file_notes(src: Path, im: Image.Image, fmt: str, removed: list[str]) -> list[str]:
    """Notes on the file as a whole: location removed, orientation kept, a suffix that lies."""
    notes: list[str] = []
    if removed:
        notes.append(f"location removed ({len(removed)}): " + ", ".join(removed))
    orientation = im.getexif().get(0x0112)
    if orientation and orientation != 1:
        notes.append(f"EXIF orientation {orientation} kept; {SHOWN_ORIENTATION_POLICY}")
    if is_image(src) and not _suffix_matches(src.suffix.lower(), fmt):
        notes.append(f"content is {fmt} despite the {src.suffix} suffix: kept as {fmt} (not converted)")
    return notes


def _strip_jpeg(src: Path, out: bytes) -> tuple[bytes, list[str]]:
    try:
        return location.strip_jpeg_location(out)
    except location.MetadataParseError as exc:
        raise ImageFormatError(f"{src.name}: cannot remove location from the JPEG header ({exc})") from exc


def _jpeg_marker(src: Path, out: bytes, marker: Marker) -> bytes:
    try:
        return provenance.embed_jpeg(out, marker)
    except location.MetadataParseError as exc:
        raise ImageFormatError(f"{src.name}: cannot add the provenance marker ({exc})") from exc


def _suffix_matches(suffix: str, fmt: str) -> bool:
    expected = {
        "JPEG": {".jpg", ".jpeg", ".jpe", ".jfif", ".jfi", ".jif", ".pjpeg", ".pjp"},
        "PNG": {".png"},
        "WEBP": {".webp"},
        "TIFF": {".tif", ".tiff"},
        "HEIF": {".heic", ".heif", ".hif"},
        "AVIF": {".avif"},
    }
    return suffix in expected.get(fmt, set())


def poison_in_place(path: Path, spec: PatchSpec, **options: Unpack[PoisonOptions]) -> PoisonReport:
    """Poison path atomically: a crash leaves the original or the complete poisoned file.
    Permission bits are kept (poisoner.atomic). options: poison_file's."""
    path = Path(path)
    with atomic_output(path) as tmp:
        return poison_file(path, tmp, spec, **options)
