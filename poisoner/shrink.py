"""Issue 25, round 3: a subject that fills the frame. Pure functions, arrays in, answers out.

Round 2 measured the limit of moving a whole mark: on dtu_scan37 cropped to 55% around its subject
(the subject covering 82% of the frame), 6 of the 7 views whose mark touched the subject had no
place off it for even one full square. So where no plain place holds the squares whole, each square
is CROPPED (never rescaled) to the largest side, in whole blocks, that a plain place holds: the
top-left part of the same texture, the same blocks at the same block size, so its SIFT features are
those of the full copies in the other photos, both lanes keep pixel-identical copies and keep sliding
by whole pixels (poisoner/spec.py `_resolve_lanes`, poisoner/motion.py). When even the floor size
finds no plain place, the mark goes to the least-bad place, said "no plain region" as before: round 5
(no masks) takes there a crop whose squares themselves are plain, if any, without the margin
(dtu_scan37's 70% crops: half-size squares fit plain pockets by the subject, 2 -> 0 views touching
it). A photo whose full mark has a plain place is placed exactly as before (byte-identical).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from poisoner.array_search import count_integral
from poisoner.mark_place import MarkPlace
from poisoner.placement import (
    PLAIN_SHARE,
    most_plain_count,
    place_on_photo,
    reaches_a_corner,
)
from poisoner.spec import PatchPlacement, PatchSpec

# The smallest side a square is cropped to, as a share of its full side. Half the side is a quarter
# of the texture (12 x 12 blocks of 4 px -> 6 x 6 on an 800 px frame): SIFT's features are found at
# a blob scale of a few blocks and need a descriptor window of about four times that, so below half
# the side the cropped copy keeps few of the full copy's features whole (its border cuts the rest);
# bench/bench_shrink.py `floor` measures how many of a full copy's matches each side keeps.
SHRINK_FLOOR = 0.5


def crop_sides(full: int, block: int, floor: float = SHRINK_FLOOR) -> list[int]:
    """The sides to try, largest first: every whole number of blocks below `full` down to
    floor x full (rounded up to a whole block, at least one block)."""
    if full <= 0 or block <= 0:
        return []
    low = max(block, math.ceil(floor * full / block) * block)
    top = (full - 1) // block * block
    return list(range(top, low - 1, -block))


def place_fitting(
    spec: PatchSpec,
    width: int,
    height: int,
    image_key: str | None,
    orientation: int,
    detail: np.ndarray | None,
    subject: np.ndarray | None = None,
    floor: float = SHRINK_FLOOR,
    *,
    faint: np.ndarray | None = None,
) -> tuple[PatchPlacement, MarkPlace]:
    """place_on_photo's answer where it found a free place (or had nothing to judge on, or the mark
    has no lanes to crop); otherwise the largest crop of the squares (crop_sides) that finds a
    free place, its MarkPlace saying so (`shrunk`); otherwise the least-bad place: without masks the
    plainest crop whose squares are plain (PLAIN_SHARE) where the whole mark's are not (the largest on
    a tie), else the whole mark's. faint: place_on_photo's."""
    placement, place = place_on_photo(
        spec, width, height, image_key, orientation, detail, subject, faint=faint
    )
    if place.free or detail is None or not placement.parts:
        return placement, place
    full = placement.lane_size
    least_bad = (place.detail, placement, place)
    counts = count_integral(detail)  # detail is True/False (display_details); a float map raises
    plain_boxes: dict[tuple[int, int], bool] = {}  # neighbouring sides share most box sizes
    for side in crop_sides(full, placement.block, floor):
        if subject is None and not _some_square_plain(counts, place.frame, side, plain_boxes):
            continue  # no square of this side is plain anywhere: neither free nor the fallback's
        cropped, where = place_on_photo(
            spec, width, height, image_key, orientation, detail, subject, crop=side, faint=faint
        )
        if where.free:
            return cropped, dataclasses.replace(where, shrunk=(side, full))
        if (
            subject is None
            and where.detail < least_bad[0]
            and where.detail <= PLAIN_SHARE
            and not reaches_a_corner(cropped, width, height, where.frame, spec.corner_region)
        ):
            least_bad = (where.detail, cropped, dataclasses.replace(where, shrunk=(side, full)))
    # round 5: nowhere free, no masks: a crop whose squares themselves are plain (a subject filling
    # all but a few pockets of the frame: half-size squares fit pockets whole ones cannot), the
    # plainest, still said "no plain region"; a busy photo keeps its whole mark (a crop a shade less
    # busy is no better place and a weaker mark); with masks the keep-out decides what is written.
    # Round 6: never a crop reaching into a corner region: the masked attacker erases it there, and
    # on dtu_scan37's 55% crops four such crops let `masked` recover 93% of the cameras (0% with the
    # whole marks, and with the other three crops kept: bench/results/placement.md)
    return least_bad[1], least_bad[2]


def _some_square_plain(
    integral: np.ndarray, frame: tuple[int, int], side: int, known: dict[tuple[int, int], bool] | None = None
) -> bool:
    """Whether any side x side square of a frame (w, h display px) could hold at most PLAIN_SHARE
    detail on the thumbnail (`integral`: its placement.count_integral, or integral_image: whole
    counts either way): what a free place (no detail under its squares) and the plain-crop fallback
    both need, so a side that fails is skipped without changing the answer (round 5: on a photo busy
    everywhere, 10 of the 11 placements place_fitting tried). A square's thumbnail cells
    (poisoner.placement._shares) span ceil(side x scale) or one more per axis; one fewer is also
    tried, against float rounding, which only makes this say yes more often. `known`: answers per
    box size (cells wide, high) already found for this integral."""
    known = {} if known is None else known
    th, tw = (n - 1 for n in integral.shape)
    w, h = frame
    spans = []
    for cells_per_side in (side * tw / w, side * th / h):
        c = math.ceil(cells_per_side)
        spans.append(sorted({max(1, c - 1), c, c + 1}))
    for cw in spans[0]:
        for ch in spans[1]:
            if cw > tw or ch > th:
                continue
            if (cw, ch) not in known:  # every position's count in one buffer (3.8 -> 1.3 ms a photo)
                counts = np.subtract(integral[ch:, cw:], integral[:-ch, cw:])
                counts -= integral[ch:, :-cw]
                counts += integral[:-ch, :-cw]
                known[cw, ch] = bool(counts.min() <= most_plain_count(cw * ch))
            if known[cw, ch]:
                return True
    return False
