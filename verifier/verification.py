"""A verification run: SfM on the clean originals and on the poisoned set, per profile, compared.

Profiles (what an attacker would run):
- `default`: the official 3DGS convert.py settings (one shared OPENCV camera, SIFT, exhaustive
  matching or sequential for video frames, default geometric verification, incremental mapping).
- `hardened`: default plus COLMAP's two defences against fixed-position marks:
  `filter_stationary_matches=True` in verification and `ignore_watermarks=True` in the mapper.
- `published`: both sets after a platform round trip (long edge <= 2048 px, JPEG quality 85),
  then the default pipeline.
- `global`: the default's features and two-view geometry, then COLMAP 4's global mapper (GLOMAP
  merged into COLMAP) instead of the incremental one.
- `masked`: the attacker who has read about corner marks masks the four corner regions (20% x 20%)
  out of SfM. Counted in the headline verdict since the mark is placed per photo, off the corners
  where it can be (verifier.verdict.HEADLINE_PROFILES); it defeats every corner mark by
  construction, which the report also says on its own line (verifier.verdict.masked_line).

The parent never imports pycolmap: SfM runs in child processes (verifier.sfm). Work is shared
across profiles (issue 30): one feature extraction and raw matching per image set (default,
hardened, global; masked filters those features by position; published has its own pixels), one
geometric verification for default and global, and the clean reference (features, models, results)
cached per content of the originals (`clean_cache_dir`) until they change; hardened's verification
is the default's with only the pairs its stationary filter changes verified again. How a side reuses
that work: verifier.shared_sfm; what each side sees and where its work lives: verifier.plan. Each
profile's clean and poisoned sides are tasks of their own, `workers` at once (default_workers()),
every clean side first (side_order); every figure a verdict uses is what the profile run alone
gives (tests/verifier/test_verify_shared.py, tests/verifier/test_verify_stationary.py).
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
import threading
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import msgspec

from verifier import poses as posemod
from verifier.pairs import stage_pairs as stage_pairs  # re-exported: callers stage pairs, then verify
from verifier.plan import PROFILES as PROFILES  # re-exported: the CLI and the daemon name it here
from verifier.plan import (
    ProfilePlan,
    VerifyRun,
    expand_profiles,
    plan_profile,
    poisoned_sides,
    prepare_run,
    side_order,
)
from verifier.plan import VerificationInputError as VerificationInputError
from verifier.plan import default_workers as default_workers
from verifier.plan import longest_side as longest_side
from verifier.plan import start_order as start_order
from verifier.progress import ProgressBoard
from verifier.published import round_trip, unpublish_names
from verifier.published import to_rgb as to_rgb  # re-exported for verifier.auto_search
from verifier.shared_sfm import cancelled, path_lock, run_side
from verifier.shared_sfm import content_key as content_key  # re-exported: the clean cache's key
from verifier.shared_sfm import write_json as write_json  # re-exported: reports are written with it
from verifier.verdict import (
    Verdict,
    decide,
    headline,
    holding_line,
    left_out_line,
    left_out_of,
    masked_line,
    measured_verdict,
    not_holding,
    sizes_line,
    verdict_words,
    worst_seed,
)
from verifier.verify_options import SPLAT_DEFAULTS as SPLAT_DEFAULTS  # re-exported
from verifier.verify_options import VerifyOptions as VerifyOptions  # re-exported: callers build it
from verifier.visibility import DatasetVisibility, measure_pairs

log = logging.getLogger(__name__)

_VERIFY_LOCK = threading.Lock()  # one verification at a time in this process


class ProfileReport(msgspec.Struct):
    """One profile's outcome: what its report.json holds and the Store records."""

    profile: str
    verdict: Verdict
    reasons: list[str]
    clean: dict[str, Any]  # SfM summary (no poses)
    poisoned: dict[str, Any]
    vs_clean: dict[str, Any] | None
    clean_vs_gt: dict[str, Any] | None = None
    poisoned_vs_gt: dict[str, Any] | None = None
    model_dir: str | None = None
    started_at: float = 0.0
    finished_at: float = 0.0
    splat: dict[str, Any] | None = None  # run_splat_stage's result when the splat stage ran here
    # options.seeds > 1: each poisoned run's seed, verdict and figure (the fields above: the weakest)
    seeds: list[dict[str, Any]] | None = None
    # the photos COLMAP did not read on a side of this profile: its verdict does not cover them
    left_out: list[str] = msgspec.field(default_factory=list)

    @property
    def error(self) -> str | None:
        for side in (self.clean, self.poisoned):
            if side.get("outcome") != "ok":
                return str(side.get("error") or side.get("outcome"))
        return None

    def metrics(self) -> dict[str, Any]:
        """Everything but the verdict, JSON-ready (what the Store records)."""
        keep = ("reasons", "clean", "poisoned", "vs_clean", "clean_vs_gt", "poisoned_vs_gt", "splat", "seeds",
                "left_out")
        return {k: v for k, v in msgspec.to_builtins(self).items() if k in keep}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, with the derived `error` (what report.json files hold)."""
        return {**msgspec.to_builtins(self), "error": self.error}


class VerificationReport(msgspec.Struct):
    """A verification of one (clean, poisoned) pair of folders: every profile, and what a viewer sees."""

    clean_dir: str
    poisoned_dir: str
    out_dir: str
    num_images: int
    profiles: dict[str, ProfileReport]
    visibility: DatasetVisibility | None = None  # None: not measured (visibility_images = 0)
    corner_mark: bool | None = None  # the mark lives in one corner (what the masked line says)
    sizes: dict[str, int] | None = None  # several stored sizes: each and its count (one camera each)
    video_frames: list[str] | None = None  # each video's frames measured, in words (verifier.pairs)

    def verdicts(self) -> dict[str, str]:
        return {name: str(p.verdict) for name, p in self.profiles.items()}

    def left_out(self) -> list[str]:
        """The photos a counted profile's COLMAP did not read, on either side: not measured."""
        return sorted({name for p in headline(self.verdicts()) for name in self.profiles[p].left_out})

    @property
    def verdict(self) -> Verdict:
        """The headline: the weakest of the headline profiles run (verifier.verdict.HEADLINE_PROFILES);
        never "protected" while photos of the set were not measured (they could be reconstructed)."""
        return measured_verdict(self.verdicts(), self.left_out())

    def not_holding(self) -> list[str]:
        """The headline profiles (attackers) the protection does NOT hold under (weak or NOT
        protected; a crashed or inconclusive profile is not among them)."""
        return not_holding(headline(self.verdicts()))

    def summary_lines(self) -> list[str]:
        """The dataset-level lines `ppd verify` prints under the profiles: visibility, where the
        protection does not hold, and the masked attacker."""
        lines = self.visibility.lines() if self.visibility is not None else []
        if self.sizes:
            lines.append(sizes_line(self.sizes))
        lines += self.video_frames or []
        if left := self.left_out():
            lines.append(left_out_line(left, self.num_images))
        lines.append(holding_line(headline(self.verdicts())))
        masked = masked_line(self.verdicts(), self.corner_mark)
        if masked is not None:
            lines.append(masked)
        return lines

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, with the derived verdict, profile errors and summary lines."""
        d = msgspec.to_builtins(self)
        d["profiles"] = {k: v.to_dict() for k, v in self.profiles.items()}
        counted = list(headline(self.verdicts()))
        left = self.left_out()
        return {"verdict": str(self.verdict), "verdict_counts": counted, **d, "left_out": left,
                "num_measured": self.num_images - len(left), "summary": self.summary_lines()}  # fmt: skip


def unmeasured_report(
    images: Path, out_dir: Path, profiles: Sequence[str], left_out: dict[str, str]
) -> VerificationReport:
    """The report of a set none of whose photos could be given to COLMAP (left_out: every photo, each
    with why; verifier.pairs.Staged): every profile could not be verified, and leaves them all out as
    a partly staged set's profiles leave out theirs; written as verify_folders writes its report."""
    names = sorted(left_out)
    why = left_out[names[0]] + (f", and {len(names) - 1} more" if len(names) > 1 else "")
    line = f"none of the {len(names)} photos could be given to COLMAP ({why}): no verdict covers them"
    side = {"outcome": "not_run", "error": line}
    now = time.time()
    reports = {
        p: ProfileReport(p, Verdict.INCONCLUSIVE, [line], dict(side), dict(side), None,
                         started_at=now, finished_at=now, left_out=names)
        for p in expand_profiles(profiles)
    }  # fmt: skip
    staged = (str(images / "clean"), str(images / "poisoned"))
    report = VerificationReport(*staged, str(out_dir), len(names), reports)
    write_json(out_dir / "report.json", report.to_dict())  # what `ppd report FOLDER` reads
    return report


def _summary(result: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in result.items() if k not in ("poses", "settings", "reuse_key")}


def verify_folders(
    clean_dir: Path,
    poisoned_dir: Path,
    out_dir: Path,
    profiles: Sequence[str] = PROFILES,
    options: VerifyOptions | None = None,
) -> VerificationReport:
    """SfM on clean and poisoned sets (same file names) per profile; models under out_dir/<profile>/.

    Stages: inputs -> visibility (a few images) -> SfM per profile and side (options.workers sides
    at once, shared work) -> splat (optional) -> report."""
    profile_list = expand_profiles(profiles)
    run = prepare_run(Path(clean_dir), Path(poisoned_dir), Path(out_dir), options or VerifyOptions())
    o = run.options
    board = ProgressBoard(profile_list, len(run.names), o.progress_label or str(poisoned_dir),
                          o.progress_path, o.on_progress)  # fmt: skip
    run = dataclasses.replace(run, profiles=tuple(profile_list), board=board)
    reports: dict[str, ProfileReport] = {}
    with _VERIFY_LOCK:
        board.start()
        try:
            visibility = measure_visibility(run.clean_dir, run.poisoned_dir, run.names, run.options)
            reports = _run_profiles(profile_list, run)
            if run.options.splat and not cancelled(run.options):
                _splat_stage(reports, run.clean_dir, run.poisoned_dir, run.options)
        finally:
            board.close()
            if not run.options.keep_cache:
                shutil.rmtree(run.cache, ignore_errors=True)
    corner = run.options.corner_mark
    if corner is None and visibility is not None:
        corner = visibility.worst.in_one_corner
    total = len(run.names) + len(run.options.not_staged)  # the set's photos, those COLMAP cannot read too
    report = VerificationReport(
        str(run.clean_dir), str(run.poisoned_dir), str(run.out_dir), total, reports, visibility,
        corner, run.sizes if run.camera_per_size else None, list(run.options.video_frames) or None,
    )  # fmt: skip
    write_json(run.out_dir / "report.json", report.to_dict())  # what `ppd report FOLDER` reads
    return report


def _run_profiles(profile_list: Sequence[str], run: VerifyRun) -> dict[str, ProfileReport]:
    """Every profile's two sides, each its own task taken in side_order by `workers` threads (one SfM
    child each at a time); a profile is decided as soon as both its sides are done."""
    plans = {p: plan_profile(p, run) for p in profile_list}
    reports: dict[str, ProfileReport] = {}
    workers = max(1, run.options.workers or default_workers())
    with ThreadPoolExecutor(workers, thread_name_prefix="ppd-verify") as pool:
        sides = {(p, side): pool.submit(_run_planned_side, plans[p], side, run)
                 for p, side in side_order(profile_list, run.options.seeds)}  # fmt: skip
        try:
            for p in _profiles_as_done(sides):
                poisoned = [sides[(p, side)].result() for side in poisoned_sides(run.options.seeds)]
                reports[p] = _decide_profile(plans[p], sides[(p, "clean")].result(), poisoned, run)
        except BaseException as exc:  # the pool's exit waited for every side still to run (16-41 s)
            for future in sides.values():
                future.cancel()
            # Ctrl-C: the running children are ended within a second. Only then: the daemon's
            # scheduler passes its own long-lived event, which an error here must not set
            if isinstance(exc, KeyboardInterrupt) and run.options.cancel is not None:
                run.options.cancel.set()
            raise
    return {p: reports[p] for p in profile_list}  # in the order asked


def measure_visibility(
    clean_dir: Path, poisoned_dir: Path, names: Sequence[str], options: VerifyOptions
) -> DatasetVisibility | None:
    """What a viewer sees of the protection, on options.visibility_images files (0: not measured)."""
    if options.visibility_images <= 0:
        return None
    pairs = [(clean_dir / n, poisoned_dir / n) for n in names]
    return measure_pairs(pairs, sample=options.visibility_images, subject_mask_dir=options.subject_masks)


def _splat_stage(
    reports: dict[str, ProfileReport], clean_dir: Path, poisoned_dir: Path, options: VerifyOptions
) -> None:
    """Verifier II on one profile's models; its result and a one-line finding join that profile."""
    from verifier.splat.stage import run_splat_stage

    name = options.splat_profile if options.splat_profile in reports else next(iter(reports))
    if name == "published":  # its models index round-tripped copies, which are gone by now
        name = next((p for p in reports if p != "published"), name)
    report = reports[name]
    profile_dir = Path(report.model_dir or "")
    if report.clean.get("outcome") != "ok" or report.poisoned.get("outcome") != "ok":
        report.splat = {"outcome": "skipped", "error": f"SfM of the {name} profile did not give two models"}
    else:
        # with several seeds, the poses of the run the verdict counts (the attacker's best)
        chosen = [e["model"] for e in report.seeds or () if e["seed"] == report.poisoned.get("random_seed")]
        result = run_splat_stage(
            profile_dir / "clean",
            clean_dir,
            profile_dir / (chosen[0] if chosen else "poisoned"),
            poisoned_dir,
            profile_dir / "splat",
            dict(options.splat_options),
            timeout_s=options.splat_timeout_s,
            cancel=options.cancel,
        )
        report.splat = result
    report.reasons.append(splat_finding(report.splat))
    write_json(profile_dir / "report.json", report.to_dict())


def splat_finding(splat: dict[str, Any] | None) -> str:
    """One plain sentence on what the attacker's splat achieved (the paper's cost1, clean vs poisoned)."""
    if not splat or splat.get("outcome") != "ok":
        why = (splat or {}).get("error") or (splat or {}).get("outcome", "not run")
        return f"splat stage: no result ({why})"
    clean, pois = splat["clean"]["cost1"], splat["poisoned"]["cost1"]
    if clean.get("psnr") is None or pois.get("psnr") is None:
        return "splat stage: renders have no finite PSNR"
    drop = clean["psnr"] - pois["psnr"]
    return (
        f"splat: poisoned model renders its inputs at {pois['psnr']:.1f} dB PSNR / SSIM {pois['ssim']:.3f}"
        f" vs clean {clean['psnr']:.1f} dB / {clean['ssim']:.3f} ({drop:.1f} dB worse)"
    )


def _run_planned_side(plan: ProfilePlan, side: str, run: VerifyRun) -> dict[str, Any]:
    """One side of one profile, once a slot is free: its images (the published round trip), its SfM
    (a clean result reused when cached), its poses under the originals' names. A cancelled
    verification starts no more sides."""
    if cancelled(run.options):
        return {"outcome": "cancelled", "error": "cancelled"}
    plan.started[side] = time.time()
    planned = plan.sides[side]
    if plan.profile == "published":
        o = run.options
        source = run.clean_dir if side == "clean" else run.poisoned_dir
        with path_lock(planned.image_dir):  # the poisoned runs of several seeds share one round trip
            round_trip(source, planned.image_dir, run.names, o.published_long_edge, o.published_jpeg_quality)
    result = run_side(planned, run.options, run.board)
    if side == "clean" and plan.clean_model_copy is not None and result.get("outcome") != "cancelled":
        _copy_model(planned.model_dir, plan.clean_model_copy)
    if plan.profile == "published":
        result["poses"] = unpublish_names(result.get("poses", {}), run.names)
        result["left_out"] = list(unpublish_names(dict.fromkeys(result.get("left_out") or ()), run.names))
    return result


def _profiles_as_done(sides: dict[tuple[str, str], Future[dict[str, Any]]]) -> Iterator[str]:
    """Each profile once both its sides are done (a side that raised counts as done), as they end."""
    left = Counter(profile for profile, _ in sides)
    owner = {future: profile for (profile, _), future in sides.items()}
    for future in as_completed(owner):
        profile = owner[future]
        left[profile] -= 1
        if left[profile] == 0:
            yield profile


def _compare_poses(
    clean: dict[str, Any], poisoned: dict[str, Any], run: VerifyRun
) -> tuple[dict[str, Any] | None, dict[str, Any] | None, dict[str, Any] | None]:
    """(poisoned vs clean, clean vs ground truth, poisoned vs ground truth); None where a side failed."""
    vs_clean = clean_vs_gt = poisoned_vs_gt = None
    clean_poses = posemod.poses_from_json(clean.get("poses", {}))
    pois_poses = posemod.poses_from_json(poisoned.get("poses", {}))
    if clean.get("outcome") == "ok" and poisoned.get("outcome") == "ok":
        vs_clean = posemod.compare_poses(pois_poses, clean_poses)
    if run.gt is not None:
        gt_here = {n: p for n, p in run.gt.items() if n in run.names}
        if clean.get("outcome") == "ok":
            clean_vs_gt = posemod.compare_poses(clean_poses, gt_here)
        if poisoned.get("outcome") == "ok":
            poisoned_vs_gt = posemod.compare_poses(pois_poses, gt_here)
    return vs_clean, clean_vs_gt, poisoned_vs_gt


def _decide_profile(
    plan: ProfilePlan, clean: dict[str, Any], poisoned_runs: list[dict[str, Any]], run: VerifyRun
) -> ProfileReport:
    """One attacker: each poisoned run's poses compared with the clean ones, the verdict of the run
    the attacker would keep (the weakest: verdict.worst_seed, when options.seeds > 1); written to
    <profile>/report.json."""
    profile = plan.profile
    started = min(plan.started.values(), default=time.time())
    rule = run.options.rule
    compared = [_compare_poses(clean, poisoned, run) for poisoned in poisoned_runs]
    decisions = [decide(clean, r, vs[0], rule) for r, vs in zip(poisoned_runs, compared, strict=True)]
    within = f"frac_within_{rule.threshold_deg}deg"
    fractions = [vs[0].get(within) if vs[0] else None for vs in compared]
    pick = worst_seed(decisions, fractions)
    poisoned, decision = poisoned_runs[pick], decisions[pick]
    vs_clean, clean_vs_gt, poisoned_vs_gt = compared[pick]
    seeds, reasons = None, decision.reasons
    left = sorted({*left_out_of([clean, *poisoned_runs]), *run.options.not_staged})
    if left:  # its figures are over the others (a black-box review: "6/6 images" for a set of 8)
        reasons = [*reasons, left_out_line(left, len(run.names) + len(run.options.not_staged))]
    if len(poisoned_runs) > 1:
        models = poisoned_sides(len(poisoned_runs))  # each run's model folder under the profile's
        seeds = [{"seed": r.get("random_seed"), "outcome": r.get("outcome"), "verdict": str(d.verdict),
                  "frac_within": f, "registered": r.get("registered"), "model": m}
                 for r, d, f, m in zip(poisoned_runs, decisions, fractions, models, strict=True)]  # fmt: skip
        reasons = [seeds_sentence(seeds, rule.threshold_deg), *reasons]
    profile_dir = run.out_dir / profile
    report = ProfileReport(
        profile=profile,
        verdict=decision.verdict,
        reasons=reasons,
        clean=_summary(clean),
        poisoned=_summary(poisoned),
        vs_clean=vs_clean,
        clean_vs_gt=clean_vs_gt,
        poisoned_vs_gt=poisoned_vs_gt,
        model_dir=str(profile_dir),
        started_at=started,
        finished_at=time.time(),
        seeds=seeds,
        left_out=left,
    )
    write_json(profile_dir / "report.json", report.to_dict())
    log.info("profile verified", extra={"profile": profile, "verdict": report.verdict})
    if run.board is not None:
        run.board.finish(profile, str(report.verdict))
    return report


def seeds_sentence(seeds: list[dict[str, Any]], threshold_deg: int) -> str:
    """What a profile's several poisoned runs found, in one line (its first reason)."""
    def figure(e: dict[str, Any]) -> str:
        return f"{e['frac_within']:.0%}" if e["frac_within"] is not None else verdict_words(e["verdict"])

    runs = ", ".join(f"seed {e['seed']}: {figure(e)}" for e in seeds)
    return (f"the weakest of {len(seeds)} COLMAP runs on the patched set, as an attacker keeps the best "
            f"({runs} of the clean cameras within {threshold_deg} deg)")  # fmt: skip


def _copy_model(src: Path, dst: Path) -> None:
    """A model folder's files (COLMAP's .bin / .txt and ppd's result.json) into dst."""
    dst.mkdir(parents=True, exist_ok=True)
    for f in src.iterdir():
        if f.is_file() and (f.suffix in (".bin", ".txt") or f.name == "result.json"):
            shutil.copyfile(f, dst / f.name)
