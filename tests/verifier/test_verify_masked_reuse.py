"""Issue 30: the masked profile's matching and verification from the default's (real pycolmap, real
databases).

Masked's features are the default's less the keypoints in the four corner masks, so a pair of images
the masks took nothing from has the default's raw matches and two-view geometry
(verifier.reuse, verifier.sfm.reverify_masked). Here both are compared pair by pair with a
masked run of its own (every pair matched and verified), on a set where some views have plain corners
and the others a textured one, and, under `integration`, on lego. Its features are the unmasked ones
filtered by position, which test_verify_shared.py compares with COLMAP's masked extraction by name
(a second extraction numbers the images in the order its threads finish).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.blend import poison_array
from poisoner.ladder import default_spec
from tests.verifier.test_verify_stationary import every_geometry, geometries, lego_sets
from verifier.reuse import copy_unmasked_matches, drop_stationary_geometries
from verifier.sfm import (
    MASKED_CORNER_FRACTION,
    SfmSettings,
    build_cache_db,
    corner_mask,
    filter_features,
    match_raw,
    reverify_masked,
    reverify_stationary,
    verify_pairs,
)
from verifier.synthetic import SyntheticOptions, render_scene


def raw_matches(database: Path) -> dict[tuple[int, int], list[list[int]]]:
    """Every image pair's raw-match row, empty ones too (COLMAP's readers leave those out)."""
    import itertools

    import pycolmap

    with pycolmap.Database.open(database) as db:
        ids = sorted(im.image_id for im in db.read_all_images())
        return {
            (a, b): np.asarray(db.read_matches(a, b)).tolist()
            for a, b in itertools.combinations(ids, 2)
            if db.exists_matches(a, b)
        }


def compare(images: Path, tmp_path: Path, seed: int) -> tuple[int, int, int, int]:
    """(pairs whose raw-match rows were copied, pairs with a row, of those copied the empty ones,
    failed pairs); asserts that the masked cache and verification made from the default's equal a
    masked run of its own, pair by pair."""
    # one matcher thread: COLMAP's CPU matcher gives a pair other matches now and then when several
    # threads run (CI once saw a pair of this set go empty in one of the two runs), which no copy of
    # another run's rows can equal
    default = SfmSettings(random_seed=seed, matcher_threads=1)
    masked = SfmSettings(random_seed=seed, mask_corners=MASKED_CORNER_FRACTION, matcher_threads=1)
    unmasked_cache, own_cache, reused_cache = (tmp_path / f"{n}.db" for n in ("unmasked", "own", "reused"))
    build_cache_db(images, unmasked_cache, default)
    filter_features(unmasked_cache, own_cache, images, MASKED_CORNER_FRACTION)
    match_raw(own_cache, masked)  # every pair matched
    build_cache_db(images, reused_cache, masked, features_from=unmasked_cache)
    assert raw_matches(reused_cache) == raw_matches(own_cache)

    default_verified, own, reused = tmp_path / "default-verified.db", tmp_path / "own-v.db", tmp_path / "r.db"
    shutil.copyfile(unmasked_cache, default_verified)
    verify_pairs(default_verified, default)
    shutil.copyfile(own_cache, own)
    counts_own = verify_pairs(own, masked)
    counts_reused = reverify_masked(default_verified, reused_cache, reused, masked)
    assert counts_reused == counts_own
    assert every_geometry(reused) == every_geometry(own)
    assert geometries(reused) == geometries(own)  # what the mapper reads
    failed = sum(not g["inliers"] for g in every_geometry(own).values())

    scratch = tmp_path / "copy.db"  # how many pairs the shortcut took (the cache build says it too)
    filter_features(unmasked_cache, scratch, images, MASKED_CORNER_FRACTION)
    copied, pairs = copy_unmasked_matches(unmasked_cache, scratch)
    empty = sum(not m for m in raw_matches(scratch).values())
    return copied, pairs, empty, failed


def plain_corners(arr: np.ndarray) -> np.ndarray:
    """The view flat grey but for its central 40 x 40% (no keypoint in the masked corners: the grey's
    edge, where SIFT finds blobs, lies a tenth of the frame away from them)."""
    h, w = arr.shape[:2]
    out = np.full_like(arr, 128)
    centre = (slice(3 * h // 10, 7 * h // 10), slice(3 * w // 10, 7 * w // 10))
    out[centre] = arr[centre]
    assert (corner_mask(w, h, MASKED_CORNER_FRACTION) == 0).any()
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_masked_matching_and_verification_from_the_defaults_equal_its_own(tmp_path: Path, seed: int) -> None:
    render_scene(tmp_path / "clean", SyntheticOptions(num_views=6))
    images = tmp_path / "images"
    images.mkdir()
    for i, p in enumerate(sorted((tmp_path / "clean").glob("*.png"))):
        arr = np.asarray(Image.open(p).convert("RGB"))
        arr = plain_corners(arr) if i % 2 == 0 else arr  # the masks take nothing from half the views
        arr, _ = poison_array(arr, default_spec(), image_key=p.name)
        Image.fromarray(arr).save(images / p.name)
    copied, pairs, _, _ = compare(images, tmp_path, seed)
    # the three views with plain corners make three pairs; the textured corners change the rest
    assert copied == 3 and pairs > copied


def test_a_failed_pair_of_the_defaults_is_taken_as_failed(tmp_path: Path) -> None:
    """COLMAP keeps a row without inliers for a pair whose verification failed, and verifies such a
    pair again (it skips only pairs with inliers): masked and hardened set those rows aside while
    COLMAP verifies the rest (verifier.reuse.failed_pairs_set_aside) instead of running that pair's
    RANSAC again, where a real failure costs the most: every trial. Here one untouched pair's row is
    made a failed one in the default's database, so whether it was taken shows in theirs; the raw
    matches are put back as they were."""
    import pycolmap

    # 6 views, not 4: 4 left one pair with inliers (28), and COLMAP numbers the images in the order its
    # extraction threads finish, so that pair's matches (and its verification) change from run to run:
    # CI once saw it fail, no pair left to take (StopIteration). 6 give three such pairs (23-36).
    render_scene(tmp_path / "clean", SyntheticOptions(num_views=6))
    images = tmp_path / "images"
    images.mkdir()
    for p in sorted((tmp_path / "clean").glob("*.png")):
        Image.fromarray(plain_corners(np.asarray(Image.open(p).convert("RGB")))).save(images / p.name)
    masked = SfmSettings(mask_corners=MASKED_CORNER_FRACTION)
    hardened = SfmSettings(filter_stationary_matches=True, ignore_watermarks=True)
    unmasked, cache, default_verified = tmp_path / "u.db", tmp_path / "m.db", tmp_path / "dv.db"
    build_cache_db(images, unmasked, SfmSettings())
    build_cache_db(images, cache, masked, features_from=unmasked)
    shutil.copyfile(unmasked, default_verified)
    verify_pairs(default_verified, SfmSettings())
    before = every_geometry(default_verified)
    # The pair made failed: one with inliers that masked and hardened take from the default's rows as
    # they are (the masks took none of its matches; the stationary filter changes nothing in it).
    drop_stationary_geometries(default_verified, tmp_path / "probe.db")
    filter_keeps, untouched = every_geometry(tmp_path / "probe.db"), raw_matches(unmasked)
    masked_matches = raw_matches(cache)
    takeable = [p for p in filter_keeps if masked_matches.get(p) == untouched.get(p)]
    pair = next(p for p in takeable if before[p]["inliers"])
    # what masked and hardened make of the default's rows as they are: every other pair's reference
    for name in ("work", "hardened"):
        shutil.copyfile(default_verified, tmp_path / f"{name}-ref-dv.db")
    reverify_masked(tmp_path / "work-ref-dv.db", cache, tmp_path / "work-ref.db", masked)
    reverify_stationary(tmp_path / "hardened-ref-dv.db", tmp_path / "hardened-ref.db", hardened)
    failed = pycolmap.TwoViewGeometry()
    failed.config = pycolmap.TwoViewGeometryConfiguration.DEGENERATE  # what a real failure's row says
    with pycolmap.Database.open(default_verified) as db:
        db.update_two_view_geometry(*pycolmap.pair_id_to_image_pair(pair), failed)
    reverify_masked(default_verified, cache, tmp_path / "work.db", masked)
    reverify_stationary(default_verified, tmp_path / "hardened.db", hardened)  # the same for hardened
    for work in ("work", "hardened"):
        after = every_geometry(tmp_path / f"{work}.db")
        reference = every_geometry(tmp_path / f"{work}-ref.db")
        assert after[pair]["inliers"] == [] and reference[pair]["inliers"]  # taken, not verified again
        others = {p: g for p, g in after.items() if p != pair}
        assert others == {p: g for p, g in reference.items() if p != pair}
        assert raw_matches(tmp_path / f"{work}.db") == raw_matches(cache if work == "work" else unmasked)


@pytest.mark.slow
@pytest.mark.integration
def test_lego_masked_from_the_defaults(tmp_path: Path) -> None:
    """Lego, 16 views at 800 px, clean (pairs that fail verification, mostly outliers) and with ppd's
    default mark: the same masked matches and geometry, every row."""
    clean, poisoned = lego_sets(tmp_path)
    (tmp_path / "c").mkdir()
    copied, pairs, empty, failed = compare(clean, tmp_path / "c", seed=0)
    assert 0 < copied < pairs and failed > 0 and empty > 0  # too few matches, failed: both taken
    (tmp_path / "p").mkdir()
    copied, pairs, _, _ = compare(poisoned, tmp_path / "p", seed=0)
    assert 0 < copied < pairs
