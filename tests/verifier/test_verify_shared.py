"""Issue 30: work shared across profiles gives the figures each profile gives alone.

Real pycolmap throughout: the masked profile's filtered features against COLMAP's own masked
extraction, a whole shared verification against each profile run alone (a small generated set;
lego at two seeds under `integration`/`slow`), and the clean reference cached until the originals
change.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from poisoner.blend import poison_array
from poisoner.ladder import default_spec
from verifier.synthetic import SyntheticOptions, render_scene
from verifier.verification import PROFILES, VerificationReport, VerifyOptions, content_key, verify_folders

SMALL = SyntheticOptions(num_views=6)
# The profiles whose work is shared (published has its own pixels: nothing of it is shared).
SHARING = ("default", "hardened", "global", "masked")


def poison_folder(clean: Path, out: Path) -> Path:
    """ppd's default mark on every image (the file name keys the moving mark, as poison_file does)."""
    out.mkdir(parents=True, exist_ok=True)
    spec = default_spec()
    for p in sorted(clean.glob("*.png")):
        arr, _ = poison_array(np.asarray(Image.open(p).convert("RGB")), spec, image_key=p.name)
        Image.fromarray(arr).save(out / p.name)
    return out


@pytest.fixture(scope="module")
def small_sets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("shared-sets")
    render_scene(root / "clean", SMALL)
    return {"clean": root / "clean", "poisoned": poison_folder(root / "clean", root / "poisoned")}


def figures(report: VerificationReport) -> dict[str, Any]:
    """Every figure a verdict uses, per profile, and the verdict. Not the median rotation error of
    the poisoned cameras (a reason's detail, not the verdict's input): COLMAP's mappers are not
    bit-reproducible (three identical global-mapper runs on SMALL's poisoned set: 144.03, 146.95,
    144.02 deg; incremental: 14.0228 and 14.0232), while geometric verification is on this set
    (identical inliers in three runs), which is why sharing it changes nothing. On lego it is not
    always (test_lego_shared_verification_gives_each_profiles_figures_alone's docstring). Of the models, the
    largest, the verdict's (`registered` is its size): the small side models besides it vary from run
    to run (2026-11-27, the code unchanged, hardened's clean side alone gave [6, 2] where the shared
    run gave [6]; the first failure of this test in CI, with a COLMAP run beside it)."""
    out = {}
    for name, p in report.profiles.items():
        sides = {
            side: {
                k: d.get(k) for k in ("outcome", "num_images", "verified_pairs", "registered")
            }
            for side, d in (("clean", p.clean), ("poisoned", p.poisoned))
        }
        out[name] = {
            "verdict": str(p.verdict),
            **sides,
            "frac_within_5deg": (p.vs_clean or {}).get("frac_within_5deg"),
        }
    return out


def test_masked_features_filtered_by_position_equal_colmaps_masked_extraction(
    small_sets: dict[str, Path], tmp_path: Path
) -> None:
    import pycolmap

    from verifier.sfm import MASKED_CORNER_FRACTION, SfmSettings, extract_features, filter_features

    images = small_sets["poisoned"]
    unmasked, own, filtered = tmp_path / "unmasked.db", tmp_path / "own.db", tmp_path / "filtered.db"
    extract_features(images, unmasked, SfmSettings(), tmp_path / "m0")
    masked = SfmSettings(mask_corners=MASKED_CORNER_FRACTION)
    extract_features(images, own, masked, tmp_path / "m1")
    filter_features(unmasked, filtered, images, MASKED_CORNER_FRACTION)
    removed = 0
    with (
        pycolmap.Database.open(own) as a,
        pycolmap.Database.open(filtered) as b,
        pycolmap.Database.open(unmasked) as u,
    ):
        by_name = {im.name: im.image_id for im in b.read_all_images()}
        assert len(by_name) == SMALL.num_views
        for image in a.read_all_images():
            other = by_name[image.name]
            np.testing.assert_array_equal(a.read_keypoints(image.image_id), b.read_keypoints(other))
            np.testing.assert_array_equal(
                a.read_descriptors(image.image_id).data, b.read_descriptors(other).data
            )
            removed += u.num_keypoints_for_image(other) - b.num_keypoints_for_image(other)
        assert b.num_matches() == 0 and b.num_verified_image_pairs() == 0  # matched afresh by masked
    assert removed > 0  # the corners held features (the mark's): the filter did something


def test_a_shared_verification_gives_each_profiles_figures_alone(
    small_sets: dict[str, Path], tmp_path: Path
) -> None:
    from verifier.child_files import KEPT_DATABASE

    options = VerifyOptions(
        timeout_s=300, camera_params=SMALL.camera_params(), visibility_images=0, keep_databases=True
    )
    kept = dataclasses.replace(options, keep_cache=True)
    shared = verify_folders(small_sets["clean"], small_sets["poisoned"], tmp_path / "all", SHARING, kept)
    alone = {}
    for profile in SHARING:
        report = verify_folders(
            small_sets["clean"], small_sets["poisoned"], tmp_path / profile, [profile], options
        )
        alone.update(figures(report))
        for side in ("clean", "poisoned"):  # each mapper read what it reads alone, row for row
            dbs = [Path(r.profiles[profile].model_dir or "") / side / KEPT_DATABASE for r in (shared, report)]
            assert database_digest(dbs[0]) == database_digest(dbs[1]), (profile, side)
    assert figures(shared) == alone
    assert list(shared.profiles) == list(SHARING)
    # 320 px photos: SIFT on the CPU whatever the machine has (gpu_sift_suits)
    assert {p.clean["device"] for p in shared.profiles.values()} == {"cpu"}
    clean_default = shared.profiles["default"].clean
    assert clean_default["registered"] == SMALL.num_views  # a real reference, not two empty runs agreeing
    # the sharing happened: global copied default's verified database, masked filtered its features
    assert "features_and_matches_s" not in shared.profiles["hardened"].poisoned["timings"]
    assert "features_and_matches_s" not in shared.profiles["global"].poisoned["timings"]
    # hardened's verification was made from the default's, on both sides (a verify-only child each)
    logs = [p.read_text() for p in (tmp_path / "all" / ".cache").rglob("sfm.log")]
    assert sum("stationary filter:" in text for text in logs) == 2


def test_masked_takes_the_defaults_verification_where_its_masks_change_nothing(tmp_path: Path) -> None:
    """Half the views have plain corners: masked's clean and poisoned sides take those pairs' matches
    and geometry from the default's (verifier.reuse), and its figures are masked's alone."""
    import re

    from tests.verifier.test_verify_masked_reuse import plain_corners

    render_scene(tmp_path / "rendered", SMALL)
    clean = tmp_path / "clean"
    clean.mkdir()
    for i, p in enumerate(sorted((tmp_path / "rendered").glob("*.png"))):
        arr = np.asarray(Image.open(p).convert("RGB"))
        Image.fromarray(plain_corners(arr) if i % 2 == 0 else arr).save(clean / p.name)
    poisoned = poison_folder(clean, tmp_path / "poisoned")
    options = VerifyOptions(timeout_s=300, camera_params=SMALL.camera_params(), visibility_images=0)
    kept = dataclasses.replace(options, keep_cache=True)
    both = verify_folders(clean, poisoned, tmp_path / "both", ["default", "masked"], kept)
    alone = verify_folders(clean, poisoned, tmp_path / "alone", ["masked"], kept)
    assert figures(both)["masked"] == figures(alone)["masked"]

    def said(run: str, what: str) -> list[tuple[int, int]]:
        text = "".join(p.read_text() for p in (tmp_path / run).rglob("sfm.log"))
        return [(int(a), int(b)) for a, b in re.findall(rf"masked: (\d+) of (\d+) pair\(s\) {what}", text)]

    for what in ("keep the unmasked raw matches", "taken from the default's verification"):
        counts = said("both", what)
        assert len(counts) == 2, what  # the clean side and the poisoned one
        assert all(0 < n < pairs for n, pairs in counts), counts  # some pairs, not all
        assert said("alone", what) == []  # nothing to take without the default in the run
    # the default's verification was made once per side (a verify-only child), for both profiles
    assert len(list((tmp_path / "both" / ".cache").rglob("*-verified-*-work"))) == 2


def test_the_clean_reference_is_cached_until_an_original_changes(
    small_sets: dict[str, Path], tmp_path: Path
) -> None:
    clean = tmp_path / "clean"
    clean.mkdir()
    for p in small_sets["clean"].iterdir():
        (clean / p.name).write_bytes(p.read_bytes())
    options = VerifyOptions(
        timeout_s=300, camera_params=SMALL.camera_params(), visibility_images=0,
        clean_cache_dir=tmp_path / "clean-cache", clean_cache_keep=1,
    )  # fmt: skip
    first = verify_folders(clean, small_sets["poisoned"], tmp_path / "one", ["default"], options)
    assert not list((tmp_path / "one").rglob("database.db"))  # the mappers' input kept only when asked
    key = content_key(clean, sorted(os.listdir(clean)))
    assert [p.name for p in (tmp_path / "clean-cache").iterdir()] == [key]
    second = verify_folders(clean, small_sets["poisoned"], tmp_path / "two", ["default"], options)
    reused = dict(second.profiles["default"].clean)
    made = reused.pop("reused_from", None)  # said: the time is the earlier run's (a black-box review)
    assert reused == first.profiles["default"].clean and "reused_from" not in first.profiles["default"].clean
    assert made is not None and re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d", made), made  # read back, not rerun
    from daemon.cli.verify_tables import reused_line

    line = reused_line(second.to_dict())
    assert line is not None and "clean reference reused for default: " in line and made in line, line
    assert reused_line(first.to_dict()) is None
    # the key names the SIFT device by its end alone: clean results cached before cpu_sift stay valid
    stored = [json.loads(p.read_text()) for p in (tmp_path / "clean-cache").rglob("result.json")]
    keys = [r["reuse_key"] for r in stored]
    assert keys and all('"camera_model"' in k and "cpu_sift" not in k for k in keys)
    assert not any("matcher_threads" in k for k in keys)  # COLMAP's own, as before the setting
    assert figures(second) == figures(first)
    # same bytes, new mtime: still cached (the key is the content); one changed original: not
    first_view = clean / sorted(os.listdir(clean))[0]
    os.utime(first_view, (1, 1))
    assert content_key(clean, sorted(os.listdir(clean))) == key
    Image.open(first_view).rotate(180).save(first_view)
    third = verify_folders(clean, small_sets["poisoned"], tmp_path / "three", ["default"], options)
    assert third.profiles["default"].clean["elapsed_s"] != first.profiles["default"].clean["elapsed_s"]
    assert [p.name for p in (tmp_path / "clean-cache").iterdir()] != [key]  # the stale cache is gone
    assert len(list((tmp_path / "clean-cache").iterdir())) == 1


def database_digest(path: Path) -> dict[str, str]:
    """A COLMAP database's every table, row by row in the order COLMAP reads them (rowid): sha256."""
    import hashlib
    import sqlite3

    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        query = "SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name"
        tables = [r[0] for r in con.execute(query)]
        digests = {}
        for table in tables:
            h = hashlib.sha256()
            for row in con.execute(f'SELECT * FROM "{table}" ORDER BY rowid'):
                h.update(repr(row).encode())
            digests[table] = h.hexdigest()
        return digests
    finally:
        con.close()


# a side's mapping ran to its end (a model, or none found): what a deterministic mapper repeats
FINISHED = {"ok", "failed"}


@pytest.mark.slow
@pytest.mark.integration
@pytest.mark.parametrize("seed", [0, 1])
def test_lego_shared_verification_gives_each_profiles_figures_alone(
    shared_dir: Path, tmp_path: Path, seed: int
) -> None:
    """Lego, 16 views at 800 px, every profile shared and each alone, the incremental mapper on one
    thread: every side's mapper reads the same verified database (table by table, row by row in
    COLMAP's reading order: features, raw matches, two-view geometries, cameras, images), and every
    side whose mapping ran to its end in both runs has the same figures, and a profile whose four
    sides did the same verdict and cameras within 5 degrees. One thread, because on several COLMAP
    4.2.1's mapper maps one database differently when the machine is busy (3 of 12 runs two at a
    time; docs/VERIFIER.md, "Mapping under load": this test's figures failed so at both seeds on
    2026-12-02, the default's patched `registered` 2 shared against 16 alone, with identical
    databases). A mapping cut by the timeout (seed 0: hardened's patched side spends minutes an image
    in structure-less registrations) is cut at another point in each run: its database is still
    compared (kept before the mapper opens it), its figures are not. COLMAP's raw matching of the
    same features once gave other matches (2026-12-06, seed 0: the default's patched side alone, 22
    of 120 pairs a few matches apart, where the shared run and 17 matchings since agree: one at a
    time, three or four at once, beside two busy loops, and afresh from extraction): a failure in
    one side's raw matches alone is that, not the sharing (docs/VERIFIER.md)."""
    from verifier.child_files import KEPT_DATABASE
    from verifier.shared_data import prepare_lego

    clean, _, _ = prepare_lego(16)
    views = tmp_path / "clean"
    views.mkdir()
    for i in range(16):
        os.link(clean / f"r_{i}.png", views / f"r_{i}.png")
    poisoned = poison_folder(views, tmp_path / "poisoned")
    options = VerifyOptions(
        timeout_s=240, random_seed=seed, visibility_images=0, keep_databases=True, mapper_threads=1
    )
    shared = verify_folders(views, poisoned, tmp_path / "all", PROFILES, options)
    together = figures(shared)
    sides_compared = profiles_compared = 0
    for profile in PROFILES:
        alone = verify_folders(views, poisoned, tmp_path / profile, [profile], options)
        for side in ("clean", "poisoned"):
            dbs = [Path(r.profiles[profile].model_dir or "") / side / KEPT_DATABASE for r in (shared, alone)]
            assert all(db.is_file() for db in dbs), (profile, side)
            assert database_digest(dbs[0]) == database_digest(dbs[1]), (profile, side)
        mine, theirs = figures(alone)[profile], together[profile]
        ended = [s for s in ("clean", "poisoned") if {mine[s]["outcome"], theirs[s]["outcome"]} <= FINISHED]
        for side in ended:
            assert mine[side] == theirs[side], (profile, side)
            sides_compared += 1
        if len(ended) == 2:
            assert mine == theirs, profile
            profiles_compared += 1
    assert sides_compared >= 6 and profiles_compared >= 2  # the figures were compared, not skipped


def test_published_starts_first_the_rest_as_asked() -> None:
    from verifier.verification import start_order

    assert start_order(PROFILES) == ["published", "default", "hardened", "global", "masked"]
    assert start_order(["masked", "default"]) == ["masked", "default"]


def test_every_clean_side_takes_a_slot_before_any_poisoned_one() -> None:
    from verifier.verification import side_order

    order = side_order(["default", "published", "masked"])
    assert order == [
        ("published", "clean"), ("default", "clean"), ("masked", "clean"),
        ("published", "poisoned"), ("default", "poisoned"), ("masked", "poisoned"),
    ]  # fmt: skip
    # --seeds 2: every profile's first poisoned run before any profile's second
    assert side_order(["default", "published"], seeds=2) == [
        ("published", "clean"), ("default", "clean"), ("published", "poisoned"), ("default", "poisoned"),
        ("published", "poisoned-run2"), ("default", "poisoned-run2"),
    ]  # fmt: skip


def test_feature_builds_at_once_follow_the_memory() -> None:
    from verifier.shared_sfm import feature_builds_at_once

    gib = 1 << 30
    assert feature_builds_at_once(4 * gib) == 1  # a small machine: one set's SIFT at a time
    assert feature_builds_at_once(16 * gib) == 2
    assert feature_builds_at_once(24 * gib) == 3
    assert feature_builds_at_once(128 * gib) == 16
    assert feature_builds_at_once(0) == 1  # memory unknown: still one
    assert feature_builds_at_once() >= 1  # this machine's


def test_images_are_numbered_by_name_whichever_extraction_thread_finishes_first(tmp_path: Path) -> None:
    """COLMAP's extraction numbers images in the order its threads finish, and the numbering decides
    which image of a pair is matched against the other: the same photos gave other verified pairs from
    run to run (a test in CI lost its only verified pair so). ppd writes the images first, in name
    order; every run numbers them so, and every image still gets its features."""
    import pycolmap

    from verifier.sfm import SfmSettings, extract_features, list_images

    render_scene(tmp_path / "views", SyntheticOptions(num_views=12))
    names = list_images(tmp_path / "views")
    for run in range(3):
        extract_features(tmp_path / "views", tmp_path / f"{run}.db", SfmSettings(), tmp_path / f"masks{run}")
        with pycolmap.Database.open(tmp_path / f"{run}.db") as db:
            ids = {im.name: im.image_id for im in db.read_all_images()}
            keypoints = [db.num_keypoints_for_image(i) for i in ids.values()]
            cameras = db.num_cameras()
        assert [ids[n] for n in names] == sorted(ids.values()) and len(ids) == 12, ids
        assert min(keypoints) > 50 and cameras == 1, (keypoints, cameras)


def test_the_mapper_takes_one_thread_where_a_side_has_a_cores_share(
    small_sets: dict[str, Path], tmp_path: Path
) -> None:
    """2 cores, two sides at once: one thread each (the same model from the same database every time);
    more cores than sides: COLMAP's own (every core); asked: as asked. A clean result cached under
    COLMAP's threads keeps its key (made before the setting: the key does not say it)."""
    from verifier.plan import mapper_threads, plan_profile, prepare_run
    from verifier.sfm import SfmSettings, mapper_options

    assert mapper_threads(0, workers=2, cores=2) == 1
    assert mapper_threads(0, workers=1, cores=1) == 1
    assert mapper_threads(0, workers=2, cores=4) == -1
    assert mapper_threads(0, workers=8, cores=16) == -1
    assert mapper_threads(-1, workers=2, cores=2) == -1
    assert mapper_threads(3, workers=8, cores=16) == 3
    assert mapper_options(SfmSettings(mapper_threads=1)).num_threads == 1
    assert mapper_options(SfmSettings()).num_threads == -1  # COLMAP's default, untouched

    def clean_side(threads: int) -> Any:
        options = VerifyOptions(mapper_threads=threads, visibility_images=0)
        run = prepare_run(small_sets["clean"], small_sets["poisoned"], tmp_path / str(threads), options)
        return plan_profile("default", run).sides["clean"]

    one, colmaps = clean_side(1), clean_side(-1)
    assert one.settings.mapper_threads == 1 and colmaps.settings.mapper_threads == -1
    assert '"mapper_threads": 1' in (one.reuse_key or "")
    assert "mapper_threads" not in (colmaps.reuse_key or "")
    assert (one.reuse_key or "").replace(', "mapper_threads": 1', "") == colmaps.reuse_key
