"""bench/bench_watermark.py's designs (testkit/watermark_designs.py): claims its results table leans on."""

from __future__ import annotations

import numpy as np

from poisoner.blend import apply_patch
from poisoner.spec import PatchSpec
from testkit.watermark_designs import designs


def _same_pixels(one: PatchSpec, other: PatchSpec, w: int, h: int) -> bool:
    rng = np.random.default_rng(1)
    photo = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    for i in range(0, 40, 3):
        name = f"r_{i}.png"
        a = apply_patch(photo, one.resolve(w, h, image_key=name))
        if not np.array_equal(a, apply_patch(photo, other.resolve(w, h, image_key=name))):
            return False
    return True


def test_the_named_tilted_lanes_are_what_was_measured_at_each_size() -> None:
    """watermark-lanes-2 (blocks of 0.25% of the width, >= 4 px) writes the same pixels as the bench's
    0.5%-block form up to 800 px wide (lego, dtu at 800x600, the 640 px render) and as its 4 px-block
    form at 1600 px (dtu at full size): those runs stand for the named spec."""
    names = ("watermark-lanes-2", "watermark-lanes-2-b4", "watermark-lanes-2-b05")
    (named,), (b4,), (b05,) = (designs()[n] for n in names)
    for w, h in ((800, 600), (800, 800), (640, 480)):
        assert _same_pixels(named, b05, w, h), (w, h)
        assert _same_pixels(named, b4, w, h), (w, h)
    assert _same_pixels(named, b4, 1600, 1200)
    assert not _same_pixels(named, b05, 1600, 1200)
    assert named.resolve(1600, 1200).block == 4 and b05.resolve(1600, 1200).block == 8
    assert named.resolve(3200, 2400).block == 8  # a quarter percent above 1600 px: 4 px after a 2x downscale
