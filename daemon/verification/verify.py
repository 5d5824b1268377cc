"""Verifying a dataset of the daemon: its vault originals vs its patched files, one run folder per
verification under `<runs_dir>/<dataset>/<run id>/`, one Store row per profile.

The verifier (verifier.verification) compares two folders; this module is the application side:
it finds the dataset's (original, patched) pairs, holds the cross-process verification lock,
records the report in the Store and prunes old run folders.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import re
import shutil
import time
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from poisoner.media import is_video
from verifier.pairs import stage_pairs
from verifier.verdict import Verdict
from verifier.verification import (
    PROFILES,
    VerificationInputError,
    VerificationReport,
    VerifyOptions,
    unmeasured_report,
    verify_folders,
)

if TYPE_CHECKING:
    from daemon.context import AppContext


def new_run_id() -> str:
    return time.strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:6]


STAMP = r"\d{8}T\d{6}"  # a folder name's time (new_run_id, the automatic mode's auto-<time>)
RUN_ID = re.compile(STAMP + r"-[0-9a-f]{6}")  # new_run_id()'s names, and nothing else of the folder


def prune_runs(dataset_runs: Path, keep_last: int) -> list[Path]:
    """Delete all but the newest keep_last folders of each kind in a dataset's runs: verification
    runs (run ids sort by time), the automatic mode's auto-<time> and auto-interim-<time>. Kept
    apart because "auto-..." sorts after every run id: mixed, a verification just recorded was
    pruned as the oldest when keep_last auto folders existed."""
    if not dataset_runs.is_dir():
        return []
    kinds: dict[str, list[Path]] = {}
    for p in dataset_runs.iterdir():
        if p.is_dir() and not p.name.startswith("."):
            kinds.setdefault(re.sub(STAMP + ".*$", "", p.name), []).append(p)
    doomed = [p for runs in kinds.values() for p in sorted(runs)[: max(0, len(runs) - keep_last)]]
    for p in doomed:
        shutil.rmtree(p, ignore_errors=True)
    return doomed


def remove_unfinished_runs(dataset_runs: Path) -> list[Path]:
    """Delete the verification run folders without a report.json: verifications killed or failed
    midway (their staged images, feature caches and partial models). Called under the verification
    lock, so no verification is running; only run-id names (not the automatic mode's auto-* folders,
    not .clean-cache)."""
    if not dataset_runs.is_dir():
        return []
    runs = [p for p in dataset_runs.iterdir() if RUN_ID.fullmatch(p.name) and p.is_dir()]
    doomed = [p for p in runs if not (p / "report.json").is_file()]
    for p in doomed:
        shutil.rmtree(p, ignore_errors=True)
    return doomed


@contextlib.contextmanager
def _process_lock(lock_path: Path) -> Iterator[None]:
    """One verification at a time across processes (the daemon's scheduler and `ppd verify`)."""
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    with open(lock_path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def verify_dataset(
    ctx: AppContext,
    dataset: str,
    profiles: Sequence[str] = PROFILES,
    options: VerifyOptions | None = None,
    keep_last: int | None = None,
) -> VerificationReport:
    """Verify a daemon dataset: its vault originals vs its protected files; rows in the Store."""
    from daemon.protect.one_file import dataset_pairs

    options = dataset_options(ctx, dataset, options or VerifyOptions())
    keep = keep_last if keep_last is not None else ctx.config.verification.keep_runs
    pairs = dataset_pairs(ctx, dataset)
    root = Path((ctx.store.dataset(dataset) or {}).get("root") or ".")
    if not pairs and not root.is_dir():  # it said "pair missing" (a second black-box review)
        raise VerificationInputError(f"dataset {dataset!r}: its folder {root} is gone (moved or deleted?)")
    # a video gives many views (its frames, sampled by stage_pairs): one clip of a walk-around is enough
    if len(pairs) < 3 and not any(is_video(protected) for _, protected in pairs):
        raise VerificationInputError(
            f"dataset {dataset!r} has {len(pairs)} patched photo(s); SfM needs at least 3 views to verify"
        )
    runs_root = Path(ctx.paths.runs_dir)
    run_dir = runs_root / dataset / new_run_id()
    with _process_lock(runs_root / ".verify.lock"):
        remove_unfinished_runs(runs_root / dataset)  # what a killed verification left
        images = run_dir / ".images"
        try:
            staged = stage_pairs(pairs, images / "clean", images / "poisoned")
            if len(staged.left_out) == len(pairs):  # no photo for COLMAP: said and recorded, as a few are
                report = unmeasured_report(images, run_dir, profiles, staged.left_out)
            else:
                matching = staged.matching if staged.matching != "auto" else options.matching
                opts = dataclasses.replace(options, matching=matching, not_staged=tuple(staged.left_out),
                                           video_frames=staged.video_frames)  # fmt: skip
                report = verify_folders(images / "clean", images / "poisoned", run_dir, profiles, opts)
        except BaseException:  # a run with no report (Ctrl-C, a failure) leaves no folder of ppd's
            shutil.rmtree(run_dir, ignore_errors=True)
            raise
        finally:
            shutil.rmtree(images, ignore_errors=True)
        # verify_folders wrote run_dir/report.json (what `ppd report RUN_DIR` reads)
        record_report(ctx, dataset, report)
        prune_runs(runs_root / dataset, keep)
    return report


def dataset_options(ctx: AppContext, dataset: str, options: VerifyOptions) -> VerifyOptions:
    """options with what the dataset knows: its subject masks (visibility's "touches subject") and
    whether its mark lives in one corner (what the masked attacker's line says)."""
    from daemon.datasets.subject_masks import SubjectMaskError, subject_masks_for

    changes: dict[str, Any] = {}
    if options.subject_masks is None:
        try:
            changes["subject_masks"] = subject_masks_for(ctx, dataset)
        except SubjectMaskError as exc:
            raise VerificationInputError(str(exc)) from None
    spec = ctx.store.dataset_spec(dataset)
    if options.corner_mark is None and spec is not None:
        changes["corner_mark"] = spec.corner_bound
    if options.clean_cache_dir is None:  # issue 30: clean reference cached per dataset; progress file
        from daemon.verification.verify_state import dataset_run_options

        changes.update(dataset_run_options(ctx.paths, dataset))
    return dataclasses.replace(options, **changes) if changes else options


def record_report(ctx: AppContext, dataset: str, report: VerificationReport) -> list[int]:
    """One Store row per profile; each row's metrics carry the run's visibility figures (measured once
    per verification, on the dataset's files), and whether the mark lives in one corner, so a report
    built from the Store shows them."""
    visibility = msgspec.to_builtins(report.visibility) if report.visibility is not None else None
    ids = []
    for p in report.profiles.values():
        ids.append(
            ctx.store.add_verification_run(
                dataset=dataset,
                profile=p.profile,
                verdict=p.verdict,
                metrics={**p.metrics(), "visibility": visibility, "corner_mark": report.corner_mark,
                         "video_frames": report.video_frames},  # fmt: skip
                started_at=p.started_at,
                finished_at=p.finished_at,
                model_dir=p.model_dir,
                error=p.error if p.verdict != Verdict.PROTECTED else None,
            )
        )
    return ids
