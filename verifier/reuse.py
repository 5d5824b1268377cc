"""What a profile's verification takes over from the default's (issue 30): pair by pair, where its
input is the same.

COLMAP's geometric verification of a pair is a function of that pair's raw matches, the two images'
keypoints, the cameras and the two-view options (RANSAC with a fixed seed), and COLMAP's matcher
and verifier both skip a pair the database already holds. So a profile that sees the default's
input for most pairs gets those pairs' results from the default's databases and computes the rest:
- hardened (`drop_stationary_geometries`): its stationary filter changes a pair's input only where
  it removes a match;
- masked (`copy_unmasked_matches`, `take_unmasked_geometries`): its features are the default's less
  those in the corner masks (verifier.sfm.filter_features), so a pair of images the masks took no
  keypoint from has the default's raw matches and geometry.
verifier.sfm (`reverify_stationary`, `reverify_masked`) then runs COLMAP's verification on the rest,
with the pairs whose taken row says they failed set aside (`failed_pairs_set_aside`).
Each is compared pair by pair with a whole verification of its own in tests/verifier
(test_verify_stationary.py, test_verify_masked_reuse.py).
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any


def stationary_pairs(database: Path, max_error: float) -> list[tuple[int, int]]:
    """The image pairs whose raw matches hold a match that COLMAP's stationary filter removes: the
    same keypoint position, within max_error px, in both images (FilterStationaryMatches in
    colmap/estimators/two_view_geometry.cc, applied to a pair's matches before its RANSAC)."""
    import numpy as np
    import pycolmap

    # a hair wider than COLMAP's `<=` in doubles: verifying an unchanged pair again changes nothing
    limit = max_error * max_error * (1 + 1e-9) + 1e-9
    with pycolmap.Database.open(database) as db:
        xy = {
            im.image_id: db.read_keypoints(im.image_id)[:, :2].astype(np.float64)
            for im in db.read_all_images()
        }
        pair_ids, all_matches = db.read_all_matches()
    pairs = []
    for pair_id, matches in zip(pair_ids, all_matches, strict=True):
        if len(matches) == 0:
            continue
        id1, id2 = pycolmap.pair_id_to_image_pair(pair_id)
        moved = xy[id1][matches[:, 0]] - xy[id2][matches[:, 1]]
        if bool(np.any(np.einsum("ij,ij->i", moved, moved) <= limit)):
            pairs.append((int(id1), int(id2)))
    return pairs


def drop_stationary_geometries(default_verified: Path, work_db: Path) -> int:
    """work_db = the default's verified database less the geometries of the pairs the stationary
    filter changes (hardened's verification computes only those); how many."""
    import pycolmap

    shutil.copyfile(default_verified, work_db)
    two_view = pycolmap.TwoViewGeometryOptions()
    pairs = stationary_pairs(work_db, two_view.stationary_matches_max_error)
    with pycolmap.Database.open(work_db) as db:
        for id1, id2 in pairs:
            db.delete_two_view_geometry(id1, id2)
    return len(pairs)


def same_features(a: Any, b: Any, image_id: int, descriptors: bool) -> bool:
    """Whether two open databases hold the same keypoints (and descriptors) for image_id."""
    import numpy as np

    if a.num_keypoints_for_image(image_id) != b.num_keypoints_for_image(image_id):
        return False
    if not np.array_equal(a.read_keypoints(image_id), b.read_keypoints(image_id)):
        return False
    return not descriptors or np.array_equal(
        a.read_descriptors(image_id).data, b.read_descriptors(image_id).data
    )


def _kept_whole(a: Any, b: Any, descriptors: bool) -> set[int]:
    """The image ids whose features two databases of the same images (same ids) hold alike."""
    return {im.image_id for im in a.read_all_images() if same_features(a, b, im.image_id, descriptors)}


def copy_unmasked_matches(unmasked_db: Path, database: Path) -> tuple[int, int]:
    """Into database (masked features, no matches yet): unmasked_db's raw-match row of every pair whose
    two images have the same keypoints and descriptors in both (matching reads nothing else), so
    COLMAP's matcher, which skips a pair that has a row, matches only the others. Empty rows too: the
    matcher writes one for every pair it matched, and most pairs of a set far apart find too few
    matches (clean lego 40: 306 of 780). (pairs copied, pairs with a row in unmasked_db)."""
    import itertools

    import pycolmap

    with pycolmap.Database.open(unmasked_db) as src, pycolmap.Database.open(database) as dst:
        whole = _kept_whole(src, dst, descriptors=True)
        ids = sorted(im.image_id for im in src.read_all_images())
        rows = [(a, b) for a, b in itertools.combinations(ids, 2) if src.exists_matches(a, b)]
        taken = [(a, b) for a, b in rows if a in whole and b in whole]
        with pycolmap.DatabaseTransaction(dst):
            for id1, id2 in taken:
                dst.write_matches(id1, id2, src.read_matches(id1, id2))
    return len(taken), len(rows)


def take_unmasked_geometries(default_verified: Path, cache_db: Path, work_db: Path) -> tuple[int, int]:
    """work_db = cache_db (masked raw matches) with the default's geometry (default_verified, same
    two-view options) for every pair whose keypoints and raw matches are the default's (masked's
    verification computes the others); (pairs taken, pairs default_verified verified).

    Failed pairs too: COLMAP keeps a row with no inliers for a pair whose verification failed
    (`read_two_view_geometries` leaves those out), and those are the costly pairs, mostly outliers
    so RANSAC runs its every trial (clean lego 40: 284 of 474 pairs)."""
    import numpy as np
    import pycolmap

    shutil.copyfile(cache_db, work_db)
    with pycolmap.Database.open(default_verified) as src, pycolmap.Database.open(work_db) as dst:
        whole = _kept_whole(src, dst, descriptors=False)
        pair_ids, _ = src.read_num_matches()
        taken = 0
        with pycolmap.DatabaseTransaction(dst):
            for pair_id in pair_ids:
                id1, id2 = pycolmap.pair_id_to_image_pair(pair_id)
                if id1 not in whole or id2 not in whole or not src.exists_two_view_geometry(id1, id2):
                    continue
                if dst.exists_matches(id1, id2) and np.array_equal(
                    src.read_matches(id1, id2), dst.read_matches(id1, id2)
                ):
                    dst.write_two_view_geometry(id1, id2, src.read_two_view_geometry(id1, id2))
                    taken += 1
        verified = src.num_verified_image_pairs()
    return taken, verified


@contextlib.contextmanager
def failed_pairs_set_aside(database: Path) -> Iterator[int]:
    """While in it, the pairs whose two-view row holds no inliers (their verification failed) are out
    of database, raw matches and row, then put back as they were; yields how many. COLMAP's
    verification skips a pair whose row has inliers but verifies one with an empty row again, and a
    failed pair is the costliest to verify (mostly outliers: RANSAC runs every trial): on clean lego
    40, 284 of the 474 matched pairs."""
    import pycolmap

    aside = []
    with pycolmap.Database.open(database) as db, pycolmap.DatabaseTransaction(db):
        for pair_id in db.read_num_matches()[0]:
            id1, id2 = pycolmap.pair_id_to_image_pair(pair_id)
            if not db.exists_two_view_geometry(id1, id2):
                continue
            row = db.read_two_view_geometry(id1, id2)
            if len(row.inlier_matches) == 0:
                aside.append((id1, id2, db.read_matches(id1, id2), row))
                db.delete_matches(id1, id2)
                db.delete_two_view_geometry(id1, id2)
    yield len(aside)
    with pycolmap.Database.open(database) as db, pycolmap.DatabaseTransaction(db):
        for id1, id2, matches, row in aside:
            db.write_matches(id1, id2, matches)
            db.write_two_view_geometry(id1, id2, row)
