"""Camera-pose comparison: pure numpy, no pycolmap (the parent process imports this).

A pose is world-to-camera in the OpenCV/COLMAP convention: x_cam = R @ x_world + t, so the
camera centre is C = -R^T t. Poses are compared by image name. A camera that the estimate
did not register counts as a failure (error = inf) against every reference camera.

Metrics, all scale-free:
- relative rotation error over image pairs (needs no alignment),
- pair pose error = max(relative rotation error, angle between relative translation directions),
  and its AUC@5/10/20 (the usual SfM benchmark measure),
- per-camera rotation error and camera-centre error after a robust similarity alignment of the
  estimated centres onto the reference centres (Umeyama inside RANSAC, then refit on inliers),
  and the fraction of cameras within 5/10/20 degrees.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poisoner.errors import ExitStatus, PpdError

Pose = tuple[np.ndarray, np.ndarray]  # (R 3x3 world-to-camera, t 3)
Poses = Mapping[str, Pose]

THRESHOLDS_DEG = (5.0, 10.0, 20.0)

# OpenGL/Blender camera (x right, y up, looks down -z) -> OpenCV (y down, looks down +z).
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


# ---- basic geometry --------------------------------------------------------------------------
def rotation_angle_deg(rot: np.ndarray) -> float:
    """Angle of a rotation matrix in degrees; atan2(sin, cos) stays exact near 0 (arccos does not)."""
    cos = (np.trace(rot) - 1.0) / 2.0
    axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    sin = np.linalg.norm(axis) / 2.0
    return float(np.degrees(np.arctan2(sin, cos)))


def rotation_error_deg(r_est: np.ndarray, r_ref: np.ndarray) -> float:
    return rotation_angle_deg(r_est @ r_ref.T)


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-12 or nb < 1e-12:
        return 180.0
    return float(np.degrees(np.arccos(np.clip(a @ b / (na * nb), -1.0, 1.0))))


def camera_centre(pose: Pose) -> np.ndarray:
    rot, trans = pose
    return -rot.T @ trans


def relative_pose(pose_i: Pose, pose_j: Pose) -> Pose:
    """cam_j from cam_i."""
    ri, ti = pose_i
    rj, tj = pose_j
    r = rj @ ri.T
    return r, tj - r @ ti


# ---- similarity alignment ----------------------------------------------------------------------
@dataclass(frozen=True)
class Similarity:
    """x_ref = scale * rotation @ x_est + translation."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        return self.scale * points @ self.rotation.T + self.translation

    def transform_pose(self, pose: Pose) -> Pose:
        """The same camera expressed in the reference frame."""
        rot, _ = pose
        r_new = rot @ self.rotation.T
        centre = self.apply(camera_centre(pose)[None])[0]
        return r_new, -r_new @ centre


def umeyama(src: np.ndarray, dst: np.ndarray) -> Similarity:
    """Least-squares similarity dst ~ s R src + t (Umeyama 1991). src, dst: N x 3, N >= 3."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    rot = u @ sign @ vt
    var_s = (xs**2).sum() / len(src)
    scale = float(np.trace(np.diag(d) @ sign) / var_s) if var_s > 1e-15 else 1.0
    return Similarity(scale, rot, mu_d - scale * rot @ mu_s)


def scene_scale(points: np.ndarray) -> float:
    """Median distance of points to their centroid: the length unit of a scale-free error."""
    if len(points) == 0:
        return 1.0
    s = float(np.median(np.linalg.norm(points - points.mean(0), axis=1)))
    return s if s > 1e-12 else 1.0


def robust_similarity(
    src: np.ndarray,
    dst: np.ndarray,
    inlier_fraction_of_scale: float = 0.1,
    iterations: int = 500,
    seed: int = 0,
) -> tuple[Similarity | None, np.ndarray]:
    """RANSAC over minimal 3-point Umeyama fits, then a refit on the inliers (LO step).

    Returns (similarity or None when fewer than 3 points, inlier mask). The inlier threshold is
    a fraction of the reference scene scale so the test is unit-free.
    """
    n = len(src)
    if n < 3:
        return None, np.zeros(n, bool)
    threshold = inlier_fraction_of_scale * scene_scale(dst)
    rng = np.random.default_rng(seed)
    best_mask = np.zeros(n, bool)
    best_err = np.inf
    candidates = [umeyama(src, dst)]  # the all-points fit is a candidate too
    for _ in range(iterations):
        idx = rng.choice(n, 3, replace=False)
        candidates.append(umeyama(src[idx], dst[idx]))
    for sim in candidates:
        if not np.all(np.isfinite(sim.rotation)) or sim.scale <= 0:
            continue
        err = np.linalg.norm(sim.apply(src) - dst, axis=1)
        mask = err < threshold
        total = float(np.minimum(err, threshold).sum())  # MSAC score
        if mask.sum() > best_mask.sum() or (mask.sum() == best_mask.sum() and total < best_err):
            best_mask, best_err = mask, total
    if best_mask.sum() >= 3:
        best = umeyama(src[best_mask], dst[best_mask])
        err = np.linalg.norm(best.apply(src) - dst, axis=1)
        refit_mask = err < threshold
        if refit_mask.sum() >= best_mask.sum():
            best_mask = refit_mask
        return best, best_mask
    return umeyama(src, dst), best_mask


# ---- metrics -----------------------------------------------------------------------------------
def auc(errors: Sequence[float], threshold: float) -> float:
    """Area under the recall-vs-error curve up to threshold, normalised to [0, 1].

    inf errors (failures) count in the denominator and never reach the curve. Matches the
    definition used by the SfM benchmarks (e.g. IMC, VGGSfM): integral of recall(e) de / threshold.
    """
    if len(errors) == 0:
        return 0.0
    errs = np.sort(np.asarray(errors, float))
    n = len(errs)
    recall = np.arange(1, n + 1) / n
    errs_c = np.concatenate([[0.0], errs])
    recall_c = np.concatenate([[0.0], recall])
    last = int(np.searchsorted(errs_c, threshold, side="right"))
    x = np.concatenate([errs_c[:last], [threshold]])
    y = np.concatenate([recall_c[:last], [recall_c[last - 1]]])
    # step function: recall stays at y[k] from x[k] to x[k+1]
    return float(np.sum(np.diff(x) * y[:-1]) / threshold)


def pair_errors(est: Poses, ref: Poses) -> tuple[list[float], list[float]]:
    """(relative rotation errors, pair pose errors) over all pairs of reference cameras."""
    names = sorted(ref)
    rot_errs: list[float] = []
    pose_errs: list[float] = []
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            i, j = names[a], names[b]
            if i not in est or j not in est:
                rot_errs.append(math.inf)
                pose_errs.append(math.inf)
                continue
            r_e, t_e = relative_pose(est[i], est[j])
            r_r, t_r = relative_pose(ref[i], ref[j])
            rot = rotation_error_deg(r_e, r_r)
            trans = angle_between_deg(t_e, t_r)
            rot_errs.append(rot)
            pose_errs.append(max(rot, trans))
    return rot_errs, pose_errs


@dataclass(frozen=True)
class AlignedErrors:
    rotation_deg: dict[str, float]
    centre: dict[str, float]  # in units of the reference scene scale
    inliers: int


def aligned_errors(est: Poses, ref: Poses, seed: int = 0) -> AlignedErrors:
    """Per reference camera: rotation and centre error after a robust similarity alignment."""
    common = sorted(set(est) & set(ref))
    rot_err = {n: math.inf for n in ref}
    cen_err = {n: math.inf for n in ref}
    if len(common) < 3:
        return AlignedErrors(rot_err, cen_err, 0)
    src = np.stack([camera_centre(est[n]) for n in common])
    dst = np.stack([camera_centre(ref[n]) for n in common])
    sim, mask = robust_similarity(src, dst, seed=seed)
    assert sim is not None
    unit = scene_scale(dst)
    for n in common:
        r_al, _ = sim.transform_pose(est[n])
        rot_err[n] = rotation_error_deg(r_al, ref[n][0])
        c_al = sim.apply(camera_centre(est[n])[None])[0]
        cen_err[n] = float(np.linalg.norm(c_al - camera_centre(ref[n])) / unit)
    return AlignedErrors(rot_err, cen_err, int(mask.sum()))


def _finite_median(values: Sequence[float]) -> float | None:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.median(finite)) if finite else None


def compare_poses(est: Poses, ref: Poses, seed: int = 0) -> dict[str, float | int | None]:
    """All pose metrics of est against ref, as a flat JSON-friendly dict (None = undefined).

    Only cameras in ref are scored; cameras in ref missing from est are failures (inf).
    """
    n_ref = len(ref)
    rot_pairs, pose_pairs = pair_errors(est, ref)
    aligned = aligned_errors(est, ref, seed=seed)
    rot_cam = list(aligned.rotation_deg.values())
    out: dict[str, float | int | None] = {
        "cameras_compared": n_ref,
        "cameras_registered": sum(1 for n in ref if n in est),
        "alignment_inliers": aligned.inliers,
        "median_rotation_error_deg": _finite_median(rot_cam),
        "median_centre_error": _finite_median(list(aligned.centre.values())),
        "median_relative_rotation_error_deg": _finite_median(rot_pairs),
    }
    for t in THRESHOLDS_DEG:
        k = int(t)
        out[f"frac_within_{k}deg"] = (sum(1 for e in rot_cam if e <= t) / n_ref) if n_ref else None
        out[f"rra_within_{k}deg"] = (
            (sum(1 for e in rot_pairs if e <= t) / len(rot_pairs)) if rot_pairs else None
        )
        out[f"auc_{k}"] = auc(pose_pairs, t) if pose_pairs else None
    return out


# ---- ground truth readers ---------------------------------------------------------------------
class GroundTruthError(PpdError, ValueError):
    """A ground-truth file that cannot be read."""

    exit_status = ExitStatus.USAGE


def _pose_from_c2w(c2w: np.ndarray) -> Pose:
    rot_c2w = c2w[:3, :3]
    centre = c2w[:3, 3]
    rot = rot_c2w.T
    return rot, -rot @ centre


def read_nerf_transforms(path: Path, suffix: str = ".png") -> dict[str, Pose]:
    """NeRF-Synthetic transforms_*.json (OpenGL camera-to-world) -> OpenCV world-to-camera by name."""
    data = json.loads(Path(path).read_text())
    poses: dict[str, Pose] = {}
    for frame in data["frames"]:
        c2w = np.asarray(frame["transform_matrix"], float) @ GL_TO_CV
        name = Path(frame["file_path"]).name
        if not Path(name).suffix:
            name += suffix
        poses[name] = _pose_from_c2w(c2w)
    return poses


def nerf_intrinsics(path: Path, width: int) -> float:
    """Focal length in pixels from camera_angle_x (horizontal field of view)."""
    data = json.loads(Path(path).read_text())
    return width / 2 / math.tan(float(data["camera_angle_x"]) / 2)


def read_strecha_cameras(directory: Path) -> dict[str, Pose]:
    """Strecha gt_dense_cameras/NAME.camera files: K(9) dist(3) R(9, camera-to-world) C(3) w h."""
    poses: dict[str, Pose] = {}
    for f in sorted(Path(directory).glob("*.camera")):
        vals = np.array(f.read_text().split(), float)
        if len(vals) < 24:
            raise GroundTruthError(f"{f}: expected at least 24 numbers, got {len(vals)}")
        rot_c2w = vals[12:21].reshape(3, 3)
        centre = vals[21:24]
        rot = rot_c2w.T
        poses[f.name[: -len(".camera")]] = (rot, -rot @ centre)
    if not poses:
        raise GroundTruthError(f"{directory}: no *.camera files")
    return poses


def read_synthetic_cameras(path: Path) -> dict[str, Pose]:
    data = json.loads(Path(path).read_text())
    return {n: (np.asarray(c["R"], float), np.asarray(c["t"], float)) for n, c in data["cameras"].items()}


def load_ground_truth(path: Path) -> dict[str, Pose]:
    """Ground truth by format: a directory of Strecha *.camera files, NeRF transforms json, or
    ppd's synthetic cameras.json."""
    path = Path(path)
    if path.is_dir():
        return read_strecha_cameras(path)
    if not path.is_file():
        raise GroundTruthError(f"ground truth not found: {path}")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise GroundTruthError(f"{path}: not JSON ({exc})") from exc
    if "frames" in data:
        return read_nerf_transforms(path)
    if data.get("format") == "ppd-synthetic-v1":
        return read_synthetic_cameras(path)
    raise GroundTruthError(f"{path}: unknown ground-truth format")


def poses_to_json(poses: Poses) -> dict[str, dict[str, list]]:
    return {n: {"R": np.asarray(r).tolist(), "t": np.asarray(t).tolist()} for n, (r, t) in poses.items()}


def poses_from_json(data: Mapping[str, Mapping[str, list]]) -> dict[str, Pose]:
    return {n: (np.asarray(v["R"], float), np.asarray(v["t"], float)) for n, v in data.items()}
