"""Pose metrics on constructed transforms with exact expected values (no SfM)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from verifier import poses as pm


def rot_axis(axis: str, deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def ring(n: int = 8, radius: float = 4.0) -> dict[str, pm.Pose]:
    """n cameras on a tilted ring looking roughly at the origin (world-to-camera)."""
    out = {}
    for i in range(n):
        az = 360.0 * i / n
        r = rot_axis("x", 20 + 5 * (i % 2)) @ rot_axis("y", az)
        centre = np.array(
            [radius * math.sin(math.radians(az)), 0.3 * (i % 3), radius * math.cos(math.radians(az))]
        )
        out[f"img_{i}.png"] = (r, -r @ centre)
    return out


def transform_world(poses: dict[str, pm.Pose], scale: float, rot: np.ndarray, trans: np.ndarray):
    """The same cameras in a world frame x' = scale * rot @ x + trans (what another SfM run gives)."""
    out = {}
    for n, (r, _t) in poses.items():
        c = pm.camera_centre(poses[n])
        r_new = r @ rot.T
        c_new = scale * rot @ c + trans
        out[n] = (r_new, -r_new @ c_new)
    return out


def test_rotation_angle_exact() -> None:
    assert pm.rotation_angle_deg(rot_axis("z", 30)) == pytest.approx(30.0, abs=1e-9)
    assert pm.rotation_angle_deg(np.eye(3)) == 0.0
    assert pm.rotation_angle_deg(rot_axis("y", 180)) == pytest.approx(180.0, abs=1e-6)
    assert pm.rotation_error_deg(rot_axis("x", 50), rot_axis("x", 20)) == pytest.approx(30.0, abs=1e-9)


def test_identical_poses_are_perfect() -> None:
    ref = ring()
    m = pm.compare_poses(ref, ref)
    assert m["cameras_registered"] == 8
    assert m["frac_within_5deg"] == 1.0
    assert m["auc_5"] == pytest.approx(1.0)
    assert m["median_rotation_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert m["median_centre_error"] == pytest.approx(0.0, abs=1e-9)


def test_similarity_transformed_copy_aligns_exactly() -> None:
    ref = ring()
    est = transform_world(ref, 3.7, rot_axis("z", 40) @ rot_axis("x", -65), np.array([5.0, -2.0, 11.0]))
    m = pm.compare_poses(est, ref)
    assert m["frac_within_5deg"] == 1.0
    assert m["median_rotation_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert m["median_centre_error"] == pytest.approx(0.0, abs=1e-7)
    assert m["median_relative_rotation_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert m["alignment_inliers"] == 8


def test_one_camera_rotated_in_place_has_exact_error() -> None:
    ref = ring()
    est = dict(ref)
    r, _t = ref["img_3.png"]
    c = pm.camera_centre(ref["img_3.png"])
    r_bad = rot_axis("z", 12.0) @ r  # turn the camera 12 deg about its optical axis, same centre
    est["img_3.png"] = (r_bad, -r_bad @ c)
    aligned = pm.aligned_errors(est, ref)
    assert aligned.rotation_deg["img_3.png"] == pytest.approx(12.0, abs=1e-6)
    assert aligned.rotation_deg["img_0.png"] == pytest.approx(0.0, abs=1e-6)
    m = pm.compare_poses(est, ref)
    assert m["frac_within_5deg"] == pytest.approx(7 / 8)
    assert m["frac_within_10deg"] == pytest.approx(7 / 8)
    assert m["frac_within_20deg"] == 1.0
    # 7 of the 28 pairs involve camera 3; their relative rotation error is exactly 12 deg
    rot_pairs, _ = pm.pair_errors(est, ref)
    assert sorted(rot_pairs)[-7:] == pytest.approx([12.0] * 7, abs=1e-6)
    assert m["rra_within_10deg"] == pytest.approx(21 / 28)


def test_unregistered_camera_is_a_failure() -> None:
    ref = ring()
    est = {n: p for n, p in ref.items() if n != "img_5.png"}
    m = pm.compare_poses(est, ref)
    assert m["cameras_registered"] == 7
    assert m["frac_within_20deg"] == pytest.approx(7 / 8)
    assert pm.aligned_errors(est, ref).rotation_deg["img_5.png"] == math.inf
    assert m["rra_within_20deg"] == pytest.approx(21 / 28)  # the 7 pairs with camera 5 fail


def test_robust_alignment_ignores_one_wild_camera() -> None:
    ref = ring(10)
    est = transform_world(ref, 0.5, rot_axis("y", 33), np.array([1.0, 2.0, 3.0]))
    r, _ = est["img_2.png"]
    wild_centre = np.array([100.0, -50.0, 80.0])
    est["img_2.png"] = (r, -r @ wild_centre)
    aligned = pm.aligned_errors(est, ref)
    assert aligned.inliers == 9
    assert aligned.rotation_deg["img_7.png"] == pytest.approx(0.0, abs=1e-6)
    assert aligned.centre["img_7.png"] == pytest.approx(0.0, abs=1e-7)
    assert aligned.centre["img_2.png"] > 1.0


def test_too_few_common_cameras_cannot_align() -> None:
    ref = ring()
    est = {n: ref[n] for n in ("img_0.png", "img_1.png")}
    m = pm.compare_poses(est, ref)
    assert m["frac_within_20deg"] == 0.0
    assert m["alignment_inliers"] == 0


def test_auc_exact_values() -> None:
    assert pm.auc([0.0, math.inf], 5) == pytest.approx(0.5)
    assert pm.auc([2.5], 5) == pytest.approx(0.5)
    assert pm.auc([1.0, 3.0], 5) == pytest.approx(0.6)
    assert pm.auc([10.0], 5) == 0.0
    assert pm.auc([0.0, 0.0], 20) == pytest.approx(1.0)


def test_umeyama_recovers_similarity() -> None:
    rng = np.random.default_rng(1)
    src = rng.normal(size=(20, 3))
    rot = rot_axis("z", 70) @ rot_axis("y", -20)
    dst = 2.5 * src @ rot.T + np.array([1.0, -1.0, 4.0])
    sim = pm.umeyama(src, dst)
    assert sim.scale == pytest.approx(2.5)
    assert np.allclose(sim.rotation, rot)
    assert np.allclose(sim.apply(src), dst)


def test_nerf_transforms_convention(tmp_path: Path) -> None:
    # an OpenGL camera at (0, -4, 0) looking at the origin along +y, z up
    c2w = np.array([[1, 0, 0, 0], [0, 0, -1, -4], [0, 1, 0, 0], [0, 0, 0, 1]], float)
    path = tmp_path / "transforms_train.json"
    frame = {"file_path": "./train/r_0", "transform_matrix": c2w.tolist()}
    path.write_text(json.dumps({"camera_angle_x": 0.69, "frames": [frame]}))
    poses = pm.load_ground_truth(path)
    r, t = poses["r_0.png"]
    assert np.allclose(pm.camera_centre((r, t)), [0, -4, 0])
    assert np.allclose(r[2], [0, 1, 0])  # OpenCV optical axis (+z) points at the origin
    assert np.allclose(r @ np.zeros(3) + t, [0, 0, 4])  # the origin is 4 units in front
    assert pm.nerf_intrinsics(path, 800) == pytest.approx(400 / math.tan(0.345))


def test_strecha_camera_convention(tmp_path: Path) -> None:
    r_c2w = rot_axis("y", 30)
    centre = np.array([1.0, 2.0, -3.0])
    nums = [1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, *r_c2w.ravel(), *centre, 3072, 2048]
    (tmp_path / "0000.jpg.camera").write_text(" ".join(map(str, nums)))
    r, t = pm.load_ground_truth(tmp_path)["0000.jpg"]
    assert np.allclose(r, r_c2w.T)
    assert np.allclose(pm.camera_centre((r, t)), centre)


def test_bad_ground_truth_is_a_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "x.json"
    bad.write_text("{}")
    with pytest.raises(pm.GroundTruthError, match="unknown ground-truth format"):
        pm.load_ground_truth(bad)
    with pytest.raises(pm.GroundTruthError, match="not found"):
        pm.load_ground_truth(tmp_path / "missing.json")


def test_shared_ground_truth_files_read(shared_dir: Path) -> None:
    lego = pm.load_ground_truth(shared_dir / "datasets" / "nerf_synthetic_lego" / "transforms_train.json")
    assert len(lego) == 100
    radii = [np.linalg.norm(pm.camera_centre(p)) for p in lego.values()]
    assert min(radii) > 3.5 and max(radii) < 4.5  # NeRF-Synthetic cameras sit on a ~4.03 sphere
    # every lego camera looks at the object near the origin: it lies in front of the camera
    assert all((r @ np.zeros(3) + t)[2] > 0 for r, t in lego.values())
    fountain = pm.load_ground_truth(shared_dir / "datasets" / "fountain_P11" / "gt_dense_cameras")
    assert sorted(fountain) == [f"{i:04d}.jpg" for i in range(11)]
    assert all(np.allclose(r @ r.T, np.eye(3), atol=1e-6) for r, _ in fountain.values())
