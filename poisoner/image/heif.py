"""HEIC (pillow-heif) and AVIF (Pillow): re-encoded at a high quality, EXIF/ICC/XMP kept
(location removed unless kept). A HEIC of more than 8 bits a sample (10-bit phone and camera
HEIFs) is decoded, patched and written at its own bit depth through pillow-heif's own API (Pillow
has no 16-bit colour mode: its opener hands ppd 8 bits)."""

from __future__ import annotations

import functools
import io

import numpy as np
from PIL import Image

from poisoner.blend import apply_patch_at, lane_placements
from poisoner.image import previews
from poisoner.image.metadata import metadata_options
from poisoner.image.write import paste_patch, save_explicit
from poisoner.provenance import Marker
from poisoner.spec import PatchPlacement

HEIF_QUALITY = 90  # the source's encoder quality is not recorded in the file


def poison_heif(
    im: Image.Image,
    fmt: str,
    placement: PatchPlacement,
    keep_location: bool,
    marker: Marker | None,
    keep_out: np.ndarray | None = None,
    data: bytes | None = None,
) -> tuple[bytes, list[str], list[str], list[str]]:
    """data: the source file's bytes, for a HEIC deeper than 8 bits (its bit depth is kept)."""
    opts: dict[str, object] = {"quality": HEIF_QUALITY}
    mode = "RGBA" if "A" in im.mode else "RGB"

    @functools.cache
    def patched() -> Image.Image:  # the 8-bit picture patched, once (a deep HEIC's only for its thumbnail)
        return paste_patch(im if im.mode == mode else im.convert(mode), placement, keep_out)

    preserved, removed, shown = metadata_options(im.info, keep_location, fmt, marker, opts, patched)
    if fmt == "HEIF" and (boxes := [b for b in im.info.get("thumbnails") or [] if b]):
        # the source's `thmb` items, at their sizes: pillow-heif encodes them from the picture it writes
        opts["thumbnails"] = boxes
        shown.append(f"HEIF thumbnail ({'/'.join(map(str, boxes))} px) {previews.REPLACED}")
    note = f"{fmt} re-encoded at quality {HEIF_QUALITY} (lossy)"
    depth = int(im.info.get("bit_depth") or 8)
    if fmt == "HEIF" and depth > 8 and data is not None:
        out = _deep_heif(data, depth, placement, keep_out, opts, im.info.get("nclx_profile"))
        return out, [*preserved, f"HEIF {depth}-bit samples"], [f"{note}, {depth}-bit kept", *shown], removed
    if fmt == "AVIF" and data is not None and (depth := declared_bit_depth(data)) > 8:
        # Pillow's AVIF codec reads and writes 8 bits a sample; no other AVIF writer is a dependency
        note += f"; {depth}-bit samples written as 8-bit (Pillow's AVIF codec has 8 bits a sample)"
    buf = io.BytesIO()
    save_explicit(patched(), buf, fmt, **opts)
    if fmt == "AVIF":
        shown = _written(shown, opts.get("exif"), buf.getvalue())
    return buf.getvalue(), preserved, [note, *shown], removed


def _written(notes: list[str], exif: object, out: bytes) -> list[str]:
    """The notes, true of `out`: Pillow's AVIF writer rewrites the EXIF of a photo with an orientation
    tag (into the file's `irot`) and writes no IFD1 then: no thumbnail at all, not a replaced one."""
    if not isinstance(exif, bytes) or exif.removeprefix(b"Exif\x00\x00") in out:
        return notes
    gone = "EXIF thumbnail removed (Pillow's AVIF writer keeps no IFD1 of a photo with an orientation tag)"
    return [gone if n.startswith("EXIF thumbnail (") else n for n in notes]


def declared_bit_depth(data: bytes) -> int:
    """The most bits a sample that an HEIF/AVIF file's `pixi` properties declare (8 when none)."""
    from poisoner.limits import _boxes

    deepest = 8
    for typ, start, end in _boxes(data, 0, len(data)):
        for t2, s2, e2 in _boxes(data, start + 4, end) if typ == b"meta" else []:  # meta is a full box
            for t3, s3, e3 in _boxes(data, s2, e2) if t2 == b"iprp" else []:
                for t4, s4, e4 in _boxes(data, s3, e3) if t3 == b"ipco" else []:
                    if t4 == b"pixi" and e4 > s4 + 4:  # a full box: channels, then bits per channel
                        deepest = max([deepest, *data[s4 + 5 : min(s4 + 5 + data[s4 + 4], e4)]])
    return deepest


def _deep_heif(
    data: bytes, depth: int, placement: PatchPlacement, keep_out: np.ndarray | None,
    opts: dict[str, object], nclx: object,
) -> bytes:
    """The HEIC patched at its own bit depth: pillow-heif decodes the primary image to 16 bits a
    sample (its "RGB;16" modes, the same picture Pillow's opener turns to 8 bits: transforms
    applied), the mark is blended at full scale a square at a time, and pillow-heif writes it back
    with bit_depth = the source's (10 or 12) and the source's colour description (nclx)."""
    import pillow_heif

    heif = pillow_heif.open_heif(io.BytesIO(data), convert_hdr_to_8bit=False)
    primary = heif[heif.primary_index]
    pixels = np.array(primary)  # writable copy, uint16
    for part in lane_placements(placement) or [placement]:
        x0, y0, x1, y1 = part.box
        window = None if keep_out is None else keep_out[y0:y1, x0:x1]
        pixels[y0:y1, x0:x1] = apply_patch_at(pixels[y0:y1, x0:x1], part, (x0, y0), window)
    if nclx:
        opts = {**opts, "nclx_profile": nclx}
    buf = io.BytesIO()
    out = pillow_heif.from_bytes(primary.mode, primary.size, np.ascontiguousarray(pixels).tobytes())
    out.save(buf, bit_depth=depth, **opts)
    return buf.getvalue()
