"""Pixels the mark must never change (a subject mask), checked and fitted to each writer.

Pixel writers (PNG, TIFF, WebP, HEIF/AVIF) take the mask as it is. A JPEG splice re-encodes whole
MCUs, and libjpeg's fancy chroma upsampling lets a re-encoded MCU move a decoded pixel up to one
luma pixel beyond it (per subsampled direction); so for JPEG the mask is grown to whole MCUs: an
MCU within that reach of a kept-out pixel is never written, and only MCUs that carry written
pixels are re-encoded. Arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np

from poisoner.blend import patch_coverage
from poisoner.errors import ImageFormatError
from poisoner.spec import PatchPlacement

Box = tuple[int, int, int, int]


def checked_keep_out(name: str, keep_out: np.ndarray | None, size: tuple[int, int]) -> np.ndarray | None:
    """keep_out as a bool H x W array for a picture of `size` (w, h); the wrong size or shape is an
    ImageFormatError (one line)."""
    if keep_out is None:
        return None
    mask = np.asarray(keep_out)
    w, h = size
    if mask.ndim == 3 and mask.shape[2] == 1:
        mask = mask[..., 0]
    if mask.ndim != 2 or mask.shape != (h, w):
        raise ImageFormatError(f"{name}: keep-out mask is {_shape(mask)}, the image is {w}x{h}")
    return mask > 0


def _shape(mask: np.ndarray) -> str:
    if mask.ndim == 2:
        return f"{mask.shape[1]}x{mask.shape[0]}"
    return "x".join(str(n) for n in mask.shape) + " (not H x W)"


def kept_out_note(placement: PatchPlacement, keep: np.ndarray | None) -> str | None:
    """A report note when the keep-out mask reaches the mark: how much of it is left unwritten."""
    if keep is None:
        return None
    x0, y0, x1, y1 = placement.box
    cover = patch_coverage(placement)
    blocked = int((cover & keep[y0:y1, x0:x1]).sum())
    if blocked == 0:
        return None
    share = blocked / max(1, int(cover.sum()))
    if share >= 1.0:
        return "keep-out mask covers the whole mark: nothing written in this image"
    return f"keep-out mask: {share:.0%} of the mark's pixels left unwritten"


def grow(mask: np.ndarray, by_x: int, by_y: int) -> np.ndarray:
    """mask dilated by a (2 by_x + 1) x (2 by_y + 1) rectangle (small reaches: shifts, no SciPy)."""
    out = mask.copy()
    h, w = mask.shape
    for d in range(1, by_x + 1):
        out[:, d:] |= mask[:, : w - d]
        out[:, : w - d] |= mask[:, d:]
    wide = out.copy()
    for d in range(1, by_y + 1):
        out[d:, :] |= wide[: h - d, :]
        out[: h - d, :] |= wide[d:, :]
    return out


def mcu_keep_out(keep_out: np.ndarray, box: Box, mcu: tuple[int, int], reach: tuple[int, int]) -> np.ndarray:
    """Over the MCU-aligned `box`, the MCUs the mark must not write (as a box-sized bool array):
    those within `reach` (x, y) px of a kept-out pixel of the whole-picture `keep_out`."""
    x0, y0, x1, y1 = box
    rx, ry = reach
    h, w = keep_out.shape
    gx0, gy0, gx1, gy1 = max(0, x0 - rx), max(0, y0 - ry), min(w, x1 + rx), min(h, y1 + ry)
    near = grow(keep_out[gy0:gy1, gx0:gx1], rx, ry)[y0 - gy0 : y1 - gy0, x0 - gx0 : x1 - gx0]
    mw, mh = mcu
    bh, bw = near.shape
    padded = np.zeros((-(-bh // mh) * mh, -(-bw // mw) * mw), dtype=bool)
    padded[:bh, :bw] = near
    hit = padded.reshape(padded.shape[0] // mh, mh, padded.shape[1] // mw, mw).any(axis=(1, 3))
    return np.repeat(np.repeat(hit, mh, axis=0), mw, axis=1)[:bh, :bw]


def written_box(placement: PatchPlacement, box: Box, keep: np.ndarray | None) -> Box | None:
    """The bounding box (picture coordinates) of the pixels the mark writes inside `box` when the
    box-sized `keep` is left alone; None when it writes none."""
    x0, y0, x1, y1 = box
    write = np.zeros((y1 - y0, x1 - x0), dtype=bool)
    px0, py0, px1, py1 = placement.box
    write[py0 - y0 : py1 - y0, px0 - x0 : px1 - x0] = patch_coverage(placement)
    if keep is not None:
        write &= ~keep
    ys, xs = np.nonzero(write)
    if ys.size == 0:
        return None
    return (x0 + int(xs.min()), y0 + int(ys.min()), x0 + int(xs.max()) + 1, y0 + int(ys.max()) + 1)


def written_pixels(placement: PatchPlacement, keep: np.ndarray | None) -> int:
    """How many pixels the mark writes once `keep` (whole picture, True = never change) is left
    alone; 0 means the file would come out unprotected (poisoner.errors.MarkNotWritten)."""
    cover = patch_coverage(placement)
    if keep is None:
        return int(cover.sum())
    x0, y0, x1, y1 = placement.box
    return int((cover & ~keep[y0:y1, x0:x1]).sum())
