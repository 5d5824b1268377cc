"""What a viewer sees of a stored picture: EXIF orientation applied to arrays, sizes and squares, and
where a box sits in words. Pure functions (numpy only), shared by the placement (poisoner.placement),
the blend, the preview and the report, so that the position ppd prints, the report's words and the
pixels agree (issue 25's EXIF-6 test)."""

from __future__ import annotations

import numpy as np

# EXIF orientation -> the one that undoes it (5, 7 and the flips are their own inverse)
INVERSE_ORIENTATION = {1: 1, 2: 2, 3: 3, 4: 4, 5: 5, 6: 8, 7: 7, 8: 6}

def orientation_of(value: object) -> int:
    """An EXIF orientation value as 1..8 (anything else: 1, what viewers do with a bad tag)."""
    return value if isinstance(value, int) and 1 <= value <= 8 else 1


def orient_array(a: np.ndarray, orientation: int) -> np.ndarray:
    """Stored pixels (H x W (x C)) as a viewer shows them under an EXIF orientation, as PIL's
    ImageOps.exif_transpose does (2: mirror, 3: 180, 4: flip, 5: transpose, 6: 90 clockwise,
    7: transverse, 8: 90 counter-clockwise)."""
    o = orientation_of(orientation)
    if o == 2:
        return a[:, ::-1]
    if o == 3:
        return a[::-1, ::-1]
    if o == 4:
        return a[::-1]
    if o == 5:
        return np.swapaxes(a, 0, 1)
    if o == 6:
        return np.swapaxes(a, 0, 1)[:, ::-1]
    if o == 7:
        return np.swapaxes(a, 0, 1)[::-1, ::-1]
    if o == 8:
        return np.swapaxes(a, 0, 1)[::-1]
    return a


def unorient_array(a: np.ndarray, orientation: int) -> np.ndarray:
    """A display-space array back in the stored layout (orient_array's inverse)."""
    return orient_array(a, INVERSE_ORIENTATION[orientation_of(orientation)])


def display_size(width: int, height: int, orientation: int) -> tuple[int, int]:
    """(w, h) a viewer sees of a stored width x height picture."""
    return (height, width) if orientation_of(orientation) >= 5 else (width, height)


def turn_square(x: int, y: int, side: int, orientation: int, width: int, height: int) -> tuple[int, int]:
    """Top-left of a side x side square at (x, y) of a width x height frame once the frame is shown
    under `orientation` (the inverse orientation maps display back to stored)."""
    return {
        2: (width - x - side, y),
        3: (width - x - side, height - y - side),
        4: (x, height - y - side),
        5: (y, x),
        6: (height - y - side, x),
        7: (height - y - side, width - x - side),
        8: (y, width - x - side),
    }.get(orientation_of(orientation), (x, y))


# A display matrix's turn and mirror, (a, b, c, d) of its top-left 2x2 part as signs (FFmpeg's convention,
# x' = a*x + c*y, y' = b*x + d*y), -> the EXIF orientation that shows the stored frame the same way
# (turn_square with side 0 maps each the same): what a player does with a phone clip's rotation.
_ORIENTATION_OF_MATRIX = {
    (1, 0, 0, 1): 1, (-1, 0, 0, 1): 2, (-1, 0, 0, -1): 3, (1, 0, 0, -1): 4,
    (0, 1, 1, 0): 5, (0, 1, -1, 0): 6, (0, -1, -1, 0): 7, (0, -1, 1, 0): 8,
}  # fmt: skip


def display_orientation(matrix: tuple[int, ...] | None) -> int | None:
    """The EXIF orientation (1..8) a video's display matrix (9 ints, 16.16 fixed point) shows its
    stored frames in; None without a matrix or for a turn that is not a multiple of 90 degrees."""
    if matrix is None or len(matrix) < 5:
        return None
    # 16.16 fixed point: +-1.0 is +-65536; a turn by a multiple of 90 degrees has each entry 0 or +-1
    corner = (matrix[0], matrix[1], matrix[3], matrix[4])
    a, b, c, d = (int(np.sign(v)) if abs(v) >= 1 << 15 else 0 for v in corner)
    return _ORIENTATION_OF_MATRIX.get((a, b, c, d))


ROWS = ("top", "middle", "bottom")
COLUMNS = ("left", "centre", "right")


def position_words(box: tuple[int, int, int, int], width: int, height: int) -> str:
    """Where a box sits in a width x height frame, in words: which third across and down its
    centre falls in ("top-centre", "bottom-left", "centre")."""
    cx, cy = (box[0] + box[2]) / 2 / width, (box[1] + box[3]) / 2 / height
    row, col = ROWS[min(2, int(cy * 3))], COLUMNS[min(2, int(cx * 3))]
    if row == "middle" and col == "centre":
        return "centre"
    return f"{row}-{col}"
