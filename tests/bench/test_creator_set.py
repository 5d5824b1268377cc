"""testkit/creator_set.py: a creator's shoot made from real photo textures (small sizes here)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from testkit.creator_set import FLOOR, intrinsics, make_creator_set, project
from verifier.synthetic import SyntheticOptions, camera_poses


def test_a_small_creator_set_is_jpeg_photos_marked_by_ppd(shared_dir: Path, tmp_path: Path) -> None:
    clean, poisoned, gt = make_creator_set(tmp_path / "set", views=3, width=600, height=400, workers=1)
    names = sorted(p.name for p in clean.iterdir())
    assert names == ["IMG_0000.jpg", "IMG_0001.jpg", "IMG_0002.jpg"]
    assert sorted(p.name for p in poisoned.iterdir() if not p.name.startswith(".")) == names
    for name in names:
        with Image.open(clean / name) as a, Image.open(poisoned / name) as b:
            assert a.format == "JPEG" and a.size == (600, 400) and b.size == (600, 400)
            pixels_a, pixels_b = np.asarray(a.convert("RGB")), np.asarray(b.convert("RGB"))
        assert pixels_a.std() > 20  # a textured box on a backdrop, not a blank frame
        assert np.count_nonzero(np.abs(pixels_a.astype(int) - pixels_b).max(axis=2) > 30) > 100  # the mark
    assert len(json.loads(gt.read_text())["cameras"]) == 3
    again = make_creator_set(tmp_path / "set", views=3, width=600, height=400, workers=1)
    assert again == (clean, poisoned, gt)  # made once


def test_every_plane_corner_is_in_front_of_every_camera_of_a_40_view_shoot() -> None:
    options = SyntheticOptions(num_views=40, width=6000, height=4000, focal=7200.0, backdrop="plain")
    k = intrinsics(options)
    for rot, trans in camera_poses(options):
        origin, eu, ev, _ = FLOOR
        project(k, rot, trans, np.stack([origin, origin + eu, origin + eu + ev, origin + ev]))
    behind = np.array([[0.0, -20.0, 2.0]])  # far behind the first camera
    with pytest.raises(ValueError, match="behind a camera"):
        project(k, *camera_poses(options)[0], behind)
