"""Metadata for re-encoded images (WebP, TIFF, HEIC, AVIF): the source's EXIF and XMP with
location removed unless kept, the provenance marker added to the XMP, the ICC profile kept."""

from __future__ import annotations

from collections.abc import Callable
from typing import cast

from PIL import Image

from poisoner import location, provenance
from poisoner.image import previews
from poisoner.provenance import Marker


def clean_exif_xmp(
    info: dict[str, object], keep_location: bool, label: str, marker: Marker | None
) -> tuple[bytes | None, bytes | None, list[str]]:
    """The source's EXIF and XMP for a re-encoded file: location removed unless kept, the
    provenance marker added to the XMP when given."""
    # Pillow's info holds EXIF and XMP as bytes (XMP as str from some plugins: encoded below).
    exif = cast("bytes | None", info.get("exif") or None)
    raw_xmp = info.get("xmp") or None
    xmp = raw_xmp.encode() if isinstance(raw_xmp, str) else cast("bytes | None", raw_xmp)
    removed: list[str] = []
    if marker is not None:
        xmp = provenance.xmp_with_marker(xmp, marker)
    if keep_location:
        return exif, xmp, removed
    if isinstance(exif, bytes):
        exif, gone = location.clean_exif(exif)
        removed += [f"{label} {g}" for g in gone]
    if isinstance(xmp, bytes):
        xmp, gone = location.strip_xmp_location(xmp)
        removed += [f"{label} {g}" for g in gone]
    return exif, xmp, removed


def metadata_options(
    info: dict, keep_location: bool, fmt: str, marker: Marker | None, opts: dict[str, object],
    picture: Callable[[], Image.Image],
) -> tuple[list[str], list[str], list[str]]:  # fmt: skip
    """Put the cleaned EXIF, the ICC profile and the cleaned (marked) XMP into Pillow's save
    options; returns (what was kept, what location was removed, notes). picture(): the patched
    picture, for the EXIF thumbnail (poisoner.image.previews: never the original's)."""
    exif, xmp, removed = clean_exif_xmp(info, keep_location, fmt, marker)
    notes: list[str] = []
    if exif:
        exif, notes = previews.exif_previews(exif, previews.render_image(picture))
    if xmp:
        xmp, said = previews.xmp_previews(xmp)
        notes += said
    preserved = []
    for key, label, value in (("exif", "EXIF", exif), ("icc_profile", "ICC", info.get("icc_profile")),
                              ("xmp", "XMP", xmp)):  # fmt: skip
        if value:
            opts[key] = value
            preserved.append(f"{fmt} {label}")
    return preserved, removed, notes
