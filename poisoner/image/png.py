"""PNG, lossless: the patched pixels (IHDR/PLTE/tRNS/IDAT) spliced between the source's own
ancillary chunks, copied byte for byte; palette images stay palette images when the patch's
colours fit; 16-bit colour goes through FFmpeg's PNG codec (Pillow reads it as 8-bit)."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
from PIL import Image

from poisoner import location
from poisoner.blend import apply_lanes, lane_placements, patch_coverage
from poisoner.errors import ImageFormatError
from poisoner.image.read import PNG_MODES
from poisoner.image.write import image_from_array, paste_patch
from poisoner.spec import PatchPlacement

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


def bytes_after_iend(data: bytes) -> int:
    """How many bytes follow a PNG's IEND chunk (an appended file, a trailer): no writer keeps them."""
    pos = len(PNG_SIGNATURE)
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        end = pos + 12 + length
        if data[pos + 4 : pos + 8] == b"IEND":
            return max(0, len(data) - end)
        pos = end
    return 0


def png_chunk(ctype: bytes, body: bytes) -> bytes:
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
    parts = [PNG_SIGNATURE, png_chunk(b"IHDR", new_pixel[b"IHDR"][0])]
    parts += [png_chunk(t, b) for t, b in before]
    parts += [png_chunk(b"PLTE", b) for b in new_pixel[b"PLTE"]]
    # hIST counts palette entries: stale when the palette grew.
    if new_pixel[b"PLTE"] and any(t == b"PLTE" and b != new_pixel[b"PLTE"][0] for t, b in src):
        after_plte = [c for c in after_plte if c[0] != b"hIST"]
    parts += [png_chunk(b"tRNS", b) for b in new_pixel[b"tRNS"]]
    parts += [png_chunk(t, b) for t, b in after_plte]
    parts += [png_chunk(b"IDAT", b) for b in new_pixel[b"IDAT"]]
    parts += [png_chunk(t, b) for t, b in after]
    parts.append(png_chunk(b"IEND", b""))
    kept = [t.decode("latin-1") for t, _ in before + after_plte + after]
    return b"".join(parts), kept


def strip_png_location(data: bytes) -> tuple[bytes, list[str]]:
    """The PNG with location removed from its ancillary chunks (eXIf, XMP iTXt, raw profiles, text
    chunks keyed exif:GPSLatitude, photoshop:City ...); pixel chunks and every other chunk are copied
    byte for byte."""
    parts = [PNG_SIGNATURE]
    removed: list[str] = []
    for ctype, body in png_chunks(data):
        if (key := location.location_text_key(ctype, body)) is not None:
            removed.append(f"PNG {ctype.decode('latin-1')}: {key}")
            continue
        if ctype not in _PIXEL_CHUNKS:
            cleaned, gone = location.clean_png_chunk(ctype, body)
            removed += [f"PNG {ctype.decode('latin-1')}: {g}" for g in gone]
            if cleaned is None:
                continue
            body = cleaned
        parts.append(png_chunk(ctype, body))
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


def _palette_patch(
    im: Image.Image, placement: PatchPlacement, keep_out: np.ndarray | None = None
) -> tuple[Image.Image, list[str]]:
    """Patch a palette image; keep it a palette image when the new colours fit."""
    notes: list[str] = []
    has_alpha = "transparency" in im.info
    rgb_mode = "RGBA" if has_alpha else "RGB"
    full = np.asarray(im.convert(rgb_mode))
    patched = apply_lanes(full, placement, keep_out)
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


def _off_key(
    out: Image.Image, placement: PatchPlacement, keep_out: np.ndarray | None, key: object
) -> int:
    """Moves every pixel the mark wrote (its coverage, keep_out left alone) that equals the tRNS
    colour key one level off it, each channel up (down at full scale), in place: a viewer would show
    it transparent, and on a dark background the mark would vanish. The mark stays opaque, as it is
    on an RGBA file (poisoner.blend). Returns how many pixels moved."""
    moved = 0
    for part in lane_placements(placement) or [placement]:
        x0, y0, x1, y1 = part.box
        region = np.array(out.crop(part.box))
        key_arr = np.asarray(key, dtype=region.dtype)
        hit = (region == key_arr).all(axis=-1) if region.ndim == 3 else region == key_arr
        hit &= patch_coverage(part)[: y1 - y0, : x1 - x0]
        if keep_out is not None:
            hit &= keep_out[y0:y1, x0:x1] == 0
        if hit.any():
            top = np.iinfo(region.dtype).max
            region[hit] = np.where(key_arr < top, key_arr + 1, key_arr - 1)
            out.paste(image_from_array(region, out.mode), (x0, y0))
            moved += int(hit.sum())
    return moved


def poison_png(
    im: Image.Image, data: bytes, placement: PatchPlacement, keep_out: np.ndarray | None = None
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
        encoded = _encode_png16_colour(apply_lanes(pixels, placement, keep_out))
        notes.append("16-bit colour PNG coded with FFmpeg's PNG codec (Pillow reads it as 8-bit)")
    elif depth == 16 and colour_type == 4:
        raise ImageFormatError("16-bit grey+alpha PNG is not supported (Pillow reads it as 8-bit)")
    elif im.mode == "P":
        out, pnotes = _palette_patch(im, placement, keep_out)
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
        if mode not in PNG_MODES:
            raise ImageFormatError(f"PNG mode {mode} is not supported")
        out = paste_patch(im, placement, keep_out)
        save_opts = {}
        if "transparency" in im.info and mode in ("L", "RGB", "I;16"):
            save_opts["transparency"] = im.info["transparency"]  # tRNS colour key
            if nudged := _off_key(out, placement, keep_out, im.info["transparency"]):
                notes.append(f"{nudged} mark pixel(s) equal to the tRNS colour key moved one level off it "
                             "(the mark stays opaque)")  # fmt: skip
        out.save(buf, "PNG", **save_opts)
        encoded = buf.getvalue()
    spliced, kept = splice_png(data, encoded)
    return spliced, [f"PNG {c}" for c in kept], notes
