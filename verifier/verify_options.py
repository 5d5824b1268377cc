"""What one verification is asked to do (`verify_folders`' options), in a module of its own so that
the verification (verifier.verification) and each SfM side it runs (verifier.shared_sfm) both
import it without importing each other."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from verifier.progress import BoardState
from verifier.verdict import VerdictRule
from verifier.visibility import VISIBILITY_SAMPLE

# The splat stage's settings inside a verification: 200 px, at most 1500 iterations and 150 s of
# training per side, so SfM + splat on 40 views stays near 10 minutes on 2 cores (bench_splat).
SPLAT_DEFAULTS: dict[str, Any] = {"long_edge": 200, "iterations": 1500, "time_budget_s": 150.0}

@dataclass
class VerifyOptions:
    timeout_s: float = 1800.0  # per SfM run
    matching: str = "auto"  # auto: sequential when the images are frames sampled from videos
    camera_params: str | None = None  # known intrinsics "fx,fy,cx,cy,k1,k2,p1,p2" (a variant)
    ground_truth: Path | None = None  # lego transforms json, Strecha gt_dense_cameras dir, synthetic json
    published_long_edge: int = 2048
    published_jpeg_quality: int = 85
    crash_retries: int = 1  # rerun a crashed SfM with another RANSAC seed, as an attacker would
    random_seed: int = 0  # COLMAP's RANSAC/mapper seed (an attacker reruns with others)
    # the attacker's runs per profile: seeds random_seed, +1, ... on the same features and matches,
    # against one clean reference (random_seed); the profile reports its weakest (verdict.worst_seed)
    seeds: int = 1
    clean_cache_dir: Path | None = None  # reuse clean features/results across verifications
    clean_cache_keep: int = 0  # >0: keep this many originals' caches under clean_cache_dir (LRU)
    workers: int = 0  # SfM sides (a profile's clean or poisoned run) at once (0: default_workers())
    # each incremental mapping's threads: 0 chooses (verifier.plan.mapper_threads), -1 is COLMAP's
    # own (every core), n pins it (1: the same model from the same database every time)
    mapper_threads: int = 0
    progress_path: Path | None = None  # the progress file (verifier.progress), removed at the end
    progress_label: str = ""  # what the progress says is being verified
    on_progress: Callable[[BoardState], None] | None = None  # e.g. a terminal display
    keep_cache: bool = False  # keep feature databases and round-tripped images
    # keep each mapping's input, its verified database, beside its model (database.db), whether or
    # not the mapping finishes: what the mapper was given, to inspect or to compare two runs
    keep_databases: bool = False
    rule: VerdictRule = field(default_factory=VerdictRule)
    cancel: threading.Event | None = None
    # Verifier II: train clean and poisoned splats on one profile's SfM poses (the paper's costs).
    splat: bool = False
    splat_profile: str = "default"  # the first profile run is used when this one is not
    splat_options: dict[str, Any] = field(default_factory=lambda: dict(SPLAT_DEFAULTS))
    splat_timeout_s: float = 1800.0
    # What a viewer sees (verifier.visibility): FLIP on this many files, spread over the set.
    visibility_images: int = VISIBILITY_SAMPLE
    subject_masks: Path | None = None  # a folder of subject masks (<name>.png, <stem>.png, same number)
    corner_mark: bool | None = None  # the mark lives in one corner (None: judged by the visibility stage)
    # the set's photos left out before SfM (verifier.pairs.Staged.left_out): named, no verdict covers them
    not_staged: tuple[str, ...] = ()
    # each video's frames given to COLMAP, in words (verifier.pairs.Staged.video_frames): said too
    video_frames: tuple[str, ...] = ()
