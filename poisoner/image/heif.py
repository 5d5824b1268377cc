"""HEIC (pillow-heif) and AVIF (Pillow): re-encoded at a high quality, EXIF/ICC/XMP kept
(location removed unless kept)."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

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
) -> tuple[bytes, list[str], list[str], list[str]]:
    mode = "RGBA" if "A" in im.mode else "RGB"
    out = paste_patch(im if im.mode == mode else im.convert(mode), placement, keep_out)
    opts: dict[str, object] = {"quality": HEIF_QUALITY}
    preserved, removed = metadata_options(im.info, keep_location, fmt, marker, opts)
    buf = io.BytesIO()
    save_explicit(out, buf, fmt, **opts)
    return buf.getvalue(), preserved, [f"{fmt} re-encoded at quality {HEIF_QUALITY} (lossy)"], removed
