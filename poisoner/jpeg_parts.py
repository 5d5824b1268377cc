"""A JPEG splice box patched a part at a time (issue 30): a mark of squares placed far apart has a
box of up to 7 MP around them on a 12 MP photo, of which only each square's MCUs are written. The
in-process pass (poisoner.jpeg.patch_in_one_pass) decodes, blends and encodes each part alone and
puts its DCT blocks where the whole box's encode would have put them; these pure functions say
whether the parts may stand for the box, and the shape of the box's block arrays."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

Box = tuple[int, int, int, int]


class McuGrid(Protocol):
    """What these functions read of poisoner.jpeg.JpegLayout (a protocol, so the two modules do not
    import each other)."""

    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def components(self) -> int: ...
    @property
    def sampling(self) -> tuple[tuple[int, int], ...]: ...
    @property
    def mcu_size(self) -> tuple[int, int]: ...


def mcu_box(box: Box, layout: McuGrid) -> Box:
    """The smallest MCU-aligned box holding `box`, clipped to the picture."""
    mw, mh = layout.mcu_size
    x0, y0, x1, y1 = box
    return (
        (x0 // mw) * mw,
        (y0 // mh) * mh,
        min(-(-x1 // mw) * mw, layout.width),
        min(-(-y1 // mh) * mh, layout.height),
    )


def crop_box(box: Box, layout: McuGrid) -> Box:
    """The MCU box grown by one MCU on every side (clipped): the lossless crop whose decode gives
    the MCU box's pixels exactly as a whole-picture decode does. Fancy chroma upsampling reads one
    chroma sample beyond a pixel's own, and a crop's border samples are replicated instead of
    read from the neighbour, so the ring absorbs that; the IDCT is per block and colour
    conversion per pixel."""
    mw, mh = layout.mcu_size
    x0, y0, x1, y1 = box
    return (max(0, x0 - mw), max(0, y0 - mh), min(layout.width, x1 + mw), min(layout.height, y1 + mh))


def box_block_shapes(layout: McuGrid, box: Box) -> list[tuple[int, int]]:
    """(block rows, block columns) per component of `box` encoded alone, as
    poisoner.jpeg_turbo.read_blocks gives them: the rows run to a whole MCU row, the columns to the
    last (partial) block."""
    mw, mh = layout.mcu_size
    w, h = box[2] - box[0], box[3] - box[1]
    factors = [(1, 1)] if layout.components == 1 else list(layout.sampling)
    return [(-(-h // mh) * v, -(-w * f // mw)) for f, v in factors]


def parts_cover(layout: McuGrid, box: Box, parts: Sequence[Box], keep_mcus: np.ndarray | None) -> bool:
    """Whether the MCU-aligned `parts` (inside box) hold every MCU of box not in keep_mcus: only then
    may the box be patched a part at a time (the MCUs outside every part keep the source's blocks)."""
    mw, mh = layout.mcu_size
    rows, cols = -(-(box[3] - box[1]) // mh), -(-(box[2] - box[0]) // mw)
    covered = np.zeros((rows, cols), dtype=bool) if keep_mcus is None else keep_mcus.astype(bool).copy()
    if covered.shape != (rows, cols):
        return False
    for part in parts:
        inside = box[0] <= part[0] < part[2] <= box[2] and box[1] <= part[1] < part[3] <= box[3]
        if not inside or mcu_box(part, layout) != part:  # MCU edges, or the picture's right/bottom
            return False
        covered[(part[1] - box[1]) // mh : -(-(part[3] - box[1]) // mh),
                (part[0] - box[0]) // mw : -(-(part[2] - box[0]) // mw)] = True  # fmt: skip
    return bool(covered.all())


def rows_taking_blocks(layout: McuGrid, keep_mcus: np.ndarray, wanted: list[range]) -> list[frozenset]:
    """Per component, the block rows of `wanted` (the box's, from its top block row) in which some MCU
    not in keep_mcus lies: the only rows whose blocks the splice changes."""
    factors = [1] if layout.components == 1 else [v for _, v in layout.sampling]
    mcu_rows = np.flatnonzero(~keep_mcus.all(axis=1))
    return [
        frozenset(row for m in mcu_rows for k in range(v) if (row := rows.start + int(m) * v + k) in rows)
        for v, rows in zip(factors, wanted, strict=True)
    ]
