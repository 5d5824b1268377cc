"""Structure-from-Motion with pycolmap 4.2.1, run in a child process, and its parent-side launcher.

The parent (daemon, CLI, tests) calls `run_sfm_job(job, ...)`: it starts `python -m verifier.child`
at low priority, sends the job (`SfmJob`) as JSON on stdin and reads the result (`SfmOk` or
`SfmFailed`, tagged by `outcome`) back from a JSON file; msgspec types both directions. pycolmap is
imported only by `execute_job`, which runs in the child. A child killed by a signal (pycolmap 4.2.1
segfaults on some poisoned sets) becomes an outcome, never a crash of the caller.

Features and raw matches are computed once per image set into a cache database; each profile
copies it and runs only its own geometric verification and mapping (default and hardened differ
there and nowhere else), which halves the work of verifying two profiles.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import msgspec

from poisoner.media import is_sfm_readable
from verifier.childenv import child_env
from verifier.supervise import run_child

log = logging.getLogger(__name__)

# Serialises verification runs inside one process: SfM is CPU-heavy and the machine is shared.
_RUN_LOCK = threading.Lock()


class SfmSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """What one SfM run does. Defaults are the official 3DGS convert.py settings."""

    camera_model: str = "OPENCV"  # convert.py: --ImageReader.camera_model OPENCV
    single_camera: bool = True  # convert.py: --ImageReader.single_camera 1
    camera_params: str | None = None  # known intrinsics ("fx,fy,cx,cy,k1,k2,p1,p2"), fixed in BA
    matching: str = "exhaustive"  # convert.py: exhaustive_matcher; "sequential" for video frames
    sequential_overlap: int = 10
    max_image_size: int = -1  # COLMAP picks its extractor default (3200 px for SIFT)
    filter_stationary_matches: bool = False  # hardened: drop matches that do not move between views
    ignore_watermarks: bool = False  # hardened: mapper ignores pairs flagged as watermark
    random_seed: int = 0
    # masked (issue 14): the attacker masks the four corner regions, each this fraction of the
    # width by this fraction of the height, so SIFT finds no features there. 0: no mask.
    mask_corners: float = 0.0

    def feature_key(self) -> str:
        """Settings that decide features + raw matches (the cache is valid across the rest)."""
        key = (
            f"{self.camera_model}-{int(self.single_camera)}-{self.camera_params}-{self.matching}-"
            f"{self.sequential_overlap}-{self.max_image_size}"
        )
        # masks change the features; unmasked keys stay as they were (existing caches stay valid)
        return key + (f"-mask{self.mask_corners:g}" if self.mask_corners > 0 else "")


# Issue 14: what an attacker who has read the paper does about a corner mark.
MASKED_CORNER_FRACTION = 0.2


def profile_sfm_settings(profile: str, base: SfmSettings) -> SfmSettings:
    """The SfM settings of a verification profile, from the default pipeline's settings.

    default / published: base (published differs in its images, not its settings); hardened:
    COLMAP's defences against fixed marks; masked: the four corner regions (20% x 20%) masked
    out of feature extraction, as an attacker who expects a corner watermark would.
    """
    if profile in ("default", "published"):
        return base
    if profile == "hardened":
        return msgspec.structs.replace(base, filter_stationary_matches=True, ignore_watermarks=True)
    if profile == "masked":
        return msgspec.structs.replace(base, mask_corners=MASKED_CORNER_FRACTION)
    raise ValueError(f"unknown profile {profile!r}")


def corner_mask(width: int, height: int, fraction: float) -> Any:
    """uint8 H x W mask for COLMAP: 0 in the four corner regions (no features there), 255 elsewhere."""
    import numpy as np

    mask = np.full((height, width), 255, dtype=np.uint8)
    rw, rh = int(round(fraction * width)), int(round(fraction * height))
    if rw > 0 and rh > 0:
        for ys in (slice(0, rh), slice(height - rh, height)):
            for xs in (slice(0, rw), slice(width - rw, width)):
                mask[ys, xs] = 0
    return mask


def write_corner_masks(image_dir: Path, names: list[str], mask_dir: Path, fraction: float) -> None:
    """One mask per image, named as COLMAP expects (`<image name>.png`), at the image's size."""
    from PIL import Image

    mask_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        with Image.open(image_dir / name) as im:
            width, height = im.size
        Image.fromarray(corner_mask(width, height, fraction)).save(mask_dir / f"{name}.png")


class SfmJob(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """What the SfM child runs (sent as JSON on its stdin)."""

    image_dir: str
    cache_db: str  # features + raw matches; created when missing
    model_dir: str  # the largest model is written here (cameras.bin, images.bin, points3D.bin)
    settings: SfmSettings = msgspec.field(default_factory=SfmSettings)
    result_path: str = ""


class CameraPose(msgspec.Struct, frozen=True):
    R: list[list[float]]  # cam_from_world rotation, 3 x 3
    t: list[float]  # cam_from_world translation


class CameraModel(msgspec.Struct, frozen=True):
    model: str
    params: list[float]


class SfmOk(msgspec.Struct, tag_field="outcome", tag="ok"):
    """The child's result when COLMAP ran: the largest model's poses and counts of all (the
    defaults: nothing reconstructed)."""

    num_images: int = 0
    verified_pairs: int = 0
    num_models: int = 0
    model_sizes: list[int] = []
    registered: int = 0
    poses: dict[str, CameraPose] = {}
    mean_reprojection_error: float | None = None
    num_points3D: int = 0  # noqa: N815 - the JSON key verification reports use
    camera: CameraModel | None = None
    timings: dict[str, float] = {}


class SfmFailed(msgspec.Struct, tag_field="outcome", tag="failed"):
    """The child's result when the job could not run (bad input, a pycolmap error)."""

    error: str


SfmResult = SfmOk | SfmFailed


class SfmCancelled(RuntimeError):
    """The run was cancelled by its caller."""


# ---- parent side ------------------------------------------------------------------------------
def _ionice_prefix() -> list[str]:
    """`ionice -c 3` (idle I/O class) when the tool exists; the child falls back to the syscall."""
    tool = shutil.which("ionice")
    return [tool, "-c", "3"] if tool else []


def run_sfm_job(
    job: SfmJob,
    timeout_s: float | None = None,
    cancel: threading.Event | None = None,
    python: str | None = None,
) -> dict[str, Any]:
    """Run one SfM job in a child process; always returns a result dict with an `outcome`:

    `ok` | `failed` (the child reported an error) | `sfm_crashed` (killed by a signal) |
    `timeout` | `cancelled`.
    """
    with _RUN_LOCK:
        return _run_locked(job, timeout_s, cancel, python)


def _run_locked(
    job: SfmJob, timeout_s: float | None, cancel: threading.Event | None, python: str | None
) -> dict[str, Any]:
    Path(job.model_dir).mkdir(parents=True, exist_ok=True)
    fd, result_path = tempfile.mkstemp(prefix=".ppd-tmp-sfm-", suffix=".json", dir=job.model_dir)
    os.close(fd)
    os.unlink(result_path)
    job = msgspec.structs.replace(job, result_path=result_path)
    cmd = [*_ionice_prefix(), python or sys.executable, "-m", "verifier.child"]
    env = child_env()  # the child imports this same copy of ppd (installed or a source tree)
    started = time.time()
    stderr_path = Path(job.model_dir) / "sfm.log"
    ended = run_child(
        cmd,
        log_path=stderr_path,
        stdin_data=msgspec.json.format(msgspec.json.encode(job), indent=0),  # json.dumps' spacing: greppable
        timeout_s=timeout_s,
        cancel=cancel,
        env=env,
        discard_stdout=True,
        on_start=lambda pid: log.info("sfm child started", extra={"pid": pid, "image_dir": job.image_dir}),
    )
    elapsed = time.time() - started
    base: dict[str, Any] = {"elapsed_s": elapsed, "returncode": ended.returncode, "log": str(stderr_path)}
    if ended.kind in ("timeout", "cancelled"):
        return {**base, "outcome": ended.kind, "error": f"{ended.kind} after {elapsed:.0f} s"}
    if ended.kind == "crashed":
        name = ended.signal_name
        return {**base, "outcome": "sfm_crashed", "signal": name, "error": f"SfM child killed by {name}"}
    try:
        result = msgspec.to_builtins(msgspec.json.decode(Path(result_path).read_bytes(), type=SfmResult))
    except OSError:
        why = f"child exited {ended.returncode} without a result: {_tail(stderr_path)}"
        return {**base, "outcome": "failed", "error": why}
    except msgspec.DecodeError as exc:  # a child of another version, or a broken write
        return {**base, "outcome": "failed", "error": f"child wrote an invalid result: {exc}"}
    finally:
        with contextlib.suppress(OSError):
            os.unlink(result_path)
    return {**base, **result}


def _tail(path: Path, n: int = 300) -> str:
    try:
        text = path.read_text(errors="replace").strip()
    except OSError:
        return ""
    return text[-n:].replace("\n", " | ")


# ---- child side (imports pycolmap) ------------------------------------------------------------
def list_images(image_dir: Path) -> list[str]:
    return sorted(p.name for p in Path(image_dir).iterdir() if is_sfm_readable(p))


def build_cache_db(image_dir: Path, cache_db: Path, settings: SfmSettings) -> None:
    """Extract SIFT features and raw (unverified) matches into cache_db, atomically (a killed run
    leaves no half-built cache under the real name)."""
    from poisoner.atomic import atomic_output

    mask_dir = cache_db.with_name(f".ppd-tmp-masks-{cache_db.stem}")
    try:
        with atomic_output(cache_db) as tmp:
            extract_features(image_dir, tmp, settings, mask_dir)
            match_raw(tmp, settings)
    finally:
        shutil.rmtree(mask_dir, ignore_errors=True)


def extract_features(image_dir: Path, database: Path, settings: SfmSettings, mask_dir: Path) -> None:
    """SIFT features of every image into database (corner masks written to mask_dir when asked)."""
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = settings.camera_model
    if settings.camera_params:
        reader.camera_params = settings.camera_params
    if settings.mask_corners > 0:
        write_corner_masks(image_dir, list_images(image_dir), mask_dir, settings.mask_corners)
        reader.mask_path = str(mask_dir)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = settings.max_image_size
    mode = pycolmap.CameraMode.SINGLE if settings.single_camera else pycolmap.CameraMode.AUTO
    pycolmap.extract_features(
        database,
        image_dir,
        image_names=list_images(image_dir),
        camera_mode=mode,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )


def match_raw(database: Path, settings: SfmSettings) -> None:
    """Raw matches (no geometric verification: each profile verifies with its own options)."""
    import pycolmap

    matching = pycolmap.FeatureMatchingOptions()
    matching.skip_geometric_verification = True
    if settings.matching == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = settings.sequential_overlap
        pycolmap.match_sequential(
            database, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu
        )
    elif settings.matching == "exhaustive":
        pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
    else:
        raise ValueError(f"unknown matching {settings.matching!r}")


def execute_job(job: SfmJob) -> SfmResult:
    """Run the job in this process (the child): features and raw matches (cached), then this
    profile's geometric verification and mapping."""
    import pycolmap

    settings = job.settings
    pycolmap.set_random_seed(settings.random_seed)
    image_dir, cache_db, model_dir = Path(job.image_dir), Path(job.cache_db), Path(job.model_dir)
    if not list_images(image_dir):  # COLMAP would only say "no models"; say why
        return SfmFailed(error=f"no images COLMAP can read in {image_dir}")
    timings: dict[str, float] = {}
    t0 = time.time()
    if not cache_db.exists():
        cache_db.parent.mkdir(parents=True, exist_ok=True)
        build_cache_db(image_dir, cache_db, settings)
        timings["features_and_matches_s"] = time.time() - t0
    work_db = model_dir / "work.db"
    shutil.copyfile(cache_db, work_db)
    t1 = time.time()
    num_images, verified_pairs = verify_pairs(work_db, settings)
    timings["verification_s"] = time.time() - t1
    t2 = time.time()
    with tempfile.TemporaryDirectory(prefix=".ppd-tmp-map-", dir=model_dir) as tmp:
        models = pycolmap.incremental_mapping(work_db, image_dir, tmp, options=mapper_options(settings))
        timings["mapping_s"] = time.time() - t2
        work_db.unlink()
        result = summarise_models(models, num_images, verified_pairs)
        if models:
            largest = max(models.values(), key=lambda r: r.num_reg_images())
            largest.write(model_dir)
    result.timings = timings
    return result


def verify_pairs(work_db: Path, settings: SfmSettings) -> tuple[int, int]:
    """This profile's geometric verification of the raw matches; (images, verified pairs)."""
    import pycolmap

    two_view = pycolmap.TwoViewGeometryOptions()
    two_view.filter_stationary_matches = settings.filter_stationary_matches
    two_view.ransac.random_seed = settings.random_seed
    pycolmap.geometric_verification(work_db, two_view_geometry_options=two_view)
    with pycolmap.Database.open(work_db) as db:
        return db.num_images(), db.num_verified_image_pairs()


def mapper_options(settings: SfmSettings) -> Any:
    """COLMAP's incremental mapper options for these settings."""
    import pycolmap

    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.ignore_watermarks = settings.ignore_watermarks
    mapper.random_seed = settings.random_seed
    if settings.camera_params:  # known intrinsics: keep them fixed, as a careful attacker would
        mapper.ba_refine_focal_length = False
        mapper.ba_refine_principal_point = False
        mapper.ba_refine_extra_params = False
    return mapper


def summarise_models(models: dict[int, Any], num_images: int, verified_pairs: int) -> SfmOk:
    """Poses of the largest model and counts of all."""
    sizes = sorted((r.num_reg_images() for r in models.values()), reverse=True)
    if not models:
        return SfmOk(num_images=num_images, verified_pairs=verified_pairs)
    largest = max(models.values(), key=lambda r: r.num_reg_images())
    poses = {}
    for image in largest.images.values():
        if not image.has_pose:
            continue
        cam_from_world = image.cam_from_world()
        poses[image.name] = CameraPose(
            R=cam_from_world.rotation.matrix().tolist(), t=list(map(float, cam_from_world.translation))
        )
    cams = list(largest.cameras.values())
    camera = CameraModel(str(cams[0].model.name), list(map(float, cams[0].params))) if cams else None
    return SfmOk(
        num_images=num_images,
        verified_pairs=verified_pairs,
        num_models=len(models),
        model_sizes=sizes,
        registered=len(poses),
        poses=poses,
        mean_reprojection_error=float(largest.compute_mean_reprojection_error()),
        num_points3D=int(largest.num_points3D()),
        camera=camera,
    )
