"""The plan of a verification: which profiles run, each profile's two SfM sides (what images
each sees, where its shared work lives, the key its clean result is reused under), and the order
the sides take their slots. verifier.verification runs the plan and decides each profile."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import threading
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import msgspec

from poisoner.errors import ExitStatus, PpdError
from poisoner.limits import HeaderError, decoded_size
from verifier import poses as posemod
from verifier.progress import ProgressBoard
from verifier.sfm import SfmSettings, list_images, profile_sfm_settings
from verifier.shared_sfm import SfmSide, clean_cache_for, content_key
from verifier.sift_device import gpu_sift_suits
from verifier.verify_options import VerifyOptions

# masked: the attacker who has read about corner marks masks the four corner regions out of SfM;
# global: COLMAP 4's global mapper on the default's matches.
PROFILES = ("default", "hardened", "published", "global", "masked")
# Profiles whose features are the originals' unmasked SIFT features (masked filters those).
UNMASKED_FEATURE_PROFILES = ("default", "hardened", "global")


class VerificationInputError(PpdError, ValueError):
    """Folders that cannot be verified (message = one clear line)."""

    exit_status = ExitStatus.USAGE


# ---- settings per profile ------------------------------------------------------------------------
def profile_settings(profile: str, matching: str, camera_params: str | None) -> SfmSettings:
    try:
        return profile_sfm_settings(profile, SfmSettings(matching=matching, camera_params=camera_params))
    except ValueError:
        choices = ", ".join(PROFILES)
        raise VerificationInputError(f"unknown profile {profile!r}; choose from {choices}") from None


def expand_profiles(profiles: Sequence[str] | str) -> list[str]:
    names = [profiles] if isinstance(profiles, str) else list(profiles)
    out: list[str] = []
    for n in names:
        for p in PROFILES if n == "all" else (n,):
            if p not in PROFILES:
                raise VerificationInputError(f"unknown profile {p!r}; choose from {', '.join(PROFILES)}, all")
            if p not in out:
                out.append(p)
    return out


def looks_like_video_frames(names: Sequence[str]) -> bool:
    """Frames sampled from a video are named with a frame index (poisoner.video.sample_frames)."""
    return bool(names) and all("frame" in Path(n).stem.lower() for n in names)


def default_workers() -> int:
    """SfM sides at once (a side: one profile's clean or poisoned run), two from 2 cores up, one per
    2 cores beyond: COLMAP's incremental mapping, most of a side's time once features are shared
    (lego 40: 7 of 8 minutes of a poisoned run, registration retries; 12 x 24 MP on 16 cores with
    SIFT on a GPU: 20-60 s of mapping against a few seconds of SIFT), keeps one or two cores busy,
    so on 16 cores eight sides at once keep them busy where four profiles, one side after the
    other, left half of them idle."""
    cores = os.cpu_count() or 1
    return max(min(2, cores), cores // 2)


def mapper_threads(asked: int, workers: int, cores: int | None = None) -> int:
    """Each incremental mapping's threads: what was asked (n, or -1 for COLMAP's every core), else
    one where a side's slot holds no more than a core (cores <= sides at once: 2 cores), COLMAP's own
    elsewhere. On one thread COLMAP 4.2.1's mapper gives one database one model every time, where on
    several a busy machine changes it (lego 16: 3 of 12 mappings; docs/VERIFIER.md), and on 2 cores,
    two sides mapping at once, it cost nothing measurable (bench/results/verify_speed.md round 10:
    lego 40, 6.49x against 6.73x). Not beyond: on many cores the last long mapping runs alone, and one
    structure-less registration took 237-242 s on one thread against 137 s on two."""
    if asked:
        return asked
    cores = cores or os.cpu_count() or 1
    return 1 if cores <= max(1, workers) else -1


def start_order(profiles: Sequence[str]) -> list[str]:
    """The order profiles start in: `published` first, the one that shares no work (its own
    extraction and matching on both sides, lego 20: the last to finish when it started third), so
    it overlaps the others instead of running alone at the end; the rest as asked."""
    return sorted(profiles, key=lambda p: p != "published")


def poisoned_sides(seeds: int) -> list[str]:
    """A profile's poisoned sides: "poisoned" (the first seed), then "poisoned-run2", ... (one per
    further seed; each its own model folder)."""
    return ["poisoned", *(f"poisoned-run{k + 1}" for k in range(1, max(1, seeds)))]


def side_order(profiles: Sequence[str], seeds: int = 1) -> list[tuple[str, str]]:
    """The order SfM sides take their slots: every clean side first, in start_order, then the
    poisoned ones (each profile's first seed, then the further seeds). A clean reference registers
    every view and is the longest run of its profile (12 x 24 MP on 16 cores: 42-84 s of mapping
    against 14-39 s poisoned), so the last clean side no longer starts after the first poisoned ones
    end and finishes last."""
    order = start_order(profiles)
    return [(p, "clean") for p in order] + [(p, side) for side in poisoned_sides(seeds) for p in order]


# ---- the run ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class VerifyRun:
    """What every profile of one verification shares: inputs, folders, caches, ground truth."""

    clean_dir: Path
    poisoned_dir: Path
    names: list[str]
    out_dir: Path
    cache: Path  # this run's feature databases and round-tripped images (removed unless keep_cache)
    clean_cache: Path  # reused across verifications when options.clean_cache_dir is set
    clean_key: str  # the clean folder's content key (names, SHA-256 of each file)
    matching: str
    gt: dict[str, posemod.Pose] | None
    options: VerifyOptions
    profiles: tuple[str, ...] = ()
    board: ProgressBoard | None = None
    long_edge: int = 0  # the originals' longest side, px (where SIFT runs: gpu_sift_suits)
    sizes: dict[str, int] = dataclasses.field(default_factory=dict)  # "400x300": originals of that size
    # the two sides hold more than one stored size: every side maps with one camera per size
    # (verifier.sfm_images), else with convert.py's single camera
    camera_per_size: bool = False


@dataclass(frozen=True)
class ProfilePlan:
    """One attacker's two SfM sides, planned before either runs (they run independently)."""

    profile: str
    sides: dict[str, SfmSide]  # "clean", "poisoned"
    clean_model_copy: Path | None  # where the report keeps a copy of a cached clean model
    started: dict[str, float] = dataclasses.field(default_factory=dict)  # side -> when it took a slot


def prepare_run(clean_dir: Path, poisoned_dir: Path, out_dir: Path, options: VerifyOptions) -> VerifyRun:
    names = check_inputs(clean_dir, poisoned_dir)
    if options.cancel is None:  # what a Ctrl-C sets to end the running SfM children (run_profiles)
        options = dataclasses.replace(options, cancel=threading.Event())
    matching = options.matching
    if matching == "auto":
        matching = "sequential" if looks_like_video_frames(names) else "exhaustive"
    gt = posemod.load_ground_truth(options.ground_truth) if options.ground_truth else None
    out_dir.mkdir(parents=True, exist_ok=True)
    cache = out_dir / ".cache"
    key = content_key(clean_dir, names)
    clean_cache = (
        clean_cache_for(Path(options.clean_cache_dir), key, options.clean_cache_keep)
        if options.clean_cache_dir
        else cache
    )
    sizes = stored_sizes(clean_dir, names)  # each header read once: the sizes and the longest side
    per_size = len(set(sizes) | set(stored_sizes(poisoned_dir, names))) > 1
    return VerifyRun(clean_dir, poisoned_dir, names, out_dir, cache, clean_cache, key, matching, gt, options,
                long_edge=_longest(sizes), sizes={f"{w}x{h}": n for (w, h), n in sizes.most_common()},
                camera_per_size=per_size)  # fmt: skip


def stored_sizes(image_dir: Path, names: Sequence[str]) -> Counter[tuple[int, int]]:
    """How many images have each stored (width, height), as their headers say it (no EXIF orientation
    applied, as COLMAP reads them: poisoner.limits.decoded_size); an unreadable header counts nowhere."""
    sizes: Counter[tuple[int, int]] = Counter()
    for name in names:
        with contextlib.suppress(HeaderError):
            size = decoded_size(image_dir / name)
            sizes[(size.width, size.height)] += 1
    return sizes


def longest_side(image_dir: Path, names: Sequence[str]) -> int:
    """The largest width or height among the images (their headers; 0 where none can be read)."""
    return _longest(stored_sizes(image_dir, names))


def _longest(sizes: Counter[tuple[int, int]]) -> int:
    return max((max(size) for size in sizes), default=0)


def check_inputs(clean_dir: Path, poisoned_dir: Path) -> list[str]:
    for d in (clean_dir, poisoned_dir):
        if not d.is_dir():
            raise VerificationInputError(f"not a folder: {d}")
    clean, poisoned = list_images(clean_dir), list_images(poisoned_dir)
    if not clean:
        raise VerificationInputError(f"no images in {clean_dir}")
    if set(clean) != set(poisoned):
        only_c = sorted(set(clean) - set(poisoned))[:3]
        only_p = sorted(set(poisoned) - set(clean))[:3]
        raise VerificationInputError(
            "clean and poisoned folders must hold the same file names "
            f"(only clean: {only_c}, only poisoned: {only_p})"
        )
    if len(clean) < 3:
        raise VerificationInputError(f"need at least 3 images for SfM, got {len(clean)}")
    return clean


def published_copy(side: str, run: VerifyRun) -> Path:
    """Where the published profile's round-tripped copies of one side's images live."""
    o = run.options
    tag = f"{o.published_long_edge}-{o.published_jpeg_quality}"
    if side == "clean":
        return run.clean_cache / f"published-{tag}-{run.clean_key}"
    return run.cache / f"published-{tag}-poisoned"


def plan_profile(profile: str, run: VerifyRun) -> ProfilePlan:
    """The profile's two SfM sides: what each sees (the published profile's are round-tripped
    through a platform's downscale and JPEG re-encode), where its shared work lives, and the key a
    clean result is reused under (cached with the same inputs and settings)."""
    settings = profile_settings(profile, run.matching, run.options.camera_params)
    source = "published" if profile == "published" else "original"
    edge = min(run.long_edge, run.options.published_long_edge) if source == "published" else run.long_edge
    o = run.options
    settings = msgspec.structs.replace(
        settings, random_seed=o.random_seed, cpu_sift=not gpu_sift_suits(edge),
        mapper_threads=mapper_threads(o.mapper_threads, o.workers or default_workers()),
        camera_per_size=run.camera_per_size,
    )  # fmt: skip
    clean_images, poisoned_images = run.clean_dir, run.poisoned_dir
    if source == "published":
        clean_images, poisoned_images = published_copy("clean", run), published_copy("poisoned", run)
    skey = hashlib.sha256(settings.feature_key().encode()).hexdigest()[:10]
    profile_dir = run.out_dir / profile
    # the SIFT device is said by the key's end alone, so a CPU key stays as it was; COLMAP's own
    # mapper and matcher threads are not said at all (a key made before the settings stays as it was)
    as_json = {
        k: v for k, v in msgspec.to_builtins(settings).items()
        if k != "cpu_sift"
        and (k, v) not in {("mapper_threads", -1), ("matcher_threads", -1), ("camera_per_size", False)}
    }  # fmt: skip
    settings_json = json.dumps(as_json, sort_keys=True)
    reuse_key = f"{run.clean_key}-{profile}-{settings_json}-{source}"
    reuse_key += "-cuda" if settings.sift_device_name() == "cuda" else ""
    cached = bool(run.options.clean_cache_dir)
    clean_model = (
        run.clean_cache / "clean-models" / hashlib.sha256(reuse_key.encode()).hexdigest()[:16]
        if cached
        else profile_dir / "clean"
    )
    clean_db = run.clean_cache / f"clean-{source}-{run.clean_key}-{skey}.db"
    poisoned_db = run.cache / f"poisoned-{source}-{skey}.db"
    clean_from = poisoned_from = None
    if settings.mask_corners > 0 and any(p in run.profiles for p in UNMASKED_FEATURE_PROFILES):
        # the unmasked features this run extracts anyway, filtered by position (verifier.sfm)
        ukey = hashlib.sha256(msgspec.structs.replace(settings, mask_corners=0.0).feature_key().encode())
        clean_from = run.clean_cache / f"clean-{source}-{run.clean_key}-{ukey.hexdigest()[:10]}.db"
        poisoned_from = run.cache / f"poisoned-{source}-{ukey.hexdigest()[:10]}.db"
    # default, hardened and global use one verification (hardened's made from it) when two of them run;
    # masked takes the default's geometry for the pairs its masks leave alone when default or global runs
    sharing = [p for p in UNMASKED_FEATURE_PROFILES if p in run.profiles]
    masked_takes = "masked" in run.profiles and any(p in run.profiles for p in ("default", "global"))
    takes_default = clean_from is not None and masked_takes
    share = profile in sharing and (len(sharing) > 1 or masked_takes)
    # verified databases live for this run only: the clean results they lead to are what is kept
    clean_side = SfmSide(clean_images, clean_db, clean_model, settings, reuse_key, clean_from,
                         run.cache / "clean-verified", share_verification=share,
                         takes_default_verification=takes_default, profile=profile, side="clean")  # fmt: skip
    poisoned_side = SfmSide(poisoned_images, poisoned_db, profile_dir / "poisoned", settings, None,
                            poisoned_from, run.cache, share_verification=share,
                            takes_default_verification=takes_default, profile=profile,
                            side="poisoned")  # fmt: skip
    copy = profile_dir / "clean" if cached else None  # the report's model folder holds a copy
    sides = {"clean": clean_side, "poisoned": poisoned_side}
    for k, side in enumerate(poisoned_sides(run.options.seeds)[1:], start=1):  # the attacker's reruns
        seeded = msgspec.structs.replace(settings, random_seed=settings.random_seed + k)
        sides[side] = dataclasses.replace(poisoned_side, model_dir=profile_dir / side, settings=seeded,
                                          side=side)  # fmt: skip
    return ProfilePlan(profile, sides, copy)
