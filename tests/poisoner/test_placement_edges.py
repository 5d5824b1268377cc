"""A plain strip along any edge of the frame holds the mark in every photo of a set (a black-box
review: at the left edge 15 of 24 photos failed with masks, or went on the busy part without them,
while the same strip at the right, top or bottom edge held all 24). The mark's path runs right and
down from its anchor, so a photo late on the slide needs its path to start left of the frame; it may,
where the frame holds no better place, as long as every square written is inside."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.formats import poison_file
from poisoner.ladder import default_spec
from poisoner.placement import place_on_photo
from testkit.photos import textured

SPEC = default_spec()
W, H, STRIP = 640, 480, 50  # the default's squares are 38 px here: a strip of 50 holds one column


def _strip(edge: str) -> tuple[slice, slice]:
    every, near, far = slice(None), slice(0, STRIP), slice(-STRIP, None)
    return {"left": (every, near), "right": (every, far), "top": (near, every), "bottom": (far, every)}[edge]


@pytest.mark.parametrize("edge", ["left", "top", "right", "bottom"])
def test_a_masked_subject_leaving_one_plain_strip_keeps_every_photos_whole_mark_in_it(
    tmp_path: Path, edge: str
) -> None:
    src = tmp_path / "grey.png"
    Image.new("RGB", (W, H), (200, 200, 200)).save(src)
    keep_out = np.ones((H, W), dtype=bool)
    keep_out[_strip(edge)] = False
    for i in range(24):  # every point of the slide
        out = tmp_path / f"{i:04d}.png"
        report = poison_file(src, out, SPEC, keep_out=keep_out)
        place = report.place
        assert place is not None and place.free and place.shrunk is None, (i, place)
        changed = (np.asarray(Image.open(out)) != np.asarray(Image.open(src))).any(axis=2)
        assert changed.any() and not (changed & keep_out).any(), i


def test_without_masks_a_plain_strip_at_the_left_edge_is_found_on_every_photo(tmp_path: Path) -> None:
    pixels = textured(H, W, 3)
    wide = STRIP + 20  # without masks a plain place keeps a margin (3% of the shorter side) inside it
    pixels[:, :wide] = 200
    src = tmp_path / "busy.png"
    Image.fromarray(pixels).save(src)
    from poisoner.subject import display_detail

    detail, _ = display_detail(src.read_bytes())
    for i in range(24):
        placement, place = place_on_photo(SPEC, W, H, f"{i:04d}.png", 1, detail)
        assert place.free and place.source == "estimated", (i, place)
        squares = [(placement.x + dx, placement.y + dy) for dx, dy, _ in placement.parts]
        side = placement.lane_side
        assert all(x >= 0 and x + side <= wide for x, _ in squares), (i, squares)


def test_photos_whose_frame_holds_a_plain_place_keep_their_path_inside_it() -> None:
    """The path starts before the edge only where the frame holds no better place (the measured
    placements of lego and dtu_scan37 stay byte for byte): on a plain frame, and on one plain only at
    the right edge, no photo's anchor is outside the frame."""
    plain = np.zeros((120, 160), dtype=bool)
    right = np.ones((120, 160), dtype=bool)
    right[:, -20:] = False
    for detail in (plain, right):
        places = [place_on_photo(SPEC, W, H, f"{i:04d}.png", 1, detail)[1] for i in range(24)]
        assert all(p.anchor[0] >= 0 and p.anchor[1] >= 0 for p in places)
    assert all(p.free for p in places)
