"""Structure-from-Motion with pycolmap 4.2.1, run in a child process, and its parent-side launcher.

The parent (daemon, CLI, tests) calls `run_sfm_job(job, ...)`: it starts `python -m verifier.child`
at low priority, sends the job (`SfmJob`) as JSON on stdin and reads the result (`SfmOk` or
`SfmFailed`, tagged by `outcome`) back from a JSON file; msgspec types both directions. pycolmap is
imported only by `execute_job`, which runs in the child. A child killed by a signal (pycolmap 4.2.1
segfaults on some poisoned sets) becomes an outcome, never a crash of the caller.

Work shared across profiles (issue 30): features and raw matches are computed once per image set
into a cache database (a features-only child, `SfmJob.stop_after="features"`); each profile copies
it and runs only its own geometric verification and mapping (default and hardened differ there and
nowhere else). Profiles whose two-view options are the same (default and global) also share the
verified database (`SfmJob.verified_db`). The masked profile's features are the unmasked features
filtered by position (`SfmJob.features_from`): COLMAP masks keypoints after extraction, so this
equals its own extraction with the corner masks (measured: identical keypoints and descriptors on
lego 40 and in tests/verifier/test_verify_shared.py). A pair whose images the masks took no keypoint
from keeps the default's raw matches and two-view geometry; only the other pairs are matched and
verified again, as hardened verifies again only the pairs its stationary filter changes
(verifier/reuse.py).
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
from verifier.child_files import (
    KEPT_DATABASE,
    RESULT_PREFIX,
    map_temp_prefix,
    remove_child_leftovers,
    work_db_path,
)
from verifier.childenv import child_env
from verifier.sfm_images import corner_mask as corner_mask  # re-exported: tests and callers name it here
from verifier.sfm_images import import_per_size, left_out, write_corner_masks
from verifier.sift_device import sift_device, sift_device_name
from verifier.supervise import run_child

log = logging.getLogger(__name__)

# Serialises verification runs inside one process: SfM is CPU-heavy and the machine is shared.
_RUN_LOCK = threading.Lock()


class SfmSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """What one SfM run does. Defaults are the official 3DGS convert.py settings."""

    camera_model: str = "OPENCV"  # convert.py: --ImageReader.camera_model OPENCV
    single_camera: bool = True  # convert.py: --ImageReader.single_camera 1
    # a set of several stored sizes: one camera per size, as SINGLE per size (verifier.sfm_images)
    camera_per_size: bool = False
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
    # "incremental" (convert.py) or "global": COLMAP 4's global mapper (GLOMAP merged into COLMAP)
    mapper: str = "incremental"
    # SIFT on the CPU even where a GPU is (small images: verifier.sift_device.gpu_sift_suits)
    cpu_sift: bool = False
    # the incremental mapper's threads; -1: COLMAP's (every core). One thread maps one database to
    # one model every time, which several do not (docs/VERIFIER.md, "Mapping under load")
    mapper_threads: int = -1
    # the raw matcher's threads; -1: COLMAP's (every core). Its CPU matcher gives a pair other matches
    # now and then when several threads run (colmap/colmap#727; here 1 run in 500 of six views under
    # load lost most of one pair's); one thread matched 1200 runs alike
    matcher_threads: int = -1

    def verification_key(self) -> str:
        """Settings that decide the verified database (features, raw matches, two-view geometry):
        profiles with the same key share one geometric verification (default and global)."""
        return f"{self.feature_key()}-stationary{int(self.filter_stationary_matches)}-seed{self.random_seed}"

    def feature_key(self) -> str:
        """Settings that decide features + raw matches (the cache is valid across the rest)."""
        key = (
            f"{self.camera_model}-{int(self.single_camera)}-{self.camera_params}-{self.matching}-"
            f"{self.sequential_overlap}-{self.max_image_size}"
        )
        # masks change the features; unmasked keys stay as they were (existing caches stay valid)
        key += f"-mask{self.mask_corners:g}" if self.mask_corners > 0 else ""
        key += "-per-size" if self.camera_per_size else ""  # one-size keys stay as they were
        # GPU SIFT (SiftGPU) finds other features than the CPU's: a cache made on one is not reused on
        # the other; CPU keys stay as they were
        return key + ("-cuda" if self.sift_device_name() == "cuda" else "")

    def sift_device_name(self) -> str:
        """Where these settings' SIFT runs, "cuda" or "cpu" (asked without loading pycolmap)."""
        return sift_device_name(cpu_only=self.cpu_sift)


# Issue 14: what an attacker who has read the paper does about a corner mark.
MASKED_CORNER_FRACTION = 0.2


def profile_sfm_settings(profile: str, base: SfmSettings) -> SfmSettings:
    """The SfM settings of a verification profile, from the default pipeline's settings.

    default / published: base (published differs in its images, not its settings); hardened:
    COLMAP's defences against fixed marks; masked: the four corner regions (20% x 20%) masked
    out of feature extraction, as an attacker who expects a corner watermark would; global: the
    default's features and verification, then COLMAP 4's global mapper.
    """
    if profile in ("default", "published"):
        return base
    if profile == "global":
        return msgspec.structs.replace(base, mapper="global")
    if profile == "hardened":
        return msgspec.structs.replace(base, filter_stationary_matches=True, ignore_watermarks=True)
    if profile == "masked":
        return msgspec.structs.replace(base, mask_corners=MASKED_CORNER_FRACTION)
    raise ValueError(f"unknown profile {profile!r}")


class SfmJob(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """What the SfM child runs (sent as JSON on its stdin)."""

    image_dir: str
    cache_db: str  # features + raw matches; created when missing
    model_dir: str  # the largest model is written here (cameras.bin, images.bin, points3D.bin)
    settings: SfmSettings = msgspec.field(default_factory=SfmSettings)
    result_path: str = ""
    # shared work (issue 30): "" = not shared
    verified_db: str = ""  # the verified database: copied when it exists, else written after verification
    features_from: str = ""  # masked: an unmasked cache_db of the same images, filtered by position
    # hardened: the verified database of the same raw matches without the stationary filter (the
    # default's); only the pairs that filter changes are verified again (verifier.reuse)
    stationary_from: str = ""
    # masked: the default's verified database of the unmasked features (same two-view options); the
    # pairs whose input is the same take its geometry (verifier.reuse.reverify_masked)
    verified_from: str = ""
    # "features": build cache_db (features + raw matches) and stop; "verified": also write verified_db
    stop_after: str = ""
    keep_database: bool = False  # the verified database the mapper read stays as model_dir/database.db


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
    num_points3D: int = 0  # the JSON key verification reports use
    camera: CameraModel | None = None
    timings: dict[str, float] = {}
    device: str = ""  # where SIFT ran: "cpu" or "cuda" ("": not recorded)
    left_out: list[str] = []  # images of the folder COLMAP did not take into its database


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
    exclusive: bool = True,
) -> dict[str, Any]:
    """Run one SfM job in a child process; always returns a result dict with an `outcome`:

    `ok` | `failed` (the child reported an error) | `sfm_crashed` (killed by a signal) |
    `timeout` | `cancelled`. exclusive: one job at a time in this process (a verification that
    runs its profiles in parallel bounds its own children instead).
    """
    if not exclusive:
        return _run_locked(job, timeout_s, cancel, python)
    with _RUN_LOCK:
        return _run_locked(job, timeout_s, cancel, python)


def _run_locked(
    job: SfmJob, timeout_s: float | None, cancel: threading.Event | None, python: str | None
) -> dict[str, Any]:
    Path(job.model_dir).mkdir(parents=True, exist_ok=True)
    fd, result_path = tempfile.mkstemp(prefix=RESULT_PREFIX, suffix=".json", dir=job.model_dir)
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
    remove_child_leftovers(job.model_dir, job.result_path)
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


def build_cache_db(
    image_dir: Path, cache_db: Path, settings: SfmSettings, features_from: Path | None = None
) -> None:
    """Extract SIFT features and raw (unverified) matches into cache_db, atomically (a killed run
    leaves no half-built cache under the real name). With features_from (an unmasked cache of the
    same images) and corner masks: its features filtered by position instead of an extraction."""
    from poisoner.atomic import atomic_output

    mask_dir = cache_db.with_name(f".ppd-tmp-masks-{cache_db.stem}")
    try:
        with atomic_output(cache_db) as tmp:
            if features_from is not None and settings.mask_corners > 0 and features_from.exists():
                filter_features(features_from, tmp, image_dir, settings.mask_corners)
                from verifier.reuse import copy_unmasked_matches

                copied, pairs = copy_unmasked_matches(features_from, tmp)
                print(f"ppd: masked: {copied} of {pairs} pair(s) keep the unmasked raw matches",
                      file=sys.stderr, flush=True)  # fmt: skip
            else:
                extract_features(image_dir, tmp, settings, mask_dir)
            match_raw(tmp, settings)
    finally:
        shutil.rmtree(mask_dir, ignore_errors=True)


def filter_features(source_db: Path, database: Path, image_dir: Path, fraction: float) -> None:
    """database = source_db's cameras, images and features, less the keypoints (and descriptors)
    inside the corner masks, and no matches: what COLMAP's own masked extraction writes, since it
    masks keypoints after extracting them (pixel (int x, int y) of the mask, as COLMAP reads it)."""
    import pycolmap
    from PIL import Image

    shutil.copyfile(source_db, database)
    with pycolmap.Database.open(database) as db:
        db.clear_matches()
        db.clear_two_view_geometries()
        kept = {}
        for image in db.read_all_images():
            keypoints = db.read_keypoints(image.image_id)
            descriptors = db.read_descriptors(image.image_id)
            with Image.open(image_dir / image.name) as im:
                width, height = im.size
            mask = corner_mask(width, height, fraction)
            xs, ys = keypoints[:, 0].astype(int), keypoints[:, 1].astype(int)
            inside = (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height)  # COLMAP drops the others
            keep = inside.copy()
            keep[inside] = mask[ys[inside], xs[inside]] > 0
            kept[image.image_id] = (
                keypoints[keep],
                pycolmap.FeatureDescriptors(descriptors.type, descriptors.data[keep]),
            )
        db.clear_keypoints()
        db.clear_descriptors()
        for image_id, (keypoints, descriptors) in kept.items():
            db.write_keypoints(image_id, keypoints)
            db.write_descriptors(image_id, descriptors)


def extract_features(image_dir: Path, database: Path, settings: SfmSettings, mask_dir: Path) -> None:
    """SIFT features of every image into database (corner masks written to mask_dir when asked)."""
    import pycolmap

    names = list_images(image_dir)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = settings.camera_model
    if settings.camera_params:
        reader.camera_params = settings.camera_params
    if settings.mask_corners > 0:
        write_corner_masks(image_dir, names, mask_dir, settings.mask_corners)
        reader.mask_path = str(mask_dir)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = settings.max_image_size
    mode = pycolmap.CameraMode.SINGLE if settings.single_camera else pycolmap.CameraMode.AUTO
    # The images written first, in name order: COLMAP's extraction numbers images in the order its
    # threads finish, and the numbering decides which image of a pair is matched against the other,
    # so the same photos gave other verified pairs (and verdict figures) from run to run. Extraction
    # then finds each image by name and keeps its id (and camera: AUTO checks no shared size).
    pycolmap.Database.open(database).close()
    if settings.camera_per_size:
        import_per_size(database, image_dir, names, reader)
        mode = pycolmap.CameraMode.AUTO
    else:
        pycolmap.import_images(database, image_dir, camera_mode=mode, image_names=names, options=reader)
    pycolmap.extract_features(
        database,
        image_dir,
        image_names=names,
        camera_mode=mode,
        reader_options=reader,
        extraction_options=extraction,
        device=sift_device(settings.cpu_sift),
    )


def match_raw(database: Path, settings: SfmSettings) -> None:
    """Raw matches (no geometric verification: each profile verifies with its own options)."""
    import pycolmap

    matching = pycolmap.FeatureMatchingOptions()
    matching.skip_geometric_verification = True
    matching.num_threads = settings.matcher_threads
    device = sift_device(settings.cpu_sift)
    if settings.matching == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = settings.sequential_overlap
        pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing, device=device)
    elif settings.matching == "exhaustive":
        pycolmap.match_exhaustive(database, matching_options=matching, device=device)
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
        features_from = Path(job.features_from) if job.features_from else None
        build_cache_db(image_dir, cache_db, settings, features_from)
        timings["features_and_matches_s"] = time.time() - t0
    if job.stop_after == "features":
        return SfmOk(num_images=len(list_images(image_dir)), timings=timings)
    work_db = work_db_path(model_dir, job.result_path)
    t1 = time.time()
    num_images, verified_pairs = verified_database(
        cache_db, work_db, settings, job.verified_db, job.stationary_from, job.verified_from
    )
    timings["verification_s"] = time.time() - t1
    # read from this run's own copy: the shared cache is never opened once built (others copy it)
    missing = left_out(work_db, list_images(image_dir))
    if job.stop_after == "verified":  # the shared verified database is written: no mapping here
        model_dir.mkdir(parents=True, exist_ok=True)
        work_db.unlink()
        return SfmOk(num_images=num_images, verified_pairs=verified_pairs, timings=timings)
    if job.keep_database:  # kept under its name before the mapper opens it: there however mapping ends
        work_db = work_db.replace(model_dir / KEPT_DATABASE)
    t2 = time.time()
    with tempfile.TemporaryDirectory(prefix=map_temp_prefix(job.result_path), dir=model_dir) as tmp:
        models = run_mapper(work_db, image_dir, Path(tmp), settings)
        timings["mapping_s"] = time.time() - t2
        if not job.keep_database:
            work_db.unlink()
        result = summarise_models(models, num_images, verified_pairs)
        if models:
            largest = max(models.values(), key=lambda r: r.num_reg_images())
            largest.write(model_dir)
    result.timings = timings
    result.device = sift_device(settings.cpu_sift).name
    result.left_out = missing
    return result


def verified_database(
    cache_db: Path, work_db: Path, settings: SfmSettings, verified_db: str, stationary_from: str = "",
    verified_from: str = "",
) -> tuple[int, int]:  # fmt: skip
    """work_db = cache_db after this profile's geometric verification; (images, verified pairs).

    With verified_db: copied from there when an earlier profile with the same two-view options
    wrote it, else verified here and kept there (atomically) for the next one. With
    stationary_from (hardened, the default's verified database there): only the pairs the
    stationary filter changes are verified again. With verified_from (masked, the default's verified
    database of the unmasked features): only the pairs whose input the masks changed."""
    import pycolmap

    from poisoner.atomic import atomic_output

    shared = Path(verified_db) if verified_db else None
    if shared is not None and shared.exists():
        shutil.copyfile(shared, work_db)
        with pycolmap.Database.open(work_db) as db:
            return db.num_images(), db.num_verified_image_pairs()
    base = Path(stationary_from) if stationary_from else None
    if settings.filter_stationary_matches and base is not None and base.exists():
        counts = reverify_stationary(base, work_db, settings)
    elif settings.mask_corners > 0 and verified_from and Path(verified_from).exists():
        counts = reverify_masked(Path(verified_from), cache_db, work_db, settings)
    else:
        shutil.copyfile(cache_db, work_db)
        counts = verify_pairs(work_db, settings)
    if shared is not None:
        shared.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(shared) as tmp:
            shutil.copyfile(work_db, tmp)
    return counts


def run_mapper(work_db: Path, image_dir: Path, out: Path, settings: SfmSettings) -> dict[int, Any]:
    """The settings' mapper: COLMAP's incremental mapper (convert.py) or its global mapper."""
    import pycolmap

    if settings.mapper == "global":
        return pycolmap.global_mapping(work_db, image_dir, out, options=global_options(settings))
    if settings.mapper != "incremental":
        raise ValueError(f"unknown mapper {settings.mapper!r}")
    return pycolmap.incremental_mapping(work_db, image_dir, out, options=mapper_options(settings))


def global_options(settings: SfmSettings) -> Any:
    """COLMAP 4's global mapper as documented (`colmap global_mapper`), with the run's seed; no
    view-graph calibration (measured on clean lego 40: 40/40 registered without it, 33 with it)."""
    import pycolmap

    options = pycolmap.GlobalPipelineOptions()
    options.random_seed = settings.random_seed
    options.ignore_watermarks = settings.ignore_watermarks
    if settings.camera_params:  # known intrinsics: kept fixed, as in the incremental mapper
        ba = options.mapper.bundle_adjustment
        ba.refine_focal_length = False
        ba.refine_principal_point = False
        ba.refine_extra_params = False
    return options


def verify_pairs(work_db: Path, settings: SfmSettings) -> tuple[int, int]:
    """This profile's geometric verification of the raw matches; (images, verified pairs). A pair
    that already has a two-view row keeps it: COLMAP skips one with inliers, and one whose row says
    it failed (taken from the default's verification) is set aside while COLMAP runs
    (verifier.reuse.failed_pairs_set_aside)."""
    import pycolmap

    from verifier.reuse import failed_pairs_set_aside

    two_view = pycolmap.TwoViewGeometryOptions()
    two_view.filter_stationary_matches = settings.filter_stationary_matches
    two_view.ransac.random_seed = settings.random_seed
    with failed_pairs_set_aside(work_db):
        pycolmap.geometric_verification(work_db, two_view_geometry_options=two_view)
    with pycolmap.Database.open(work_db) as db:
        return db.num_images(), db.num_verified_image_pairs()


def reverify_stationary(default_verified: Path, work_db: Path, settings: SfmSettings) -> tuple[int, int]:
    """work_db = the hardened verification of the raw matches, from the default's verified database
    of the same raw matches: every pair the stationary filter changes nothing in keeps the default's
    geometry; COLMAP's own verification (which skips pairs that have one) computes the others with
    the filter. Equal to a whole hardened verification pair by pair; (images, verified pairs)."""
    from verifier.reuse import drop_stationary_geometries

    again = drop_stationary_geometries(default_verified, work_db)
    print(f"ppd: stationary filter: {again} pair(s) verified again", file=sys.stderr, flush=True)
    return verify_pairs(work_db, settings)


def reverify_masked(
    default_verified: Path, cache_db: Path, work_db: Path, settings: SfmSettings
) -> tuple[int, int]:
    """work_db = the masked verification of cache_db's raw matches, with the default's geometry for
    every pair whose keypoints and raw matches are the default's; COLMAP verifies the others. Equal
    to a whole masked verification pair by pair; (images, verified pairs)."""
    from verifier.reuse import take_unmasked_geometries

    taken, pairs = take_unmasked_geometries(default_verified, cache_db, work_db)
    print(f"ppd: masked: {taken} of {pairs} pair(s) taken from the default's verification",
          file=sys.stderr, flush=True)  # fmt: skip
    return verify_pairs(work_db, settings)


def mapper_options(settings: SfmSettings) -> Any:
    """COLMAP's incremental mapper options for these settings."""
    import pycolmap

    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.ignore_watermarks = settings.ignore_watermarks
    mapper.random_seed = settings.random_seed
    mapper.num_threads = settings.mapper_threads
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
