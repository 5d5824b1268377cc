"""One SfM side of one verification profile, with the work shared across profiles (issue 30).

What a verification (verifier.verification) plans per side, and how the side's child runs reuse
each other's work: features and raw matches built once per image set (`ensure_features`, under a
lock, so profiles that share them wait for one build), a verified database shared by the profiles
with the same two-view options (default and global), hardened's verification made from the
default's, and masked's too for the pairs its masks leave alone (`run_job`; verifier/reuse.py), and a
clean result stored next to its model reused while the originals' content key (`content_key`) and
the settings are the same.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import shutil
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from poisoner.atomic import STALE_TEMP_AGE_S, atomic_write_bytes, is_temp_name, remove_if_stale
from verifier.progress import ProgressBoard
from verifier.sfm import SfmJob, SfmSettings, run_sfm_job
from verifier.verify_options import VerifyOptions

log = logging.getLogger(__name__)


def content_key(image_dir: Path, names: Sequence[str]) -> str:
    """The originals' content key: their names and the SHA-256 of their bytes (a clean reference
    cached under it is valid until an original changes, whatever its mtime or path)."""
    h = hashlib.sha256()
    for n in names:
        with open(image_dir / n, "rb") as fh:
            digest = hashlib.file_digest(fh, "sha256").hexdigest()
        h.update(f"{n}:{digest}\n".encode())
    return h.hexdigest()[:16]


def clean_cache_for(root: Path, key: str, keep: int) -> Path:
    """The clean cache of these originals under root (private: it holds their features and
    round-tripped copies); with keep > 0, only the keep most recently used caches stay."""
    root.mkdir(parents=True, exist_ok=True, mode=0o700)
    here = root / key
    here.mkdir(exist_ok=True, mode=0o700)
    os.utime(here)  # most recently used
    sweep_killed_databases(here)
    if keep > 0:
        others = [p for p in root.iterdir() if p.is_dir() and p != here]
        others.sort(key=lambda p: p.stat().st_mtime)
        for stale in others[: max(0, len(others) - (keep - 1))]:
            shutil.rmtree(stale, ignore_errors=True)
    return here


SQLITE_SIDECARS = ("-wal", "-shm", "-journal")


def sweep_killed_databases(folder: Path) -> list[str]:
    """The temporaries a feature child killed mid-build left in a clean cache (a Ctrl-C'd or killed
    verification: its database and SQLite's -wal and -shm beside it, the originals' features, which
    nothing removed; a diff review). A database goes with its sidecars only once no living writer
    holds it (poisoner.atomic.remove_if_stale); a sidecar alone only when its database is gone and it
    is old enough to have no writer."""
    try:
        dir_fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        return []
    removed: list[str] = []
    try:
        names = [n for n in os.listdir(dir_fd) if is_temp_name(n)]  # ppd's form (a sidecar's too)
        bases = {n for n in names if not n.endswith(SQLITE_SIDECARS)}
        removed += [n for n in sorted(bases) if remove_if_stale(dir_fd, n)]
        for name in names:
            base = next((name.removesuffix(s) for s in SQLITE_SIDECARS if name.endswith(s)), None)
            if base is None or (base in bases and base not in removed):
                continue
            with contextlib.suppress(OSError):
                if time.time() - os.stat(name, dir_fd=dir_fd).st_mtime >= STALE_TEMP_AGE_S or base in removed:
                    os.unlink(name, dir_fd=dir_fd)
                    removed.append(name)
    finally:
        os.close(dir_fd)
    return removed


def feature_builds_at_once(memory_bytes: int | None = None) -> int:
    """Feature-building children (SIFT + raw matching) at once, whatever the SfM slots: one per
    8 GiB of memory, at least one. One such child on four 24 MP photos peaked at 4.0 GB with 2
    threads on the 2-core machine, and it starts a thread per core; the sides of a verification
    start together, so without a cap four sets (clean, poisoned, and published's two) could be
    extracted at once on a machine with many cores and little memory."""
    if memory_bytes is None:
        try:
            memory_bytes = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (OSError, ValueError):
            memory_bytes = 0
    return max(1, memory_bytes // (8 << 30))


_FEATURE_BUILDS = threading.BoundedSemaphore(feature_builds_at_once())
_PATH_LOCKS: dict[str, threading.Lock] = {}
_PATH_LOCKS_GUARD = threading.Lock()


@contextlib.contextmanager
def path_lock(path: Path) -> Iterator[None]:
    """One thread at a time builds a shared file (features, a verified database); the others wait."""
    with _PATH_LOCKS_GUARD:
        lock = _PATH_LOCKS.setdefault(str(path), threading.Lock())
    with lock:
        yield


def write_json(path: Path, data: Any) -> None:
    """A report or result as indented JSON, replaced atomically (a reader never sees half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, msgspec.json.format(msgspec.json.encode(data), indent=1))


def stored_result(result_file: Path, reuse_key: str) -> dict[str, Any] | None:
    """A clean SfM result stored next to its model by an earlier run with the same inputs, if any."""
    if not result_file.exists():
        return None
    stored = json.loads(result_file.read_text())
    if stored.get("reuse_key") == reuse_key and stored.get("outcome") == "ok":
        return stored
    return None


@dataclass(frozen=True)
class SfmSide:
    """One SfM side of one profile: its images, where its shared work lives, where it reports."""

    image_dir: Path
    cache_db: Path  # features + raw matches, shared by the profiles with the same feature key
    model_dir: Path
    settings: SfmSettings
    reuse_key: str | None = None  # clean side: a stored result with this key is reused
    features_from: Path | None = None  # masked: the unmasked cache_db whose features it filters
    verified_dir: Path | None = None  # where verified databases are shared (by verification key)
    # other profiles of this run use this side's verification (default, global) or hardened builds
    # from it: verified databases are built by verify-only children first, under a lock each, so a
    # profile waits for a verification, never for another profile's mapping
    share_verification: bool = False
    # masked: this run verifies the unmasked features with the default's two-view options (default
    # or global runs), and the pairs the masks left alone take that geometry (verifier.reuse)
    takes_default_verification: bool = False
    profile: str = ""
    side: str = ""


def ensure_features(side: SfmSide, options: VerifyOptions, board: ProgressBoard | None) -> float:
    """Build side.cache_db once (its features_from first): a features-only child, under a lock so
    the profiles sharing it wait for one build instead of each extracting; the seconds this side
    spent building (0 when another profile had built them). A failure here is left to the
    profile's own run, which tries again and reports it."""
    spent = 0.0
    if side.features_from is not None:
        unmasked = msgspec.structs.replace(side.settings, mask_corners=0.0)
        spent += ensure_features(SfmSide(side.image_dir, side.features_from, side.model_dir, unmasked,
                                        profile=side.profile, side=side.side), options, board)  # fmt: skip
    with path_lock(side.cache_db):
        if side.cache_db.exists() or cancelled(options):
            return spent
        work = side.cache_db.parent / f"{side.cache_db.stem}-features"
        job = SfmJob(
            str(side.image_dir), str(side.cache_db), str(work), side.settings, stop_after="features",
            features_from=str(side.features_from) if side.features_from else "",
        )  # fmt: skip
        log_path = work / "sfm.log"
        watching = board.side(side.profile, side.side, log_path) if board else contextlib.nullcontext()
        with _FEATURE_BUILDS, watching:  # the slot first: the row says "features" once it runs
            built = run_sfm_job(job, timeout_s=options.timeout_s, cancel=options.cancel, exclusive=False)
        return spent + float(built.get("elapsed_s") or 0.0)


def run_side(side: SfmSide, options: VerifyOptions, board: ProgressBoard | None = None) -> dict[str, Any]:
    """One SfM run (child process). With reuse_key, a result stored next to the model is reused."""
    result_file = side.model_dir / "result.json"
    stored = stored_result(result_file, side.reuse_key) if side.reuse_key else None
    if stored is not None:
        log.info("reusing clean SfM result", extra={"model_dir": str(side.model_dir)})
        # said in the report: its time is the earlier run's, and when that ran (a black-box review:
        # a second verify showed the cached clean times as measured now and never said it reused them)
        made = time.strftime("%Y-%m-%d %H:%M", time.localtime(result_file.stat().st_mtime))
        return {**stored, "reused_from": made}
    features_s = ensure_features(side, options, board)
    settings = side.settings
    crashes: list[str] = []
    elapsed = features_s  # the features this side built count towards its cost
    for attempt in range(1 + max(0, options.crash_retries)):
        # a retry takes the next seed no other run of this profile uses (options.seeds: one each)
        retry_seed = settings.random_seed + attempt * max(1, options.seeds)
        run_settings = msgspec.structs.replace(settings, random_seed=retry_seed)
        result = run_job(side, run_settings, options, board, first=attempt == 0)
        elapsed += float(result.get("elapsed_s") or 0.0)
        result["elapsed_s"] = elapsed  # all attempts: what the verification cost
        if result.get("outcome") != "sfm_crashed":
            break
        crashes.append(str(result.get("signal")))
        log.warning("SfM crashed", extra={"image_dir": str(side.image_dir), "signal": result.get("signal")})
    if features_s and isinstance(result.get("timings"), dict):  # built by the features-only child
        result["timings"].setdefault("features_and_matches_s", features_s)
    result["crashes"] = crashes  # signals of crashed attempts (the last one too when all crashed)
    result["settings"] = msgspec.to_builtins(run_settings)
    result["random_seed"] = run_settings.random_seed  # the seed behind these figures (retries add 1)
    if side.reuse_key:
        result["reuse_key"] = side.reuse_key
    write_json(result_file, result)
    return result


def run_job(
    side: SfmSide,
    settings: SfmSettings,
    options: VerifyOptions,
    board: ProgressBoard | None,
    first: bool = True,
) -> dict[str, Any]:
    """The side's SfM child with these settings; profiles with the same two-view options share one
    geometric verification (the first writes the verified database under a lock, the others copy it),
    and hardened's and masked's are made from the default's (verifier.reuse)."""
    verified = stationary_from = verified_from = ""
    spent = 0.0  # seconds of verify-only children this side ran
    if side.verified_dir is not None:
        verified = str(verified_path(side, settings))
        base_settings = msgspec.structs.replace(settings, filter_stationary_matches=False)
        if settings.filter_stationary_matches and side.share_verification and first:
            spent += ensure_verified(side, base_settings, options, board)  # the default's, once
        if settings.filter_stationary_matches:
            stationary_from = str(verified_path(side, base_settings))  # used when it is there
        if side.share_verification:
            spent += ensure_verified(side, settings, options, board, stationary_from)
        if side.takes_default_verification and side.features_from is not None:
            unmasked = dataclasses.replace(side, cache_db=side.features_from, features_from=None)
            unmasked_settings = msgspec.structs.replace(settings, mask_corners=0.0)
            if first:  # the default's, which this run makes anyway: waited for, or made here first
                spent += ensure_verified(unmasked, unmasked_settings, options, board)
            verified_from = str(verified_path(unmasked, unmasked_settings))  # used when it is there
    job = SfmJob(
        str(side.image_dir), str(side.cache_db), str(side.model_dir), settings, verified_db=verified,
        features_from=str(side.features_from) if side.features_from else "", stationary_from=stationary_from,
        verified_from=verified_from, keep_database=options.keep_databases,
    )  # fmt: skip
    watching = board.side(side.profile, side.side, side.model_dir / "sfm.log") if board else None
    with watching or contextlib.nullcontext():
        if verified and not Path(verified).exists():
            with path_lock(Path(verified)):  # whoever builds it first, the others wait and copy
                result = run_sfm_job(job, timeout_s=options.timeout_s, cancel=options.cancel, exclusive=False)
        else:
            result = run_sfm_job(job, timeout_s=options.timeout_s, cancel=options.cancel, exclusive=False)
    if spent:  # the verify-only children's time is this side's verification
        result["elapsed_s"] = float(result.get("elapsed_s") or 0.0) + spent
        if isinstance(result.get("timings"), dict):
            result["timings"]["verification_s"] = float(result["timings"].get("verification_s", 0.0)) + spent
    return result


def ensure_verified(
    side: SfmSide, settings: SfmSettings, options: VerifyOptions, board: ProgressBoard | None,
    stationary_from: str = "",
) -> float:  # fmt: skip
    """Write the verified database of side's raw matches under settings' two-view options once: a
    verify-only child, under that database's lock (the profiles sharing it wait for the
    verification only); the seconds spent (0 when it was there). A failure is left to the
    profile's own run, which verifies itself."""
    path = verified_path(side, settings)
    with path_lock(path):
        if path.exists() or cancelled(options):
            return 0.0
        work = path.parent / f"{path.stem}-work"
        job = SfmJob(
            str(side.image_dir), str(side.cache_db), str(work), settings, verified_db=str(path),
            features_from=str(side.features_from) if side.features_from else "",
            stationary_from=stationary_from, stop_after="verified",
        )  # fmt: skip
        with board.side(side.profile, side.side, work / "sfm.log") if board else contextlib.nullcontext():
            built = run_sfm_job(job, timeout_s=options.timeout_s, cancel=options.cancel, exclusive=False)
        return float(built.get("elapsed_s") or 0.0)


def verified_path(side: SfmSide, settings: SfmSettings) -> Path:
    """Where the verified database of side's raw matches under these two-view options is shared."""
    assert side.verified_dir is not None
    vkey = hashlib.sha256(settings.verification_key().encode()).hexdigest()[:10]
    return side.verified_dir / f"{side.cache_db.stem}-verified-{vkey}.db"


def cancelled(options: VerifyOptions) -> bool:
    return bool(options.cancel and options.cancel.is_set())
