"""TIFF: the same compression; descriptive tags, ICC, XMP and IPTC kept (location removed
unless kept); palette and bilevel pictures are written as RGB(A) / greyscale."""

from __future__ import annotations

import io
from typing import cast

import numpy as np
from PIL import Image, TiffImagePlugin

from poisoner import location
from poisoner.blend import apply_lanes
from poisoner.errors import ImageFormatError
from poisoner.image import previews
from poisoner.image.metadata import clean_exif_xmp
from poisoner.image.read import format_refusal
from poisoner.image.write import image_from_array, paste_patch, save_explicit
from poisoner.provenance import Marker
from poisoner.spec import PatchPlacement

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


def poison_tiff(
    im: Image.Image, placement: PatchPlacement, keep_location: bool, marker: Marker | None,
    keep_out: np.ndarray | None = None,
) -> tuple[bytes, list[str], list[str], bool, list[str]]:  # fmt: skip
    if (why := format_refusal(im)) is not None:
        raise ImageFormatError(why)
    tags = cast(TiffImagePlugin.TiffImageFile, im).tag_v2  # the opened TIFF's own tags
    notes: list[str] = []
    compression = im.info.get("compression", "raw")
    mode = im.mode
    if mode in ("P", "1"):
        mode = "RGBA" if "transparency" in im.info else "RGB" if mode == "P" else "L"
        notes.append(f"{im.mode} TIFF written as {mode}")
    src = im.convert(mode) if mode != im.mode else im
    if mode == "I;16B":
        out = image_from_array(apply_lanes(np.asarray(src).astype(np.uint16), placement, keep_out), "I;16")
    else:
        out = paste_patch(src, placement, keep_out)
    info = {tag: tags[tag] for tag in _TIFF_KEEP_TAGS if tag in tags}
    opts: dict[str, object] = {"compression": compression, "tiffinfo": info}
    preserved = [f"TIFF {_TIFF_KEEP_TAGS[t]}" for t in info]
    removed: list[str] = []
    _, xmp, removed = clean_exif_xmp({"xmp": im.info.get("xmp")}, keep_location, "TIFF", marker)
    if xmp:  # (no EXIF IFD1 is written: the EXIF sub-IFD is not copied, a second page is refused)
        xmp, shown = previews.xmp_previews(xmp)
        notes += shown
    if im.info.get("icc_profile"):
        opts["icc_profile"] = im.info["icc_profile"]
        preserved.append("TIFF ICC")
    if xmp:
        info[700] = xmp  # Pillow's TIFF writer takes XMP as tag 700, not as xmp=
        preserved.append("TIFF XMP")
    if 33723 in tags:  # IPTC
        iptc = tags[33723]
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
    if 34853 in tags:  # GPS IFD
        if keep_location:
            info[34853] = im.getexif().get_ifd(0x8825)
            preserved.append("TIFF GPS IFD")
        else:
            removed.append("TIFF GPS IFD")
    if tags.get(317) == 2 and compression in ("tiff_lzw", "tiff_deflate", "tiff_adobe_deflate"):
        info[317] = 2  # horizontal differencing: Pillow's libtiff writer applies it when asked
        preserved.append("TIFF Predictor")
    if compression == "jpeg":
        opts["quality"] = 95
        notes.append("JPEG-compressed TIFF re-encoded at quality 95")
    if 34665 in tags:
        notes.append("TIFF EXIF sub-IFD not copied")
    buf = io.BytesIO()
    save_explicit(out, buf, "TIFF", **opts)
    return buf.getvalue(), preserved, notes, compression in _TIFF_LOSSLESS, removed
