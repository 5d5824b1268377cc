"""Whether a picture is ppd's output saved again by another program: the same pixels under other bytes
(a PNG re-saved, its seal chunk dropped) or the pixels of a lossy re-encode of it (a JPEG saved again at
quality 90). Decoded and compared with the original and with ppd's output of it: off the mark the file
holds the original's pixels, on the mark ppd's, each within re-encoding noise (a black-box review,
2026-12-07: such a file was taken as a new original, marked a second time, and `ppd restore` handed
back the once-marked picture as "restored").

An edit anywhere (a retouch, a crop, another exposure) is more than that noise: it is not ppd's output,
and stays a new photo to protect."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from poisoner.image.read import open_decoded

if TYPE_CHECKING:
    import numpy as np
    from PIL import Image

# A pixel ppd's mark changed: its output differs from the original by more than this, in some channel.
MARK_LEVELS = 12
# A lossy re-encode of ppd's output (JPEG quality 75 to 95, 4:2:0 and 4:4:4, measured on DTU and
# NeRF-synthetic views and the test textures: at most 10 levels, a colour's drift under 0.6) stays
# under these; an edit does not: a 16-pixel retouch or a clone 49 to 137 levels on its blocks, a
# brightness change of 8 levels a drift of 4.5 and more.
BLOCK = 16  # the noise is judged per BLOCK x BLOCK pixels: a re-encode spreads it, an edit gathers it
BLOCK_MAX = 24.0  # a block's mean error from ppd's output, in levels (any channel's mean)
DRIFT_MAX = 2.0  # the picture's mean signed error per channel (exposure, white balance)
# On the mark the file must be ppd's, not the original's: its error from ppd's output there at most this
# share of the mark's own strength (a re-save of the original, mark-free, is a new photo)
ON_MARK_SHARE = 0.35
LOSSY = ("JPEG", "MPO", "WEBP", "HEIF", "AVIF")  # Pillow's names; a lossless WebP is judged as lossy
STRIP = 512  # rows compared at a time (a multiple of BLOCK): a 50-megapixel photo in bounded memory


def is_resaved_output(name: str, original: bytes, output: bytes, current: bytes) -> bool:
    """Whether current (a file's bytes) is ppd's output (output: what ppd writes from original) saved
    again: exactly its pixels for a lossless format, within re-encoding noise for a lossy one. False
    for anything else: another size (a crop, a resize, a rotation), an edit, the original re-saved."""
    src = Path(name)
    with open_decoded(src, current) as now, open_decoded(src, original) as was, \
            open_decoded(src, output) as ours:  # fmt: skip
        if not now.size == was.size == ours.size:
            return False
        lossy = now.format in LOSSY
        mode = "RGBA" if any(im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info
                             for im in (now, was, ours)) else "RGB"  # fmt: skip
        return _compare(*(_eight_bit(im, mode) for im in (now, was, ours)), exact=not lossy)


def _eight_bit(im: Image.Image, mode: str) -> Image.Image:
    from poisoner.image.read import eight_bit_grey

    im = eight_bit_grey(im)
    return im if im.mode == mode else im.convert(mode)  # no copy of a photo already in that mode


def _compare(now: Image.Image, was: Image.Image, ours: Image.Image, *, exact: bool) -> bool:
    """Strip by strip: exact, every level equal; else within a re-encode's noise off the mark and
    ppd's on it (see the constants)."""
    import numpy as np

    width, height = now.size
    drift = np.zeros(len(now.getbands()))
    on_mark_error = strength = 0.0
    for top in range(0, height, STRIP):
        box = (0, top, width, min(height, top + STRIP))
        a, b, c = (np.asarray(im.crop(box), dtype=np.int16) for im in (now, was, ours))
        off = a - c
        if exact:
            if off.any():
                return False
            continue
        if _worst_block(np.abs(off)) > BLOCK_MAX:
            return False
        drift += off.sum(axis=(0, 1))
        mark = np.abs(c - b).max(axis=-1) > MARK_LEVELS
        on_mark_error += float(np.abs(off)[mark].sum())
        strength += float(np.abs(c - b)[mark].sum())
    if exact:
        return True
    if np.abs(drift / (width * height)).max() > DRIFT_MAX or strength == 0:  # no mark: nothing says ppd's
        return False
    return on_mark_error <= ON_MARK_SHARE * strength


def _worst_block(error: np.ndarray) -> float:
    """The largest mean error of a BLOCK x BLOCK block, per channel (edge blocks padded with zeros)."""
    import numpy as np

    h, w, ch = error.shape
    padded = np.pad(error, ((0, -h % BLOCK), (0, -w % BLOCK), (0, 0)))
    blocks = padded.reshape(padded.shape[0] // BLOCK, BLOCK, padded.shape[1] // BLOCK, BLOCK, ch)
    return float(blocks.mean(axis=(1, 3)).max())
