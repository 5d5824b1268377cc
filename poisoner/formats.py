"""Image files, faithfully: read a photo, blend the dataset's patch in, write the same kind of file.

What "faithfully" means per format (docs/FORMATS.md has the measured details):
- JPEG: only the MCUs the patch touches are re-encoded (DCT-coefficient splice, poisoner.jpeg);
  if that is impossible, one re-encode with the source's own quantisation tables and chroma
  subsampling. EXIF, ICC, XMP, IPTC and comments are kept.
- PNG: lossless; the new pixel data (IHDR/PLTE/tRNS/IDAT) is spliced between the source's own
  ancillary chunks, copied byte for byte (text, iCCP, eXIf, pHYs, gAMA, cHRM, sRGB, tIME, ...).
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

Every input is fully decoded before anything is written, so a truncated file fails before dst
exists; errors are ImageFormatError with a one-line message, and src is never opened for writing.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import logging
import struct
import warnings
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageFile

from poisoner import jpeg as jpeg_codec
from poisoner import location, provenance
from poisoner.atomic import atomic_output
from poisoner.blend import apply_patch
from poisoner.errors import ImageFormatError
from poisoner.media import is_image
from poisoner.provenance import Marker
from poisoner.spec import PatchPlacement, PatchSpec, SpecError

log = logging.getLogger(__name__)

# JPEG: decode only a lossless crop around the patch's MCUs (poisoner.jpeg.decode_box) instead of
# the whole picture. Same output bytes either way (tests/test_jpeg_region.py); False: whole decode.
JPEG_REGION_DECODE = True

ORIENTATION_POLICY = "patch placed in stored pixels (EXIF orientation ignored, tag kept)"
PALETTE_POLICY = "patch colours appended to the palette when there is room, else written as RGB(A)"


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


# ---- reading -----------------------------------------------------------------------------------
_heif_registered = False


def _register_heif() -> None:
    global _heif_registered
    if not _heif_registered:
        try:
            import pillow_heif

            pillow_heif.register_heif_opener()
        except ImportError:  # HEIC stays unsupported; everything else works
            log.warning("pillow-heif not installed: HEIC files are unsupported")
        _heif_registered = True


def image_from_array(pixels: np.ndarray, mode: str) -> Image.Image:
    """Image.fromarray that also takes 16-bit grey (Pillow 13 infers I;16 from uint16 itself)."""
    if mode == "I;16":
        return Image.fromarray(np.ascontiguousarray(pixels, dtype=np.uint16))
    return Image.fromarray(pixels, mode)


def paste_patch(im: Image.Image, placement: PatchPlacement) -> Image.Image:
    """im with the patch blended in, in place: only the patch box goes through numpy, so memory
    stays at one decoded picture (a whole-picture array costs one or two more, measured)."""
    x0, y0, _, _ = placement.box
    local = dataclasses.replace(placement, x=0, y=0)
    region = apply_patch(np.asarray(im.crop(placement.box)), local)
    im.paste(image_from_array(region, im.mode), (x0, y0))
    return im


def save_explicit(im: Image.Image, fp: io.BytesIO, fmt: str, **opts: object) -> None:
    """Save with only the metadata in opts. Pillow's writers fall back to im.info (the source's
    EXIF, XMP...) for what opts leave out, and its TIFF writer copies XMP/IPTC from a TIFF
    source's own tags: either would bring removed location back. A plain Image sharing the
    pixel memory (no copy) carries neither."""
    plain = im._new(im.im)  # noqa: SLF001 - Pillow's own shallow constructor
    plain.info = {}
    plain.save(fp, fmt, **opts)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


@contextlib.contextmanager
def _decode_errors(src: Path) -> Iterator[None]:
    """Every failure of opening or decoding becomes one ImageFormatError line."""
    try:
        with warnings.catch_warnings():
            # Pillow only warns between MAX_IMAGE_PIXELS and twice that: refuse instead.
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            yield
    except ImageFormatError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ImageFormatError(f"{src.name}: decompression-bomb limit: {_one_line(exc)}") from exc
    except Image.UnidentifiedImageError as exc:
        raise ImageFormatError(f"{src.name}: not a recognised image file") from exc
    except (OSError, SyntaxError, ValueError, struct.error, zlib.error, EOFError) as exc:
        raise ImageFormatError(f"{src.name}: cannot decode ({_one_line(exc)})") from exc
    except (TypeError, KeyError, IndexError) as exc:
        # Pillow's TIFF reader raises these on corrupt tags ("Missing dimensions", a bytes
        # strip offset); found by the fuzz run. Confined to open/load, so not our bugs.
        raise ImageFormatError(f"{src.name}: cannot decode ({type(exc).__name__}: {_one_line(exc)})") from exc


def _open_decoded(src: Path, data: bytes, *, load: bool = True) -> Image.Image:
    """Open and (with load) fully decode; every failure becomes one ImageFormatError line.
    Without load only the header is read: the caller must decode (_load_decoded) or have the
    whole file checked another way before writing anything."""
    if not data:
        raise ImageFormatError(f"{src.name}: empty file (0 bytes)")
    _register_heif()
    with _decode_errors(src):
        im = Image.open(io.BytesIO(data))
        limit = Image.MAX_IMAGE_PIXELS
        if limit is not None and im.size[0] * im.size[1] > limit:
            raise ImageFormatError(
                f"{src.name}: {im.size[0]}x{im.size[1]} exceeds the {limit}-pixel decompression-bomb limit"
            )
        if getattr(im, "n_frames", 1) > 1:
            raise ImageFormatError(
                f"{src.name}: {im.format} with {im.n_frames} frames/pages is not supported"
            )
        if ImageFile.LOAD_TRUNCATED_IMAGES:
            raise ImageFormatError("refusing to run with PIL LOAD_TRUNCATED_IMAGES enabled")
        if load:
            im.load()
    return im


def _load_decoded(src: Path, im: Image.Image) -> Image.Image:
    with _decode_errors(src):
        im.load()
    return im


# ---- PNG chunk splice ----------------------------------------------------------------------------
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PIXEL_CHUNKS = {b"IHDR", b"PLTE", b"tRNS", b"IDAT", b"IEND"}
_AFTER_PLTE = {b"bKGD", b"hIST"}
_ANIMATION = {b"acTL", b"fcTL", b"fdAT"}


def png_chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """[(type, body)] of a PNG byte string (CRC not rechecked: Pillow already decoded it)."""
    if not data.startswith(PNG_SIGNATURE):
        raise ValueError("not a PNG")
    chunks: list[tuple[bytes, bytes]] = []
    pos = len(PNG_SIGNATURE)
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        ctype = data[pos + 4 : pos + 8]
        chunks.append((ctype, data[pos + 8 : pos + 8 + length]))
        pos += 12 + length
        if ctype == b"IEND":
            break
    return chunks


def _chunk(ctype: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + ctype + body + struct.pack(">I", zlib.crc32(ctype + body))


def splice_png(source: bytes, pixels_png: bytes) -> tuple[bytes, list[str]]:
    """The source's ancillary chunks around the new file's pixel chunks. Returns (bytes, kept types)."""
    src = png_chunks(source)
    new = png_chunks(pixels_png)
    first_idat = next(i for i, (t, _) in enumerate(src) if t == b"IDAT")
    before = [c for c in src[:first_idat] if c[0] not in _PIXEL_CHUNKS and c[0] not in _AFTER_PLTE]
    after_plte = [c for c in src[:first_idat] if c[0] in _AFTER_PLTE]
    after = [c for c in src[first_idat:] if c[0] not in _PIXEL_CHUNKS]
    new_pixel = {t: [b for tt, b in new if tt == t] for t in (b"IHDR", b"PLTE", b"tRNS", b"IDAT")}
    parts = [PNG_SIGNATURE, _chunk(b"IHDR", new_pixel[b"IHDR"][0])]
    parts += [_chunk(t, b) for t, b in before]
    parts += [_chunk(b"PLTE", b) for b in new_pixel[b"PLTE"]]
    # hIST counts palette entries: stale when the palette grew.
    if new_pixel[b"PLTE"] and any(t == b"PLTE" and b != new_pixel[b"PLTE"][0] for t, b in src):
        after_plte = [c for c in after_plte if c[0] != b"hIST"]
    parts += [_chunk(b"tRNS", b) for b in new_pixel[b"tRNS"]]
    parts += [_chunk(t, b) for t, b in after_plte]
    parts += [_chunk(b"IDAT", b) for b in new_pixel[b"IDAT"]]
    parts += [_chunk(t, b) for t, b in after]
    parts.append(_chunk(b"IEND", b""))
    kept = [t.decode("latin-1") for t, _ in before + after_plte + after]
    return b"".join(parts), kept


def strip_png_location(data: bytes) -> tuple[bytes, list[str]]:
    """The PNG with location removed from its ancillary chunks (eXIf, XMP iTXt, raw profiles);
    pixel chunks and every other chunk are copied byte for byte."""
    parts = [PNG_SIGNATURE]
    removed: list[str] = []
    for ctype, body in png_chunks(data):
        if ctype not in _PIXEL_CHUNKS:
            cleaned, gone = location.clean_png_chunk(ctype, body)
            removed += [f"PNG {ctype.decode('latin-1')}: {g}" for g in gone]
            if cleaned is None:
                continue
            body = cleaned
        parts.append(_chunk(ctype, body))
    return (b"".join(parts), removed) if removed else (data, [])


def _png_ihdr(data: bytes) -> tuple[int, int, bool]:
    """(bit depth, colour type, interlaced) from the IHDR."""
    body = png_chunks(data)[0][1]
    return body[8], body[9], body[12] == 1


def _decode_png16_colour(data: bytes, colour_type: int) -> np.ndarray:
    """16-bit RGB / RGBA PNG pixels via FFmpeg's PNG decoder (Pillow reads them as 8-bit)."""
    import av  # lazy: only 16-bit colour PNGs need it

    fmt = "rgb48le" if colour_type == 2 else "rgba64le"
    codec = av.CodecContext.create("png", "r")
    frames = codec.decode(av.Packet(data))
    if not frames:
        raise ImageFormatError("16-bit PNG: FFmpeg decoded no frame")
    return frames[0].to_ndarray(format=fmt)


def _encode_png16_colour(pixels: np.ndarray) -> bytes:
    import av

    h, w, c = pixels.shape
    src_fmt, dst_fmt = ("rgb48le", "rgb48be") if c == 3 else ("rgba64le", "rgba64be")
    enc = av.CodecContext.create("png", "w")
    enc.width, enc.height, enc.pix_fmt = w, h, dst_fmt
    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(pixels), format=src_fmt).reformat(format=dst_fmt)
    packets = list(enc.encode(frame)) + list(enc.encode(None))
    return b"".join(bytes(p) for p in packets)


def _palette_patch(im: Image.Image, placement: PatchPlacement) -> tuple[Image.Image, list[str]]:
    """Patch a palette image; keep it a palette image when the new colours fit."""
    notes: list[str] = []
    has_alpha = "transparency" in im.info
    rgb_mode = "RGBA" if has_alpha else "RGB"
    full = np.asarray(im.convert(rgb_mode))
    patched = apply_patch(full, placement)
    x0, y0, x1, y1 = placement.box
    region = patched[y0:y1, x0:x1].reshape(-1, full.shape[2])
    palette = np.asarray(im.getpalette(rawmode="RGB"), dtype=np.uint8).reshape(-1, 3)
    trns = im.info.get("transparency")
    alphas = np.full(len(palette), 255, dtype=np.uint8)
    if isinstance(trns, bytes):
        alphas[: len(trns)] = np.frombuffer(trns, dtype=np.uint8)[: len(palette)]
    elif isinstance(trns, int) and trns < len(palette):
        alphas[trns] = 0
    entries = np.concatenate([palette, alphas[:, None]], axis=1) if has_alpha else palette
    wanted = np.unique(region, axis=0)
    lookup = {tuple(e): i for i, e in reversed(list(enumerate(entries.tolist())))}
    missing = [tuple(c) for c in wanted.tolist() if tuple(c) not in lookup]
    if len(entries) + len(missing) > 256:
        notes.append(f"palette full ({len(entries)} + {len(missing)} colours > 256): written as {rgb_mode}")
        return Image.fromarray(patched, rgb_mode), notes
    for c in missing:
        lookup[c] = len(entries)
        entries = np.vstack([entries, np.asarray(c, dtype=np.uint8)[None]])
    indices = np.asarray(im).copy()
    codes = np.fromiter((lookup[tuple(c)] for c in region.tolist()), dtype=np.uint8, count=len(region))
    indices[y0:y1, x0:x1] = codes.reshape(y1 - y0, x1 - x0)
    out = Image.fromarray(indices, "P")
    out.putpalette(entries[:, :3].tobytes(), rawmode="RGB")
    if has_alpha:
        out.info["transparency"] = entries[:, 3].tobytes()
    if missing:
        notes.append(f"{len(missing)} patch colour(s) appended to the palette ({len(entries)} entries)")
    return out, notes


def _poison_png(
    im: Image.Image, data: bytes, placement: PatchPlacement
) -> tuple[bytes, list[str], list[str]]:
    depth, colour_type, interlaced = _png_ihdr(data)
    if any(t in _ANIMATION for t, _ in png_chunks(data)):
        raise ImageFormatError("animated PNG (APNG) is not supported")
    notes: list[str] = []
    if interlaced:
        notes.append("Adam7 interlacing not kept (written non-interlaced; pixels identical)")
    buf = io.BytesIO()
    if depth == 16 and colour_type in (2, 6):
        pixels = _decode_png16_colour(data, colour_type)
        encoded = _encode_png16_colour(apply_patch(pixels, placement))
        notes.append("16-bit colour PNG coded with FFmpeg's PNG codec (Pillow reads it as 8-bit)")
    elif depth == 16 and colour_type == 4:
        raise ImageFormatError("16-bit grey+alpha PNG is not supported (Pillow reads it as 8-bit)")
    elif im.mode == "P":
        out, pnotes = _palette_patch(im, placement)
        notes += pnotes
        save_opts: dict[str, object] = {}
        if "transparency" in out.info:
            save_opts["transparency"] = out.info["transparency"]
        out.save(buf, "PNG", **save_opts)
        encoded = buf.getvalue()
    else:
        mode = im.mode
        if mode == "1":
            im = im.convert("L")
            mode = "L"
            notes.append("1-bit PNG written as 8-bit greyscale")
        if mode not in ("L", "LA", "RGB", "RGBA", "I;16"):
            raise ImageFormatError(f"PNG mode {mode} is not supported")
        out = paste_patch(im, placement)
        save_opts = {}
        if "transparency" in im.info and mode in ("L", "RGB", "I;16"):
            save_opts["transparency"] = im.info["transparency"]  # tRNS colour key
            key = im.info["transparency"]
            region = np.asarray(out.crop(placement.box))
            key_arr = np.asarray(key, dtype=region.dtype)
            hit = (region == key_arr).all(axis=-1) if region.ndim == 3 else region == key_arr
            if hit.any():
                notes.append("some patch pixels equal the tRNS colour key and show as transparent")
        out.save(buf, "PNG", **save_opts)
        encoded = buf.getvalue()
    spliced, kept = splice_png(data, encoded)
    return spliced, [f"PNG {c}" for c in kept], notes


# ---- WebP ----------------------------------------------------------------------------------------
def _riff_chunks(data: bytes) -> dict[bytes, bytes]:
    chunks: dict[bytes, bytes] = {}
    pos = 12
    while pos + 8 <= len(data):
        ctype = data[pos : pos + 4]
        (size,) = struct.unpack("<I", data[pos + 4 : pos + 8])
        chunks.setdefault(ctype, data[pos + 8 : pos + 8 + size])
        pos += 8 + size + (size & 1)
    return chunks


class _BoolDecoder:
    """VP8's boolean entropy decoder (RFC 6386, section 7), just enough to read the frame header."""

    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 2
        self.value = (data[0] << 8) | data[1]
        self.range, self.bit_count = 255, 0

    def bool(self, prob: int = 128) -> int:
        split = 1 + (((self.range - 1) * prob) >> 8)
        big_split = split << 8
        if self.value >= big_split:
            bit, self.range, self.value = 1, self.range - split, self.value - big_split
        else:
            bit, self.range = 0, split
        while self.range < 128:
            self.value <<= 1
            self.range <<= 1
            self.bit_count += 1
            if self.bit_count == 8:
                self.bit_count = 0
                if self.pos < len(self.data):
                    self.value |= self.data[self.pos]
                    self.pos += 1
        return bit

    def literal(self, bits: int) -> int:
        v = 0
        for _ in range(bits):
            v = (v << 1) | self.bool()
        return v

    def signed(self, bits: int) -> int:
        v = self.literal(bits)
        return -v if self.bool() else v


def vp8_quantizers(vp8: bytes) -> list[int]:
    """The luma AC quantiser index (0..127) of each segment of a VP8 key frame."""
    if len(vp8) < 12 or vp8[3:6] != b"\x9d\x01\x2a" or vp8[0] & 1:
        raise ValueError("not a VP8 key frame")
    d = _BoolDecoder(vp8[10:])
    d.literal(2)  # colour space, clamping
    segment_quant: list[int] | None = None
    absolute = False
    if d.bool():  # segmentation enabled
        update_map = d.bool()
        if d.bool():  # update segment feature data
            absolute = bool(d.bool())
            segment_quant = [d.signed(7) if d.bool() else 0 for _ in range(4)]
            for _ in range(4):
                if d.bool():
                    d.signed(6)
        if update_map:
            for _ in range(3):
                if d.bool():
                    d.literal(8)
    d.literal(1 + 6 + 3)  # filter type, level, sharpness
    if d.bool() and d.bool():  # loop-filter deltas enabled and updated
        for _ in range(8):
            if d.bool():
                d.signed(6)
    d.literal(2)  # partitions
    base = d.literal(7)
    if segment_quant is None:
        return [base]
    return [q if absolute else max(0, min(127, base + q)) for q in segment_quant]


def webp_quality_from_quantizer(q: float) -> int:
    """Invert libwebp's quality -> quantiser mapping (src/enc/quant_enc.c, QualityToCompression)."""
    c = 1.0 - q / 127.0
    linear = c**3
    quality = linear * 1.5 if linear < 0.5 else (linear + 1.0) / 2.0
    return int(round(max(0.0, min(1.0, quality)) * 100))


def _clean_exif_xmp(
    info: dict[str, object], keep_location: bool, label: str, marker: Marker | None
) -> tuple[bytes | None, bytes | None, list[str]]:
    """The source's EXIF and XMP for a re-encoded file: location removed unless kept, the
    provenance marker added to the XMP when given."""
    exif = info.get("exif") or None
    xmp = info.get("xmp") or None
    removed: list[str] = []
    if isinstance(xmp, str):
        xmp = xmp.encode()
    if marker is not None:
        xmp = provenance.xmp_with_marker(xmp, marker)  # type: ignore[arg-type]
    if keep_location:
        return exif, xmp, removed  # type: ignore[return-value]
    if isinstance(exif, bytes):
        exif, gone = location.clean_exif(exif)
        removed += [f"{label} {g}" for g in gone]
    if isinstance(xmp, bytes):
        xmp, gone = location.strip_xmp_location(xmp)
        removed += [f"{label} {g}" for g in gone]
    return exif, xmp, removed  # type: ignore[return-value]



def _metadata_options(
    info: dict, keep_location: bool, fmt: str, marker: Marker | None, opts: dict[str, object]
) -> tuple[list[str], list[str]]:
    """Put the cleaned EXIF, the ICC profile and the cleaned (marked) XMP into Pillow's save
    options; returns (what was kept, what location was removed)."""
    exif, xmp, removed = _clean_exif_xmp(info, keep_location, fmt, marker)
    preserved = []
    for key, label, value in (("exif", "EXIF", exif), ("icc_profile", "ICC", info.get("icc_profile")),
                              ("xmp", "XMP", xmp)):  # fmt: skip
        if value:
            opts[key] = value
            preserved.append(f"{fmt} {label}")
    return preserved, removed

def _poison_webp(
    im: Image.Image, data: bytes, placement: PatchPlacement, keep_location: bool, marker: Marker | None
) -> tuple[bytes, list[str], list[str], bool, list[str]]:
    chunks = _riff_chunks(data)
    lossless = b"VP8L" in chunks
    notes: list[str] = []
    opts: dict[str, object] = {"exact": True, "method": 4}
    if lossless:
        opts["lossless"] = True
    else:
        try:
            quant = vp8_quantizers(chunks[b"VP8 "])
            # libwebp spreads segment quantisers above its base one: the finest segment is
            # closest to the base (measured: q30->35, q50->55, q75->77, q90->91).
            quality = webp_quality_from_quantizer(float(min(quant)))
            notes.append(f"lossy WebP re-encoded at quality {quality} (from VP8 quantisers {quant})")
        except (KeyError, ValueError, IndexError) as exc:
            quality = 90
            notes.append(f"lossy WebP re-encoded at quality 90 (source quality unknown: {exc})")
        opts["quality"] = quality
        if b"ALPH" in chunks:
            opts["alpha_quality"] = 100
    preserved, removed = _metadata_options(im.info, keep_location, "WebP", marker, opts)
    mode = im.mode if im.mode in ("RGB", "RGBA") else "RGBA" if "A" in im.mode else "RGB"
    out = paste_patch(im if im.mode == mode else im.convert(mode), placement)
    buf = io.BytesIO()
    save_explicit(out, buf, "WEBP", **opts)
    return buf.getvalue(), preserved, notes, lossless, removed


# ---- TIFF ----------------------------------------------------------------------------------------
# Tags that describe the picture, not its layout: safe to copy onto the re-written file.
_TIFF_KEEP_TAGS = {
    269: "DocumentName",
    270: "ImageDescription",
    271: "Make",
    272: "Model",
    274: "Orientation",
    282: "XResolution",
    283: "YResolution",
    285: "PageName",
    296: "ResolutionUnit",
    305: "Software",
    306: "DateTime",
    315: "Artist",
    316: "HostComputer",
    318: "WhitePoint",
    319: "PrimaryChromaticities",
    33432: "Copyright",
}
_TIFF_LOSSLESS = {"raw", "tiff_lzw", "tiff_deflate", "tiff_adobe_deflate", "packbits", None}


def _poison_tiff(
    im: Image.Image, placement: PatchPlacement, keep_location: bool, marker: Marker | None
) -> tuple[bytes, list[str], list[str], bool, list[str]]:
    if im.mode not in ("L", "LA", "RGB", "RGBA", "I;16", "I;16B", "P", "1"):
        raise ImageFormatError(f"TIFF mode {im.mode} is not supported")
    bits = im.tag_v2.get(258)
    if im.mode in ("RGB", "RGBA") and bits and max(bits) > 8:
        raise ImageFormatError("16-bit colour TIFF is not supported (Pillow reads it as 8-bit)")
    notes: list[str] = []
    compression = im.info.get("compression", "raw")
    mode = im.mode
    if mode in ("P", "1"):
        mode = "RGBA" if "transparency" in im.info else "RGB" if mode == "P" else "L"
        notes.append(f"{im.mode} TIFF written as {mode}")
    src = im.convert(mode) if mode != im.mode else im
    if mode == "I;16B":
        out = image_from_array(apply_patch(np.asarray(src).astype(np.uint16), placement), "I;16")
    else:
        out = paste_patch(src, placement)
    info = {tag: im.tag_v2[tag] for tag in _TIFF_KEEP_TAGS if tag in im.tag_v2}
    opts: dict[str, object] = {"compression": compression, "tiffinfo": info}
    preserved = [f"TIFF {_TIFF_KEEP_TAGS[t]}" for t in info]
    removed: list[str] = []
    _, xmp, removed = _clean_exif_xmp({"xmp": im.info.get("xmp")}, keep_location, "TIFF", marker)
    if im.info.get("icc_profile"):
        opts["icc_profile"] = im.info["icc_profile"]
        preserved.append("TIFF ICC")
    if xmp:
        info[700] = xmp  # Pillow's TIFF writer takes XMP as tag 700, not as xmp=
        preserved.append("TIFF XMP")
    if 33723 in im.tag_v2:  # IPTC
        iptc = im.tag_v2[33723]
        if not keep_location:
            raw = iptc if isinstance(iptc, bytes) else bytes(iptc) if isinstance(iptc, tuple) else None
            try:
                cleaned, gone = location.strip_iim_location(raw) if raw is not None else (iptc, [])
            except location.MetadataParseError as exc:
                cleaned, gone = None, [f"IPTC dropped: unreadable, could hold a place ({exc})"]
            removed += [f"TIFF {g}" for g in gone]
            iptc = cleaned
        if iptc is not None:
            info[33723] = iptc
            preserved.append("TIFF IPTC")
    if 34853 in im.tag_v2:  # GPS IFD
        if keep_location:
            info[34853] = im.getexif().get_ifd(0x8825)
            preserved.append("TIFF GPS IFD")
        else:
            removed.append("TIFF GPS IFD")
    if compression == "jpeg":
        opts["quality"] = 95
        notes.append("JPEG-compressed TIFF re-encoded at quality 95")
    if 34665 in im.tag_v2:
        notes.append("TIFF EXIF sub-IFD not copied")
    buf = io.BytesIO()
    save_explicit(out, buf, "TIFF", **opts)
    return buf.getvalue(), preserved, notes, compression in _TIFF_LOSSLESS, removed


# ---- HEIC / AVIF ---------------------------------------------------------------------------------
HEIF_QUALITY = 90  # the source's encoder quality is not recorded in the file


def _poison_heif(
    im: Image.Image, fmt: str, placement: PatchPlacement, keep_location: bool, marker: Marker | None
) -> tuple[bytes, list[str], list[str], list[str]]:
    mode = "RGBA" if "A" in im.mode else "RGB"
    out = paste_patch(im if im.mode == mode else im.convert(mode), placement)
    opts: dict[str, object] = {"quality": HEIF_QUALITY}
    preserved, removed = _metadata_options(im.info, keep_location, fmt, marker, opts)
    buf = io.BytesIO()
    save_explicit(out, buf, fmt, **opts)
    return buf.getvalue(), preserved, [f"{fmt} re-encoded at quality {HEIF_QUALITY} (lossy)"], removed


# ---- JPEG ----------------------------------------------------------------------------------------
def _jpeg_preserved(layout: jpeg_codec.JpegLayout, info: dict[str, object]) -> list[str]:
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


def _poison_jpeg(
    src: Path, im: Image.Image, data: bytes, placement: PatchPlacement, *, loaded: bool
) -> tuple[bytes, list[str], list[str], str]:
    """The patched JPEG. With loaded=False im is only opened (header): every byte of the file is
    still entropy-decoded before anything is written (by jpegtran's crop and drop, whose warnings
    on corrupt or truncated data send it to the full decode), so a broken file fails as before."""
    try:
        layout = jpeg_codec.read_layout(data)
    except ValueError as exc:
        raise ImageFormatError(f"{src.name}: bad JPEG header ({exc})") from exc
    if im.mode not in ("L", "RGB"):
        raise ImageFormatError(f"{src.name}: {im.mode} JPEG is not supported")
    preserved = _jpeg_preserved(layout, im.info)
    notes: list[str] = []
    # The splice only needs the MCU box's pixels: with JPEG_REGION_DECODE they come from a
    # lossless crop around the box (jpeg_codec.decode_box), so the rest of the picture is never
    # decoded to pixels; otherwise (or when the crop is refused) from the whole decoded picture,
    # of which only the box is converted to an array.
    box = jpeg_codec.mcu_box(placement.box, layout)
    local = dataclasses.replace(placement, x=placement.x - box[0], y=placement.y - box[1])
    try:
        if loaded:
            box_pixels = np.asarray(im.crop(box))
        else:
            try:
                box_pixels = jpeg_codec.decode_box(src, im, layout, box)
            except jpeg_codec.SpliceUnavailable as exc:
                log.info("jpeg region decode unavailable", extra={"path": str(src), "reason": str(exc)})
                _load_decoded(src, im)
                box_pixels = np.asarray(im.crop(box))
        out = jpeg_codec.splice_patch(src, im, layout, apply_patch(box_pixels, local), box)
        notes.append(f"DCT splice: only MCU box {box} re-encoded, all other coefficients copied")
        return out, preserved, notes, "jpeg-dct-splice"
    except jpeg_codec.SpliceUnavailable as exc:
        notes.append(f"DCT splice impossible ({exc}): whole image re-encoded with the source tables")
        log.info("jpeg splice unavailable", extra={"path": str(src), "reason": str(exc)})
    _load_decoded(src, im)
    patched = apply_patch(np.asarray(im), placement)
    if layout.components == 3 and "subsampling" not in jpeg_codec.table_options(im):
        notes.append(f"sampling {layout.sampling} not reproducible by Pillow: written 4:2:0")
    if any(s.payload.startswith(b"MPF\x00") for s in layout.segments):
        notes.append("MPF segment and its secondary images dropped")
    return jpeg_codec.encode_like(patched, im, layout), preserved, notes, "jpeg-reencode-same-tables"


# ---- entry points --------------------------------------------------------------------------------
def poison_file(
    src: Path,
    dst: Path,
    spec: PatchSpec,
    *,
    marker: Marker | None = None,
    keep_location: bool = False,
    max_pixels: int | None = None,
) -> PoisonReport:
    """Read src, write the complete poisoned file to dst (src is only read).

    Location metadata (GPS, place names) is removed from dst unless keep_location; with a marker,
    dst carries it (poisoner.provenance). A file whose header declares more than max_pixels
    (None: poisoner.limits.DEFAULT_MAX_PIXELS) is refused before anything is decoded."""
    from poisoner.limits import DEFAULT_MAX_PIXELS, check_decode_budget  # limits imports this module

    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ImageFormatError(f"{src.name}: dst must differ from src (use poison_in_place)")
    check_decode_budget(src, DEFAULT_MAX_PIXELS if max_pixels is None else max_pixels)
    try:
        data = src.read_bytes()
    except OSError as exc:
        raise ImageFormatError(f"{src.name}: cannot read ({_one_line(exc)})") from exc
    # A JPEG need not be decoded to pixels whole (only the patch's MCUs, _poison_jpeg).
    region = JPEG_REGION_DECODE and data[:2] == b"\xff\xd8" and jpeg_codec.jpegtran_binary() is not None
    im = _open_decoded(src, data, load=not region)
    fmt = im.format or "unknown"
    if region and fmt != "JPEG":
        _load_decoded(src, im)
    width, height = im.size
    try:
        placement = spec.resolve(width, height, image_key=src.name)  # the real name: moving specs (issue #9)
    except SpecError as exc:
        raise ImageFormatError(f"{src.name}: {exc}") from exc
    notes: list[str] = []
    removed: list[str] = []
    lossless = False
    if fmt == "JPEG":
        out, preserved, notes, method = _poison_jpeg(src, im, data, placement, loaded=not region)
        if not keep_location:
            out, removed = _strip_jpeg(src, out)
        if marker is not None:
            out = _jpeg_marker(src, out, marker)
    elif fmt == "PNG":
        out, preserved, notes = _poison_png(im, data, placement)
        method, lossless = "png-lossless", True
        if not keep_location:
            out, removed = strip_png_location(out)
        if marker is not None:
            out = provenance.embed_png(out, marker)
    elif fmt == "WEBP":
        out, preserved, notes, lossless, removed = _poison_webp(im, data, placement, keep_location, marker)
        method = "webp-lossless" if lossless else "webp-lossy"
    elif fmt == "TIFF":
        out, preserved, notes, lossless, removed = _poison_tiff(im, placement, keep_location, marker)
        method = "tiff"
    elif fmt in ("HEIF", "AVIF"):
        out, preserved, notes, removed = _poison_heif(im, fmt, placement, keep_location, marker)
        method = fmt.lower()
    else:
        raise ImageFormatError(f"{src.name}: {fmt} files are not supported")
    if removed:
        notes.append(f"location removed ({len(removed)}): " + ", ".join(removed))
    orientation = im.getexif().get(0x0112)
    if orientation and orientation != 1:
        notes.append(f"EXIF orientation {orientation} kept; {ORIENTATION_POLICY}")
    if is_image(src) and not _suffix_matches(src.suffix.lower(), fmt):
        notes.append(f"content is {fmt} despite the {src.suffix} suffix: written as {fmt}")
    dst.write_bytes(out)
    report = PoisonReport(
        fmt, width, height, placement, preserved, notes, method, lossless, len(data), len(out), removed
    )
    log.info(
        "poisoned image",
        extra={"src": str(src), "format": fmt, "method": method, "size": f"{width}x{height}", "notes": notes},
    )
    return report


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
        "JPEG": {".jpg", ".jpeg", ".jpe"},
        "PNG": {".png"},
        "WEBP": {".webp"},
        "TIFF": {".tif", ".tiff"},
        "HEIF": {".heic", ".heif"},
        "AVIF": {".avif"},
    }
    return suffix in expected.get(fmt, set())


def poison_in_place(
    path: Path,
    spec: PatchSpec,
    *,
    marker: Marker | None = None,
    keep_location: bool = False,
    max_pixels: int | None = None,
) -> PoisonReport:
    """Poison path atomically: a crash leaves the original or the complete poisoned file.
    Permission bits are kept (poisoner.atomic)."""
    path = Path(path)
    with atomic_output(path) as tmp:
        return poison_file(path, tmp, spec, marker=marker, keep_location=keep_location, max_pixels=max_pixels)
