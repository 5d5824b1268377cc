"""Automatic mode: pick, per dataset, the least visible candidate patch that Verifier I confirms.

`preflight(images, ladder, budget, options, out_dir)`, one named step each:
1. `prepare_sample`: an evenly spaced sample of the dataset (`options.sample_size` photos, by name;
   HEIC and AVIF too: COLMAP is given them as `ppd verify` gives them, verifier.pairs);
2. `measure_ladder`: poison the sample with every candidate of the ladder and MEASURE what a viewer
   sees on this dataset: FLIP (verifier.visibility) at the budget's display width, the noticeable
   area (FLIP > 0.5), the 99.9th percentile against a JPEG q85 re-encode of the same image, whether
   the change stays in one corner; the worst image of the sample counts. Whole-image SSIM (as 3DGS)
   and LPIPS-VGG are measured too and reported (the paper's cost2); they do not gate. The ladder's
   own order is design intent only and is never trusted for the budget;
3. candidates over the visibility budget (verifier.auto_options.VisibilityBudget) are skipped and
   recorded as such;
4. `walk_candidates`: the others, least visible first, go through Verifier I (real COLMAP in child
   processes) under every profile of the options; the clean SfM runs once (clean_cache_dir) and a
   candidate stops at its first profile that is not `protected`;
5. `decide`: the first candidate `protected` under every profile is chosen; the preflight stops at
   its time budget and says so; every candidate tried leaves its evidence in the decision.

The visibility measures live in verifier.auto_visibility; what a preflight takes (budget, options,
job) in verifier.auto_options.

Runs as a child process for the daemon: `python -m verifier.auto_search JOB.json` (see `main`; the job is a
`PreflightJob`, the result an `AutoDecision` or `{"error": ...}`, JSON both ways through msgspec).
torch (LPIPS) is imported only when LPIPS is measured; pycolmap only in the SfM grandchildren.
"""

from __future__ import annotations

import logging
import shutil
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from poisoner.atomic import atomic_write_bytes
from poisoner.errors import PpdError
from poisoner.media import SFM_SUFFIXES, image_format, is_sfm_readable, read_head
from poisoner.scratch import owned_temp_dir
from poisoner.spec import PatchSpec
from verifier.auto_options import (
    MIN_SAMPLE,
    CandidateStatus,
    LadderEntry,
    Outcome,
    PreflightInputError,
    PreflightJob,
    PreflightOptions,
    VisibilityBudget,
)
from verifier.auto_visibility import (
    SampleVisibility,
    budget_notes,
    budget_use,
    jpeg_reference_p999,
    load_rgb8,
    measure_image,
    open_lpips,
    summarise_visibility,
    within_budget,
)
from verifier.pairs import link_or_copy, stage_photos
from verifier.verdict import INCONCLUSIVE as INCONCLUSIVE_VERDICT
from verifier.verdict import PROTECTED as PROTECTED_VERDICT

if TYPE_CHECKING:
    from poisoner.ladder import Candidate

log = logging.getLogger(__name__)

NO_CANDIDATE = "no candidate within the visibility budget protects this dataset"
STAGED_SAMPLE = "sample-staged"  # the clean sample as COLMAP is given it (verifier.pairs.stage_photos)


# ---- evidence and decision ------------------------------------------------------------------------
OVER_BUDGET, PROTECTED = CandidateStatus.OVER_BUDGET, CandidateStatus.PROTECTED
NOT_PROTECTED, INCONCLUSIVE = CandidateStatus.NOT_PROTECTED, CandidateStatus.INCONCLUSIVE
NOT_REACHED, TIMED_OUT = CandidateStatus.NOT_REACHED, CandidateStatus.TIMED_OUT
NOT_NEEDED, FAILED = CandidateStatus.NOT_NEEDED, CandidateStatus.FAILED


class ProfileEvidence(msgspec.Struct):
    """One profile's Verifier I result for a candidate, as the decision keeps it."""

    verdict: str
    frac_within_5deg: float | None = None
    median_rotation_error_deg: float | None = None
    clean_registered: int | None = None
    poisoned_registered: int | None = None
    num_images: int | None = None
    crashes: list[Any] = []
    reasons: list[str] = []
    seconds: float = 0.0


class CandidateEvidence(msgspec.Struct):
    name: str
    why: str
    spec: PatchSpec
    spec_id: str
    status: CandidateStatus = CandidateStatus.NOT_REACHED
    visibility: SampleVisibility | None = None
    budget_use: float | None = None  # the largest fraction of a budget limit used: <= 1 fits
    within_budget: bool = False  # budget_use <= 1 and, with corner_only, inside one corner
    budget_notes: list[str] = []
    profiles: dict[str, ProfileEvidence] = {}
    seconds: float = 0.0
    error: str | None = None


class InterimMeasure(msgspec.Struct):
    """One candidate measured for the interim choice (no SfM)."""

    name: str
    spec_id: str | None = None
    error: str | None = None  # it could not be applied to these files
    within_budget: bool = False
    budget_use: float | None = None
    visibility: SampleVisibility | None = None


class InterimChoice(msgspec.Struct):
    """The interim choice: the strongest candidate within the budget, else the least visible one."""

    chosen: str
    within_budget: bool
    measured: list[InterimMeasure]


class AutoDecision(msgspec.Struct):
    chosen: str | None
    spec: PatchSpec | None
    spec_id: str | None
    reason: str
    outcome: Outcome
    lpips_checked: bool  # LPIPS is reported only; False says it could not be measured here
    lpips_note: str | None
    budget: VisibilityBudget
    options: PreflightOptions
    sample: list[str]
    elapsed_s: float
    evidence: list[CandidateEvidence]


# ---- sample ---------------------------------------------------------------------------------------
ImageInput = Path | tuple[Path, str]


def normalise_inputs(pairs_or_images: Sequence[ImageInput]) -> list[tuple[Path, str]]:
    """(source file, name) for each input; a bare Path is named by its file name. The name matters:
    poisoners pick the format by suffix, and a moving patch places itself by the name."""
    out: list[tuple[Path, str]] = []
    for item in pairs_or_images:
        if isinstance(item, tuple):
            out.append((Path(item[0]), str(item[1])))
        else:
            out.append((Path(item), Path(item).name))
    return out


def in_sample(src: Path, name: str) -> bool:
    """Whether a photo may be sampled: COLMAP reads it by its name, or its first bytes (src's: a vault
    original has no suffix) say it is a photo ppd patches (an iPhone's HEIC, AVIF, a JPEG under
    another name), which COLMAP is given as `ppd verify` gives it (verifier.pairs.staged_as)."""
    return is_sfm_readable(name) or image_format(read_head(src)) is not None


def choose_sample(items: Sequence[tuple[Path, str]], size: int) -> list[tuple[Path, str]]:
    """An evenly spaced sample by name (deterministic; spans the capture, as a walk around does)."""
    usable = sorted(
        {name: (src, name) for src, name in items if in_sample(src, name)}.values(),
        key=lambda t: t[1],
    )
    if len(usable) < MIN_SAMPLE:
        raise PreflightInputError(
            f"need at least {MIN_SAMPLE} images COLMAP can read ({', '.join(sorted(SFM_SUFFIXES))}; "
            f"HEIC and AVIF converted), got {len(usable)}"
        )
    if len(usable) <= size:
        return usable
    idx = sorted({round(i * (len(usable) - 1) / (size - 1)) for i in range(size)})
    return [usable[i] for i in idx]


def prepare_sample(pairs_or_images: Sequence[ImageInput], size: int, out_dir: Path) -> tuple[Path, list[str]]:
    """The sample linked (or copied) under its names into out_dir/sample: (that folder, the names).
    The files as they are (a HEIC a HEIC): what the candidates are poisoned onto and measured on."""
    sample = choose_sample(normalise_inputs(pairs_or_images), size)
    clean_dir = out_dir / "sample"
    shutil.rmtree(clean_dir, ignore_errors=True)
    clean_dir.mkdir(parents=True)
    for src, name in sample:
        link_or_copy(src, clean_dir / name)
    return clean_dir, [name for _, name in sample]


# ---- step 2: measure every candidate ---------------------------------------------------------------
def _candidate_dir(out_dir: Path, index: int, name: str) -> Path:
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
    return out_dir / "candidates" / f"{index:02d}-{safe}"


def measure_ladder(
    ladder: Sequence[Candidate | LadderEntry],
    clean_dir: Path,
    names: list[str],
    budget: VisibilityBudget,
    lpips_model: Any,
    out_dir: Path,
) -> list[CandidateEvidence]:
    """Every candidate's visibility on the sample; those over the budget are marked OVER_BUDGET."""
    jpeg = {name: jpeg_reference_p999(load_rgb8(clean_dir / name), budget) for name in names}
    folders = [_candidate_dir(out_dir, i, c.name) / "images" for i, c in enumerate(ladder)]
    evidence = [
        _measure(c, folder, clean_dir, names, lpips_model, budget, jpeg)
        for c, folder in zip(ladder, folders, strict=True)
    ]
    for e in evidence:
        if e.status != FAILED and not e.within_budget:
            e.status = OVER_BUDGET
    return evidence


def _measure(
    candidate: Candidate | LadderEntry,
    images: Path,
    clean_dir: Path,
    names: list[str],
    lpips_model: Any,
    budget: VisibilityBudget,
    jpeg_p999: dict[str, float],
) -> CandidateEvidence:
    """Poison the sample with one candidate into `images` and measure its visibility."""
    from poisoner.formats import poison_file

    spec = candidate.spec
    e = CandidateEvidence(candidate.name, candidate.why, spec, spec.spec_id)
    t0 = time.monotonic()
    shutil.rmtree(images, ignore_errors=True)
    images.mkdir(parents=True)
    per_image = []
    name = ""
    try:
        for name in names:
            poison_file(clean_dir / name, images / name, spec)
            clean, poisoned = load_rgb8(clean_dir / name), load_rgb8(images / name)
            per_image.append(measure_image(clean, poisoned, budget, lpips_model, jpeg_p999.get(name)))
    except Exception as exc:  # a candidate that cannot be applied here is recorded, not fatal
        e.status, e.error = FAILED, str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        where = {"candidate": candidate.name, "file": name, "error": e.error}
        log.info("candidate not measurable", extra=where)
        shutil.rmtree(images, ignore_errors=True)
        return e
    e.visibility = summarise_visibility(per_image)
    e.budget_use = round(budget_use(e.visibility, budget), 4)
    e.within_budget = within_budget(e.visibility, budget)
    e.budget_notes = budget_notes(e.visibility, budget)
    e.seconds = round(time.monotonic() - t0, 2)
    if not e.within_budget:
        shutil.rmtree(images, ignore_errors=True)
    return e


# ---- step 4: verify the candidates within the budget -------------------------------------------------
class WalkResult(msgspec.Struct):
    chosen: CandidateEvidence | None = None
    stopped_by_time: bool = False
    clean_failed: bool = False


def walk_candidates(
    evidence: list[CandidateEvidence],
    clean_dir: Path,
    names: list[str],
    out_dir: Path,
    options: PreflightOptions,
    deadline: float,
) -> WalkResult:
    """Verifier I on the candidates within the budget, least visible first, until one is protected
    under every profile, the time budget runs out, or the clean sample proves unreconstructable.
    COLMAP is given the sample staged once into out_dir/STAGED_SAMPLE (verifier.pairs.stage_photos)."""
    order = sorted((e for e in evidence if e.within_budget and e.status != FAILED),
                   key=lambda e: e.budget_use or 0.0)  # fmt: skip
    walk = WalkResult()
    if not order:
        return walk
    staged_clean = out_dir / STAGED_SAMPLE
    shutil.rmtree(staged_clean, ignore_errors=True)  # a killed run's, of another sample maybe
    stage_photos([(clean_dir / name, name) for name in names], staged_clean)
    cancel = threading.Event()
    timer = threading.Timer(max(0.0, deadline - time.monotonic()), cancel.set)
    timer.daemon = True
    timer.start()
    try:
        for e in order:
            if walk.chosen is not None:
                e.status = NOT_NEEDED
                continue
            if walk.stopped_by_time or walk.clean_failed or time.monotonic() >= deadline:
                walk.stopped_by_time = walk.stopped_by_time or not walk.clean_failed
                continue  # stays NOT_REACHED
            cand_dir = _candidate_dir(out_dir, evidence.index(e), e.name)
            _verify_candidate(e, staged_clean, cand_dir, names, out_dir, options, deadline, cancel)
            if e.status == PROTECTED:
                walk.chosen = e
            elif e.status == TIMED_OUT:
                walk.stopped_by_time = True
            elif e.status == INCONCLUSIVE:
                walk.clean_failed = True  # the clean sample itself does not reconstruct: same for all
    finally:
        timer.cancel()
    return walk


def _verify_candidate(
    e: CandidateEvidence,
    staged_clean: Path,
    cand_dir: Path,
    names: list[str],
    out_dir: Path,
    options: PreflightOptions,
    deadline: float,
    cancel: threading.Event,
) -> None:
    """Verifier I, one profile at a time, on the candidate's poisoned sample staged as the clean one
    (staged_clean); stops at the first profile that is not protected."""
    from verifier.verification import VerifyOptions, verify_folders

    t0 = time.monotonic()
    images, staged, verify_dir = cand_dir / "images", cand_dir / "staged", cand_dir / "verify"
    status = PROTECTED
    try:
        shutil.rmtree(staged, ignore_errors=True)  # a killed run's
        stage_photos([(images / name, name) for name in names], staged)
        for profile in options.profiles:
            remaining = deadline - time.monotonic()
            if remaining <= 1 or cancel.is_set():
                status = TIMED_OUT
                break
            vopts = VerifyOptions(
                timeout_s=remaining, crash_retries=options.crash_retries, cancel=cancel,
                camera_params=options.camera_params,
                clean_cache_dir=out_dir / "clean-cache", keep_cache=True,  # poisoned features reused
            )  # fmt: skip
            report = verify_folders(staged_clean, staged, verify_dir, [profile], vopts).profiles[profile]
            e.profiles[profile] = _profile_evidence(report)
            if cancel.is_set():
                status = TIMED_OUT
                break
            if report.verdict == PROTECTED_VERDICT:
                continue
            status = INCONCLUSIVE if report.verdict == INCONCLUSIVE_VERDICT else NOT_PROTECTED
            break
    finally:
        shutil.rmtree(verify_dir / ".cache", ignore_errors=True)
        shutil.rmtree(staged, ignore_errors=True)  # links, or PNGs of the HEICs kept in images
        if not options.keep_images:
            shutil.rmtree(images, ignore_errors=True)
    e.status = status
    e.seconds = round(e.seconds + time.monotonic() - t0, 2)


def _profile_evidence(report: Any) -> ProfileEvidence:
    vs = report.vs_clean or {}
    return ProfileEvidence(
        verdict=str(report.verdict),
        frac_within_5deg=vs.get("frac_within_5deg"),
        median_rotation_error_deg=vs.get("median_rotation_error_deg"),
        clean_registered=report.clean.get("registered"),
        poisoned_registered=report.poisoned.get("registered"),
        num_images=report.clean.get("num_images"),
        crashes=report.poisoned.get("crashes") or [],
        reasons=list(report.reasons)[:3],
        seconds=round(report.finished_at - report.started_at, 1),
    )


# ---- step 5: the decision ---------------------------------------------------------------------------
def _pct(x: Any) -> str:
    return "n/a" if x is None else f"{100 * float(x):.0f}%"


def _chosen_reason(chosen: CandidateEvidence, budget: VisibilityBudget, failed: list[str]) -> str:
    per = ", ".join(
        f"{p} {_pct(v.frac_within_5deg)} of cameras within 5 deg" for p, v in chosen.profiles.items()
    )
    return (
        f"{chosen.name}: the least visible candidate within the budget ({budget.describe()}) that Verifier I "
        f"confirms protected under every profile it ran ({per}){_visibility_text(chosen.visibility)}."
        + (f" Less visible but not protected: {', '.join(failed)}." if failed else "")
    )


def _visibility_text(vis: SampleVisibility | None) -> str:
    """What a viewer sees of the worst sample image, then the paper's figures (reported only)."""
    if vis is None:
        return ""
    text = f"; worst sample image: {vis.noticeable_area_max:.2%} noticeably changed"
    text += f", FLIP p99.9 {vis.flip_p999_max:.2f}"
    if vis.p999_vs_jpeg_max is not None:
        text += f" ({vis.p999_vs_jpeg_max:.1f}x a JPEG q85 re-encode's)"
    if vis.ssim_min is not None:
        text += f", SSIM {vis.ssim_min:.4f}"
    if vis.lpips_max is not None:
        text += f", LPIPS {vis.lpips_max:.4f}"
    return text


def _reason(
    walk: WalkResult, evidence: list[CandidateEvidence], budget: VisibilityBudget, options: PreflightOptions
) -> tuple[Outcome, str]:
    over = [e.name for e in evidence if e.status == OVER_BUDGET]
    failed = [e.name for e in evidence if e.status == NOT_PROTECTED]
    if walk.chosen is not None:
        return Outcome.CHOSEN, _chosen_reason(walk.chosen, budget, failed)
    tail = (f" Over the budget: {', '.join(over)}." if over else "") + (
        f" Not protected: {', '.join(failed)}." if failed else ""
    )
    if walk.clean_failed:
        return Outcome.INCONCLUSIVE, (
            "inconclusive: COLMAP does not reconstruct the clean sample itself, so no candidate can be "
            "confirmed (never called protected on that basis)." + tail
        )
    if walk.stopped_by_time:
        left = [e.name for e in evidence if e.status in (NOT_REACHED, TIMED_OUT)]
        return Outcome.TIME_BUDGET, (
            f"stopped at the time budget ({options.time_budget_s:.0f} s) before any candidate was confirmed; "
            f"not verified: {', '.join(left)}." + tail
        )
    return Outcome.NONE_WITHIN_BUDGET, f"{NO_CANDIDATE} ({budget.describe()})." + tail


def decide(
    walk: WalkResult,
    evidence: list[CandidateEvidence],
    budget: VisibilityBudget,
    options: PreflightOptions,
    names: list[str],
    lpips_note: str | None,
    elapsed_s: float,
) -> AutoDecision:
    outcome, reason = _reason(walk, evidence, budget, options)
    if lpips_note is not None:
        reason += f" LPIPS not measured (reported only, not part of the budget): {lpips_note}."
    spec = walk.chosen.spec if walk.chosen else None
    return AutoDecision(
        chosen=walk.chosen.name if walk.chosen else None, spec=spec, spec_id=spec.spec_id if spec else None,
        reason=reason, outcome=outcome, lpips_checked=lpips_note is None, lpips_note=lpips_note,
        budget=budget, options=options, sample=names, elapsed_s=round(elapsed_s, 1), evidence=evidence,
    )  # fmt: skip


# ---- the interim choice (no SfM) ----------------------------------------------------------------------
def _measure_on(
    spec: PatchSpec, clean_dir: Path, out_dir: Path, names: Sequence[str], budget: VisibilityBudget,
    jpeg_p999: dict[str, float],
) -> SampleVisibility:  # fmt: skip
    """One spec poisoned onto the clean files into out_dir and measured (no LPIPS)."""
    from poisoner.formats import poison_file

    out_dir.mkdir()
    per_image = []
    for name in names:
        poison_file(clean_dir / name, out_dir / name, spec)
        clean, poisoned = load_rgb8(clean_dir / name), load_rgb8(out_dir / name)
        per_image.append(measure_image(clean, poisoned, budget, None, jpeg_p999.get(name)))
    return summarise_visibility(per_image)


def choose_interim(
    ladder: Sequence[Candidate | LadderEntry], budget: VisibilityBudget, images: Sequence[tuple[Path, str]]
) -> InterimChoice:
    """The strongest candidate (latest in the ladder) within the visibility budget on images; with
    none within it, the least visible one measured (within_budget False: the caller says so)."""
    measured: list[InterimMeasure] = []
    with owned_temp_dir(".ppd-auto-") as tmp:  # copies of the originals: swept if this process is killed
        clean_dir = Path(tmp) / "clean"
        clean_dir.mkdir()
        for src, name in images:
            link_or_copy(src, clean_dir / name)
        names = [name for _, name in images]
        gate_jpeg = budget.max_p999_vs_jpeg > 0  # one more FLIP per file: only when it decides
        jpeg = {n: jpeg_reference_p999(load_rgb8(clean_dir / n), budget) for n in names} if gate_jpeg else {}
        for index in range(len(ladder) - 1, -1, -1):
            cand = ladder[index]
            try:
                vis = _measure_on(cand.spec, clean_dir, Path(tmp) / str(index), names, budget, jpeg)
            except Exception as exc:  # does not fit these images: recorded, next one
                why = (str(exc) or type(exc).__name__).splitlines()[0]
                log.info("candidate not measurable", extra={"candidate": cand.name, "error": why})
                measured.append(InterimMeasure(cand.name, error=why))
                continue
            fits = within_budget(vis, budget)
            measured.append(InterimMeasure(cand.name, cand.spec.spec_id, None, fits,
                                           round(budget_use(vis, budget), 4), vis))  # fmt: skip
            if fits:
                return InterimChoice(cand.name, True, measured)
    usable = [m for m in measured if m.budget_use is not None]
    if not usable:
        raise PreflightInputError("no candidate of the ladder applies to these images")
    return InterimChoice(min(usable, key=lambda m: m.budget_use or 0.0).name, False, measured)


# ---- the preflight ----------------------------------------------------------------------------------
def preflight(
    pairs_or_images: Sequence[ImageInput],
    ladder: Sequence[Candidate | LadderEntry],
    budget: VisibilityBudget,
    options: PreflightOptions,
    out_dir: Path,
) -> AutoDecision:
    """Measure every candidate's visibility on a sample, then verify the ones within the budget,
    least visible first, until one is `protected` under every profile (see the module docstring).
    Writes out_dir/decision.json."""
    started = time.monotonic()
    deadline = started + options.time_budget_s
    out_dir = Path(out_dir)
    if not ladder:
        raise PreflightInputError("the candidate ladder is empty")
    clean_dir, names = prepare_sample(pairs_or_images, options.sample_size, out_dir)
    try:
        lpips_model, lpips_note = open_lpips(options.lpips_net)
        evidence = measure_ladder(ladder, clean_dir, names, budget, lpips_model, out_dir)
        walk = walk_candidates(evidence, clean_dir, names, out_dir, options, deadline)
    finally:
        shutil.rmtree(clean_dir, ignore_errors=True)
        shutil.rmtree(out_dir / STAGED_SAMPLE, ignore_errors=True)
    decision = decide(walk, evidence, budget, options, names, lpips_note, time.monotonic() - started)
    written = msgspec.json.format(msgspec.json.encode(decision), indent=1)
    atomic_write_bytes(out_dir / "decision.json", written)
    log.info("preflight decided", extra={"chosen": decision.chosen, "outcome": str(decision.outcome),
                                         "elapsed_s": decision.elapsed_s})  # fmt: skip
    return decision


# ---- child process entry ------------------------------------------------------------------------------
def run_job(job: PreflightJob) -> AutoDecision | InterimChoice:
    """A preflight (or, mode "interim", the interim choice) described by a job: what the daemon's
    child runs. Without a ladder, poisoner.ladder's."""
    if job.ladder is not None:
        ladder: list[Any] = list(job.ladder)
    else:
        from poisoner.ladder import candidate_ladder

        ladder = list(candidate_ladder())
    exclude = set(job.exclude)
    ladder = [c for c in ladder if c.name not in exclude]
    images = [(Path(src), name) for src, name in job.images]
    if job.mode == "interim":
        return choose_interim(ladder, job.budget, images)
    return preflight(images, ladder, job.budget, job.options, Path(job.out_dir))


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m verifier.auto_search JOB.json`: writes the decision (or interim choice) JSON to job.result
    (atomically); {"error": ...} when the job cannot run."""
    from verifier.supervise import adopt_child_setup

    adopt_child_setup()
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print("usage: python -m verifier.auto_search JOB.json", file=sys.stderr)
        return 2
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s %(message)s")
    try:
        job = msgspec.json.decode(Path(args[0]).read_bytes(), type=PreflightJob)
    except (OSError, msgspec.DecodeError) as exc:
        print(f"bad preflight job: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    try:
        result: Any = run_job(job)
    except (PreflightInputError, PpdError, ValueError, OSError) as exc:  # PpdError: a photo not decoded
        result = {"error": str(exc).splitlines()[0] if str(exc) else type(exc).__name__}
    atomic_write_bytes(Path(job.result), msgspec.json.encode(result))
    return 1 if isinstance(result, dict) else 0


if __name__ == "__main__":
    sys.exit(main())
