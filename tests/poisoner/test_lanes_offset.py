"""The default mark's two squares slide by different amounts at every size (black-box review 9, F8).

COLMAP's watermark test drops a pair's border matches when one translation fits them: two squares that
keep one offset from each other move as one rigid block and are removed together. Each lane's slide
was rounded to whole lattice units alone, so wherever the step is 5 px or less (under about 730 px
wide) the 1x and 2x lanes both moved one unit per photo: square 2 stayed 44 px below square 1 in every
640x480 photo. Real PNG files through poison_file, the squares found in the changed pixels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from poisoner.formats import poison_file
from poisoner.ladder import default_spec
from poisoner.spec import LANES_MAX_AREA

SPEC = default_spec()
SIZES = [(320, 240), (640, 360), (640, 480), (1280, 720)]


def squares(before: np.ndarray, after: np.ndarray) -> list[tuple[int, int, int, int]]:
    """(x, y, w, h) of each block of changed pixels, top first."""
    changed = np.abs(after.astype(int) - before.astype(int)).max(axis=2) > 0
    labels, _ = ndimage.label(changed)
    boxes = [(s[1].start, s[0].start, s[1].stop - s[1].start, s[0].stop - s[0].start)
             for s in ndimage.find_objects(labels)]  # fmt: skip
    return sorted(boxes, key=lambda b: (b[1], b[0]))


@pytest.mark.parametrize(("width", "height"), SIZES)
def test_the_two_squares_offset_changes_from_photo_to_photo(tmp_path: Path, width: int, height: int) -> None:
    # plain grey: every photo's mark at the same preferred anchor, so only the lanes' slides move it;
    # the texture's levels are 0 and 255, so every pixel of a square differs from the grey
    grey = np.full((height, width, 3), 128, dtype=np.uint8)
    offsets, moves, crops = [], [], []
    first: list[tuple[int, int, int, int]] | None = None
    for i in range(8):
        src, dst = tmp_path / f"frame_{i:04d}.png", tmp_path / f"out_{i:04d}.png"
        Image.fromarray(grey).save(src)
        poison_file(src, dst, SPEC)
        out = np.asarray(Image.open(dst).convert("RGB"))
        found = squares(grey, out)
        assert len(found) == 2, found  # two squares, apart
        (x0, y0, w0, h0), (x1, y1, w1, h1) = found
        assert w0 == h0 == w1 == h1  # whole squares, same side
        assert 2 * w0 * h0 <= LANES_MAX_AREA * width * height  # the visibility budget
        offsets.append((x1 - x0, y1 - y0))
        crops.append([out[y : y + h, x : x + w] for x, y, w, h in found])
        first = first or found
        moves.append([(x - fx, y - fy) for (x, y, _, _), (fx, fy, _, _) in zip(found, first, strict=True)])
    # square 2's offset from square 1 changes between consecutive photos: no translation fits both
    for a, b in zip(offsets, offsets[1:], strict=False):
        assert a != b, f"{width}x{height}: square 2 stays at {a} from square 1 ({offsets})"
    dx, dy = SPEC.slide_direction
    for lane_moves in moves:
        assert all(mx * dy == my * dx for mx, my in lane_moves)  # each along the slide line
    for k in (0, 1):  # each square's copies stay pixel-identical (SIFT matches them)
        assert all(np.array_equal(c[k], crops[0][k]) for c in crops)


@pytest.mark.parametrize("width", range(300, 1400, 20))
@pytest.mark.parametrize("lanes", [2, 3])
def test_no_two_lanes_move_as_one_block(width: int, lanes: int) -> None:
    """Every size up to where each lane's own rounding already differed, 2 and 3 lanes (`--lanes`):
    no two lanes keep one offset over the photos, nor over a video's frames (fractional indices
    along the same path); the default's two lanes change it between every two consecutive photos.
    (Three lanes on a short path can meet one photo step at a fold: two of three still differ.)"""
    spec = SPEC.replace(lanes=lanes)
    height = width * 3 // 4
    photos = [spec.resolve(width, height, index=i) for i in range(30)]
    frames = [spec.resolve(width, height, index=i * 6 / 30) for i in range(60)]  # 2 s at 30 fps
    for placements in (photos, frames):
        tops = [[(dx, dy) for dx, dy, _ in p.parts] for p in placements]
        for j in range(lanes):
            for k in range(j + 1, lanes):
                rel = [(t[k][0] - t[j][0], t[k][1] - t[j][1]) for t in tops]
                assert len(set(rel)) > 1, (width, j, k, rel[0])
                if lanes == 2 and placements is photos:
                    assert all(a != b for a, b in zip(rel, rel[1:], strict=False)), (width, rel)
