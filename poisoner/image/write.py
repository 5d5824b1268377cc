"""Writing pixels with Pillow: the patch pasted into a decoded picture, and saving with only the
metadata the caller passes (never the source's, which could bring removed location back)."""

from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np
from PIL import Image

from poisoner.blend import apply_patch_at, lane_placements
from poisoner.spec import PatchPlacement


def image_from_array(pixels: np.ndarray, mode: str) -> Image.Image:
    """Image.fromarray that also takes 16-bit grey (Pillow 13 infers I;16 from uint16 itself)."""
    if mode == "I;16":
        return Image.fromarray(np.ascontiguousarray(pixels, dtype=np.uint16))
    return Image.fromarray(pixels, mode)


def paste_patch(
    im: Image.Image, placement: PatchPlacement, keep_out: np.ndarray | None = None
) -> Image.Image:
    """im with the patch blended in, in place: only the patch's squares go through numpy (each on its
    own where the mark is made of squares placed apart, blend.lane_placements), so memory stays at
    one decoded picture (a whole-picture array costs one or two more, measured; the box between
    squares far apart, as floats, several). keep_out (H x W of im, nonzero = leave alone): those
    pixels keep their values."""
    for part in lane_placements(placement) or [placement]:
        x0, y0, x1, y1 = part.box
        window = None if keep_out is None else keep_out[y0:y1, x0:x1]
        region = apply_patch_at(np.asarray(im.crop(part.box)), part, (x0, y0), window)
        im.paste(image_from_array(region, im.mode), (x0, y0))
    return im


# modes whose array values are what a viewer sees (a palette index or a 1-bit pixel is not)
_VALUE_MODES = ("L", "LA", "RGB", "RGBA", "I;16")


def changes_a_pixel(im: Image.Image, squares: Sequence[PatchPlacement], keep_out: np.ndarray | None) -> bool:
    """Whether blending these squares into im changes any pixel's value. A mark whose blocks match
    the photo where they land (a black block on black, in a photo too small for more than one block
    a square) writes nothing, and such a file must fail, never be called patched (issue 25)."""
    for square in squares:
        x0, y0, x1, y1 = square.box
        crop = im.crop(square.box)
        if crop.mode not in _VALUE_MODES:
            crop = crop.convert("RGBA")
        window = np.asarray(crop)
        kept = None if keep_out is None else keep_out[y0:y1, x0:x1]
        if not np.array_equal(apply_patch_at(window, square, (x0, y0), kept), window):
            return True
    return False


def save_explicit(im: Image.Image, fp: io.BytesIO, fmt: str, **opts: object) -> None:
    """Save with only the metadata in opts. Pillow's writers fall back to im.info (the source's
    EXIF, XMP...) for what opts leave out, and its TIFF writer copies XMP/IPTC from a TIFF
    source's own tags: either would bring removed location back. A plain Image sharing the
    pixel memory (no copy) carries neither."""
    plain = im._new(im.im)  # Pillow's own shallow constructor
    plain.info = {}
    plain.save(fp, fmt, **opts)
