"""Issue 30: hardened's geometric verification from the default's (real pycolmap, real databases).

COLMAP's stationary filter removes a pair's matches that sit at the same position in both images
before that pair's RANSAC; a pair it removes nothing from gets the default's geometry. So the
hardened verification is the default's with only the filtered pairs verified again
(verifier.sfm.reverify_stationary, verifier/reuse.py); here it is compared pair by pair with a whole hardened
verification, on a set carrying the paper's static mark (stationary matches in many pairs) and,
under `integration`, on lego's poisoned set.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from poisoner.blend import poison_array
from poisoner.ladder import named_spec
from verifier.reuse import stationary_pairs
from verifier.sfm import SfmSettings, build_cache_db, reverify_stationary, verify_pairs
from verifier.synthetic import SyntheticOptions, render_scene


def geometry_values(g: Any) -> dict[str, Any]:
    """A pycolmap TwoViewGeometry as plain values."""
    return {
        "config": int(g.config),
        "inliers": np.asarray(g.inlier_matches).tolist(),
        **{m: None if getattr(g, m) is None else np.asarray(getattr(g, m)).tolist() for m in "EFH"},
    }


def geometries(database: Path) -> dict[int, dict[str, Any]]:
    """Every pair's two-view geometry with inliers as plain values (what the mapper reads)."""
    import pycolmap

    with pycolmap.Database.open(database) as db:
        return {int(p): geometry_values(g) for p, g in zip(*db.read_two_view_geometries(), strict=True)}


def every_geometry(database: Path) -> dict[int, dict[str, Any]]:
    """Every pair's two-view geometry row, failed pairs' (no inliers) too, which
    `read_two_view_geometries` leaves out, as plain values."""
    import pycolmap

    out = {}
    with pycolmap.Database.open(database) as db:
        for pair_id in db.read_num_matches()[0]:
            id1, id2 = pycolmap.pair_id_to_image_pair(pair_id)
            if db.exists_two_view_geometry(id1, id2):
                out[int(pair_id)] = geometry_values(db.read_two_view_geometry(id1, id2))
    return out


def compare(images: Path, tmp_path: Path, seed: int) -> tuple[int, int, int]:
    """(pairs verified again, pairs whose geometry the filter changed, pairs); asserts the two ways
    agree."""
    cache = tmp_path / "cache.db"
    build_cache_db(images, cache, SfmSettings())
    default, whole, patched = tmp_path / "default.db", tmp_path / "whole.db", tmp_path / "patched.db"
    for db in (default, whole):
        shutil.copyfile(cache, db)
    verify_pairs(default, SfmSettings(random_seed=seed))
    hardened = SfmSettings(filter_stationary_matches=True, ignore_watermarks=True, random_seed=seed)
    counts_whole = verify_pairs(whole, hardened)
    counts_patched = reverify_stationary(default, patched, hardened)
    assert counts_patched == counts_whole
    assert geometries(patched) == geometries(whole)
    assert every_geometry(patched) == every_geometry(whole)  # failed pairs' rows too
    base, hard = geometries(default), geometries(whole)
    changed = sum(base[p] != hard[p] for p in hard)
    return len(stationary_pairs(cache, 4.0)), changed, len(hard)


def test_hardened_verification_from_the_defaults_equals_a_whole_one(tmp_path: Path) -> None:
    options = SyntheticOptions(num_views=6)
    render_scene(tmp_path / "clean", options)
    marked = tmp_path / "marked"
    marked.mkdir()
    spec = named_spec("paper")  # the same checkerboard at the same pixels of half the views
    for i, p in enumerate(sorted((tmp_path / "clean").glob("*.png"))):
        arr = np.asarray(Image.open(p).convert("RGB"))
        if i % 2 == 0:
            arr, _ = poison_array(arr, spec, image_key=p.name)
        Image.fromarray(arr).save(marked / p.name)
    reverified, changed, pairs = compare(marked, tmp_path, seed=0)
    assert reverified > 0 and changed > 0  # the filter mattered, and the shortcut reproduced it
    assert reverified < pairs  # ... while verifying fewer pairs than a whole verification


def lego_sets(tmp_path: Path, views: int = 16) -> tuple[Path, Path]:
    """(clean, poisoned): lego's first views at 800 px on white, and with ppd's default mark."""
    from poisoner.ladder import default_spec
    from verifier.shared_data import prepare_lego

    clean, _, _ = prepare_lego(views)
    poisoned = tmp_path / "poisoned"
    poisoned.mkdir()
    for i in range(views):
        arr = np.asarray(Image.open(clean / f"r_{i}.png").convert("RGB"))
        out, _ = poison_array(arr, default_spec(), image_key=f"r_{i}.png")
        Image.fromarray(out).save(poisoned / f"r_{i}.png")
    return clean, poisoned


@pytest.mark.slow
@pytest.mark.integration
@pytest.mark.parametrize("seed", [0, 1])
def test_lego_hardened_verification_from_the_defaults(shared_dir: Path, tmp_path: Path, seed: int) -> None:
    """Lego, 16 views at 800 px with ppd's default mark: the same hardened geometry, pair by pair."""
    clean, poisoned = lego_sets(tmp_path)
    reverified, _, pairs = compare(poisoned, tmp_path, seed=seed)
    assert 0 < reverified < pairs
    (tmp_path / "clean").mkdir()  # clean: pairs whose verification fails, their rows kept as they were
    reverified, _, pairs = compare(clean, tmp_path / "clean", seed=seed)
    assert reverified < pairs
