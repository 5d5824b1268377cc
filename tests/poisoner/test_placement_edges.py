"""A strip free of the subject along any edge of the frame holds the mark in every photo of a set (a
black-box review: at the left edge 15 of 24 masked photos failed, while the same strip at the right,
top or bottom edge held all 24). The mark's path runs right and down from its anchor, so a photo late
on the slide needs its path to start left of the frame; with masks it may, where the frame holds no
better place, as long as every square written is inside. Without masks it may not: there it moved two
marks of a dtu_scan37 crop and the default attacker recovered more cameras (placement.md round 8)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.formats import poison_file
from poisoner.ladder import default_spec
from poisoner.placement import place_on_photo

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


def test_photos_whose_frame_holds_a_plain_place_keep_their_path_inside_it() -> None:
    """The path starts before the edge only with masks and where the frame holds no better place (the
    measured placements of lego and dtu_scan37 stay byte for byte): without masks, on a plain frame,
    on one plain only at the right edge and on one plain only at the left edge, no photo's anchor is
    outside the frame."""
    plain = np.zeros((120, 160), dtype=bool)
    right, left = np.ones((120, 160), dtype=bool), np.ones((120, 160), dtype=bool)
    right[:, -20:] = False
    left[:, :20] = False
    for detail in (plain, right, left):
        places = [place_on_photo(SPEC, W, H, f"{i:04d}.png", 1, detail)[1] for i in range(24)]
        assert all(p.anchor[0] >= 0 and p.anchor[1] >= 0 for p in places)
        assert detail is left or all(p.free for p in places)
