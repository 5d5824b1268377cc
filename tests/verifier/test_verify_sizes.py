"""A set of several stored sizes (phone photos stored turned, EXIF orientation 6) reaches COLMAP whole:
one camera per size on both sides, and what COLMAP still leaves out is named and not called protected
(black-box review 5, F1: "6/6 images" and "protected" for a dataset of 8, two of them turned).

Real pycolmap on small generated views; the turned photos are stored as a phone writes them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.blend import poison_array
from poisoner.ladder import default_spec
from verifier import verdict as vd
from verifier.plan import plan_profile, prepare_run
from verifier.sfm import SfmSettings
from verifier.synthetic import SyntheticOptions, render_scene
from verifier.verification import ProfileReport, VerificationReport, VerifyOptions, verify_folders

VIEWS = SyntheticOptions(num_views=8, width=320, height=240, focal=384.0)
TURNED = ("view_02.jpg", "view_05.jpg")  # stored turned, EXIF orientation 6 (as a phone writes them)
ORIENTATION = 0x0112


def save_as_phone(rgb: np.ndarray, path: Path, turned: bool) -> None:
    """A JPEG as a phone stores it: turned ones hold their pixels rotated, EXIF 6 says how to show them."""
    im, exif = Image.fromarray(rgb), Image.Exif()
    exif[ORIENTATION] = 1
    if turned:
        im, exif[ORIENTATION] = im.transpose(Image.Transpose.ROTATE_90), 6
    im.save(path, quality=92, exif=exif.tobytes())


@pytest.fixture(scope="module")
def phone_sets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """8 views (6 stored 320x240, 2 stored 240x320) and ppd's default mark on each, same stored size."""
    root = tmp_path_factory.mktemp("phone")
    render_scene(root / "renders", VIEWS)
    clean, pois = root / "clean", root / "poisoned"
    clean.mkdir()
    pois.mkdir()
    spec = default_spec()
    for png in sorted((root / "renders").glob("*.png")):
        name = png.with_suffix(".jpg").name
        save_as_phone(np.asarray(Image.open(png).convert("RGB")), clean / name, name in TURNED)
        with Image.open(clean / name) as stored:
            arr, _ = poison_array(np.asarray(stored.convert("RGB")), spec, image_key=name)
        exif = Image.Exif()
        exif[ORIENTATION] = 6 if name in TURNED else 1
        Image.fromarray(arr).save(pois / name, quality=92, exif=exif.tobytes())
    return {"clean": clean, "poisoned": pois, "root": root}


def test_every_photo_of_several_sizes_reaches_colmap_and_the_figures_are_over_all(
    phone_sets: dict[str, Path], tmp_path: Path
) -> None:
    options = VerifyOptions(timeout_s=300, visibility_images=0, keep_databases=True)
    report = verify_folders(phone_sets["clean"], phone_sets["poisoned"], tmp_path / "out", ["default"],
                            options)  # fmt: skip
    p = report.profiles["default"]
    # convert.py's single camera took 6 of them (the turned two have another size) and said nothing
    assert (p.clean["num_images"], p.poisoned["num_images"]) == (8, 8), p.reasons
    assert p.left_out == [] and p.clean["left_out"] == [] and p.poisoned["left_out"] == []
    assert any("/8 images" in r for r in p.reasons) and not any("/6 images" in r for r in p.reasons)
    assert report.sizes == {"320x240": 6, "240x320": 2}
    said = report.to_dict()
    assert said["left_out"] == [] and said["num_measured"] == 8 == said["num_images"]
    assert any("2 stored sizes (320x240: 6, 240x320: 2)" in line for line in said["summary"])
    # what each mapper read: one camera per stored size, every image under the one of its size. (How
    # many COLMAP registers is its own matter: under load, multi-threaded matching varies it.)
    import pycolmap

    for side in ("clean", "poisoned"):
        with pycolmap.Database.open(tmp_path / "out" / "default" / side / "database.db") as db:
            sizes = {c.camera_id: (c.width, c.height) for c in db.read_all_cameras()}
            images = {im.name: sizes[im.camera_id] for im in db.read_all_images()}
        assert sorted(sizes.values()) == [(240, 320), (320, 240)], side
        assert {n for n, size in images.items() if size == (240, 320)} == set(TURNED), side
        assert len(images) == 8, side


def test_a_set_of_one_size_keeps_the_single_camera_and_its_keys(
    phone_sets: dict[str, Path], tmp_path: Path
) -> None:
    upright = [n.name for n in sorted(phone_sets["clean"].iterdir()) if n.name not in TURNED]
    one = tmp_path / "one"
    one.mkdir()
    for name in upright:
        (one / name).write_bytes((phone_sets["clean"] / name).read_bytes())
    run = prepare_run(one, one, tmp_path / "out", VerifyOptions())
    assert not run.camera_per_size and run.sizes == {"320x240": 6}
    plan = plan_profile("default", run)
    settings = plan.sides["clean"].settings
    assert settings.camera_per_size is False and settings.single_camera is True
    # the keys a one-size set's caches are found under are the ones made before camera_per_size was
    assert "per-size" not in settings.feature_key()
    assert "camera_per_size" not in (plan.sides["clean"].reuse_key or "")
    assert settings.feature_key() == SfmSettings(cpu_sift=settings.cpu_sift).feature_key()
    mixed = prepare_run(phone_sets["clean"], phone_sets["poisoned"], tmp_path / "mixed", VerifyOptions())
    assert mixed.camera_per_size
    assert "per-size" in plan_profile("default", mixed).sides["clean"].settings.feature_key()


def profile(verdict: str, left_out: list[str]) -> ProfileReport:
    side = {"outcome": "ok", "num_images": 8 - len(left_out), "registered": 6, "left_out": left_out}
    return ProfileReport("default", vd.Verdict(verdict), [], side, side, None, left_out=left_out)


def test_photos_colmap_left_out_are_named_and_the_set_is_not_called_protected() -> None:
    left = ["view_02.jpg", "view_05.jpg"]
    report = VerificationReport("c", "p", "o", 8, {"default": profile("protected", left)})
    assert report.verdict == vd.Verdict.INCONCLUSIVE  # measured 6 of 8: "protected" would cover all 8
    said = report.to_dict()
    assert said["verdict"] == "inconclusive" and said["left_out"] == left and said["num_measured"] == 6
    named = "not measured: 2 of 8 photos (view_02.jpg, view_05.jpg)"
    assert any(line.startswith(named) for line in said["summary"])
    # a verdict that does not hold says so still; nothing left out: as before
    weak = VerificationReport("c", "p", "o", 8, {"default": profile("not_protected", left)})
    assert weak.verdict == vd.Verdict.NOT_PROTECTED
    whole = VerificationReport("c", "p", "o", 8, {"default": profile("protected", [])})
    assert whole.verdict == vd.Verdict.PROTECTED and whole.to_dict()["num_measured"] == 8


def test_a_photo_colmap_cannot_read_is_named_in_the_profile(
    phone_sets: dict[str, Path], tmp_path: Path
) -> None:
    """Whatever keeps a photo out of COLMAP's database (here a file it cannot decode) is read back from
    the database and named, with the figures over the others."""
    sets = {}
    for side in ("clean", "poisoned"):
        folder = sets[side] = tmp_path / side
        folder.mkdir()
        for f in sorted(phone_sets[side].iterdir()):
            if f.name not in TURNED:
                (folder / f.name).write_bytes(f.read_bytes())
        (folder / "broken.jpg").write_bytes((phone_sets[side] / "view_00.jpg").read_bytes()[:200])
    options = VerifyOptions(timeout_s=300, visibility_images=0)
    report = verify_folders(sets["clean"], sets["poisoned"], tmp_path / "out", ["default"], options)
    p = report.profiles["default"]
    assert p.left_out == ["broken.jpg"] and p.clean["num_images"] == 6, p.reasons
    assert any(r.startswith("not measured: 1 of 7 photos (broken.jpg)") for r in p.reasons)
    assert report.to_dict()["left_out"] == ["broken.jpg"] and report.verdict != vd.Verdict.PROTECTED
