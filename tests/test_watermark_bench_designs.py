"""bench/bench_watermark.py's designs: the claims its results table leans on."""

from __future__ import annotations

import numpy as np

from bench.bench_watermark import designs
from poisoner.blend import apply_patch


def test_lanes_2_b4_is_pixel_identical_to_lanes_2_at_800_px_wide() -> None:
    """At 800 px wide 0.5% of the width is 4 px: the two designs write the same pixels there (so the
    800 px runs of one stand for the other), and differ only on larger frames."""
    (b4,), (lanes2,) = designs()["watermark-lanes-2-b4"], designs()["watermark-lanes-2"]
    rng = np.random.default_rng(1)
    for w, h in ((800, 600), (800, 800)):
        photo = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        for i in range(0, 40, 3):
            name = f"r_{i}.png"
            a = apply_patch(photo, b4.resolve(w, h, image_key=name))
            b = apply_patch(photo, lanes2.resolve(w, h, image_key=name))
            assert np.array_equal(a, b), (w, h, i)
    assert b4.resolve(1600, 1200).block == 4 and lanes2.resolve(1600, 1200).block == 8
