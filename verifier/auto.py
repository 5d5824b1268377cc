"""Automatic mode: pick, per dataset, the least visible candidate patch that Verifier I confirms.

`preflight(images, ladder, budget, options, out_dir)`:
1. take an evenly spaced sample of the dataset (`PreflightOptions.sample_size` images, by name);
2. poison the sample with every candidate of the ladder and MEASURE its visibility on this
   dataset (whole-image SSIM as 3DGS and LPIPS-VGG, clean vs poisoned, worst image of the sample);
   the ladder's own order is design intent only and is never trusted for the budget;
3. candidates over the visibility budget are skipped (and recorded as such);
4. the others, least visible first, go through Verifier I (real COLMAP in child processes) under
   every profile of the options; the clean SfM runs once (clean_cache_dir) and a candidate stops at
   its first profile that is not `protected`;
5. the first candidate `protected` under every profile is chosen; the preflight stops at its time
   budget and says so; every candidate tried leaves its evidence in the decision.

When the LPIPS weights are not installed, the LPIPS half of the budget cannot be checked: the
decision says so (`lpips_checked=False` and a sentence in the reason), it never pretends.

Runs as a child process for the daemon: `python -m verifier.auto JOB.json` (see `main`). torch
(LPIPS) is imported only when LPIPS is measured; pycolmap only in the SfM grandchildren.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import PIL.Image  # before anything that could bring pycolmap here (pillow 13 + pycolmap 4.2.1)

from poisoner.media import SFM_SUFFIXES, is_sfm_readable
from poisoner.spec import PatchSpec
from verifier.metrics import ssim_map

if TYPE_CHECKING:
    from poisoner.ladder import Candidate

log = logging.getLogger(__name__)

NO_CANDIDATE = "no candidate within the visibility budget protects this dataset"
# Formats COLMAP reads (the sample must be SfM-able); others are left out of the preflight.
SSIM_RADIUS = 5  # 3DGS SSIM: 11 x 11 window


class PreflightInputError(ValueError):
    """A sample that cannot be preflighted (message = one clear line)."""


# ---- options ------------------------------------------------------------------------------------
@dataclass
class VisibilityBudget:
    """How visible a patch may be, clean vs poisoned, on the whole image (the issue's default)."""

    min_ssim: float = 0.99
    max_lpips: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 < self.min_ssim <= 1.0:
            raise PreflightInputError(f"min SSIM must be in (0, 1], got {self.min_ssim}")
        if not self.max_lpips >= 0.0:
            raise PreflightInputError(f"max LPIPS must be >= 0, got {self.max_lpips}")


@dataclass
class PreflightOptions:
    sample_size: int = 12
    time_budget_s: float = 900.0
    profiles: tuple[str, ...] = ("default", "hardened")
    lpips_net: str = "vgg"
    crash_retries: int = 1  # as Verifier I: a crashed SfM is rerun once with another seed
    keep_images: bool = False  # keep each candidate's poisoned sample (inspection)
    # known intrinsics "fx,fy,cx,cy,k1,k2,p1,p2" as Verifier I takes them; None = COLMAP estimates
    # the focal length, where pycolmap 4.2.1 can segfault on poisoned sets (recorded as a crash)
    camera_params: str | None = None

    def __post_init__(self) -> None:
        if self.sample_size < 3:
            raise PreflightInputError(f"sample size must be at least 3 (SfM), got {self.sample_size}")
        if self.time_budget_s <= 0:
            raise PreflightInputError(f"time budget must be positive, got {self.time_budget_s}")
        self.profiles = tuple(self.profiles)


# ---- evidence and decision ------------------------------------------------------------------------
# status of one candidate in a preflight
OVER_BUDGET = "over_budget"
PROTECTED = "protected"
NOT_PROTECTED = "not_protected"  # some profile was weak / not_protected / crashed
INCONCLUSIVE = "inconclusive"  # the clean reference failed: no claim either way
NOT_REACHED = "not_reached"  # the time budget ran out before its turn
TIMED_OUT = "timed_out"  # the time budget ran out during its verification
NOT_NEEDED = "not_needed"  # a less visible candidate was already confirmed
FAILED = "failed"  # it could not be applied to this dataset (e.g. does not fit the images)


@dataclass
class CandidateEvidence:
    name: str
    why: str
    spec: dict[str, Any]
    spec_id: str
    status: str = NOT_REACHED
    visibility: dict[str, Any] = field(default_factory=dict)  # ssim_min/mean, lpips_max/mean
    budget_use: float | None = None  # max((1-ssim)/(1-min_ssim), lpips/max_lpips): <= 1 fits
    budget_notes: list[str] = field(default_factory=list)
    profiles: dict[str, dict[str, Any]] = field(default_factory=dict)  # verdict, frac_within_5deg
    seconds: float = 0.0
    error: str | None = None

    @property
    def within_budget(self) -> bool:
        return self.budget_use is not None and self.budget_use <= 1.0

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CandidateEvidence:
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})


@dataclass
class AutoDecision:
    chosen: str | None
    spec: PatchSpec | None
    reason: str
    evidence: list[CandidateEvidence]
    outcome: str  # "chosen" | "none_within_budget" | "time_budget" | "inconclusive"
    lpips_checked: bool
    lpips_note: str | None
    budget: VisibilityBudget
    options: PreflightOptions
    sample: list[str]
    elapsed_s: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "chosen": self.chosen,
            "spec": self.spec.to_dict() if self.spec else None,
            "spec_id": self.spec.spec_id if self.spec else None,
            "reason": self.reason,
            "outcome": self.outcome,
            "lpips_checked": self.lpips_checked,
            "lpips_note": self.lpips_note,
            "budget": dataclasses.asdict(self.budget),
            "options": dataclasses.asdict(self.options),
            "sample": self.sample,
            "elapsed_s": self.elapsed_s,
            "evidence": [e.to_dict() for e in self.evidence],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AutoDecision:
        options = dict(data["options"])
        options["profiles"] = tuple(options.get("profiles", ()))
        return cls(
            chosen=data["chosen"],
            spec=PatchSpec.from_dict(data["spec"]) if data.get("spec") else None,
            reason=data["reason"],
            evidence=[CandidateEvidence.from_dict(e) for e in data["evidence"]],
            outcome=data["outcome"],
            lpips_checked=bool(data["lpips_checked"]),
            lpips_note=data.get("lpips_note"),
            budget=VisibilityBudget(**data["budget"]),
            options=PreflightOptions(**options),
            sample=list(data["sample"]),
            elapsed_s=float(data["elapsed_s"]),
        )


# ---- visibility -----------------------------------------------------------------------------------
def load_rgb(path: Path) -> np.ndarray:
    """H x W x 3 float in [0, 1]; transparency composited on white (as Verifier I's round trip)."""
    from verifier.verification import to_rgb

    with PIL.Image.open(path) as im:
        im.load()
        rgb = to_rgb(im)
    return np.asarray(rgb, dtype=np.float64) / 255.0


def changed_box(a: np.ndarray, b: np.ndarray) -> tuple[int, int, int, int] | None:
    """(y0, x0, y1, x1), exclusive ends, of the pixels where a and b differ; None when identical."""
    diff = np.any(a != b, axis=2) if a.ndim == 3 else a != b
    rows, cols = np.flatnonzero(diff.any(axis=1)), np.flatnonzero(diff.any(axis=0))
    if rows.size == 0:
        return None
    return int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1


def whole_image_ssim(clean: np.ndarray, poisoned: np.ndarray) -> float:
    """`verifier.metrics.ssim` over the whole image, computed only around the change.

    Why: a patch changes a few thousand pixels of a 6-megapixel photo. Where both windows see
    identical pixels the SSIM map is exactly 1, so the whole-image mean is 1 minus the deficit
    summed over the changed box grown by the window radius; the crop keeps one more radius of
    real context so every window in that box sees what it sees in the full image (crop edges
    inside the image never reach the summed pixels; edges on the image border pad with zeros
    exactly as the full computation does). Equal to the full computation (tested)."""
    a, b = np.asarray(clean, dtype=np.float64), np.asarray(poisoned, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    box = changed_box(a, b)
    if box is None:
        return 1.0
    h, w, c = a.shape
    y0, x0, y1, x1 = box
    r = SSIM_RADIUS
    sy0, sx0, sy1, sx1 = max(0, y0 - r), max(0, x0 - r), min(h, y1 + r), min(w, x1 + r)
    cy0, cx0, cy1, cx1 = max(0, sy0 - r), max(0, sx0 - r), min(h, sy1 + r), min(w, sx1 + r)
    smap = ssim_map(a[cy0:cy1, cx0:cx1], b[cy0:cy1, cx0:cx1])
    inner = smap[sy0 - cy0 : sy1 - cy0, sx0 - cx0 : sx1 - cx0]
    return float(1.0 - np.sum(1.0 - inner) / (h * w * c))


def visibility(clean: np.ndarray, poisoned: np.ndarray, lpips_model: Any) -> dict[str, float | None]:
    """Whole-image clean-vs-poisoned SSIM (3DGS formula) and LPIPS ([0, 1] H x W x 3 floats).

    lpips_model: a `verifier.lpips.Lpips` or None (then "lpips" is None: not measured)."""
    result: dict[str, float | None] = {"ssim": whole_image_ssim(clean, poisoned), "lpips": None}
    if lpips_model is not None:
        result["lpips"] = float(lpips_model.distance(clean, poisoned))
    return result


def open_lpips(net: str = "vgg") -> tuple[Any, str | None]:
    """(model, None) or (None, why LPIPS cannot be measured here)."""
    try:
        from verifier.lpips import Lpips, lpips_available
    except ImportError as exc:  # torch missing
        return None, f"LPIPS unavailable ({exc})"
    ok, reason = lpips_available(net)
    if not ok:
        return None, reason
    return Lpips(net), None


def summarise_visibility(per_image: Sequence[dict[str, float | None]]) -> dict[str, Any]:
    ssims = [float(v["ssim"]) for v in per_image if v["ssim"] is not None]
    lp = [float(v["lpips"]) for v in per_image if v.get("lpips") is not None]
    return {
        "images": len(per_image),
        "ssim_min": min(ssims) if ssims else None,
        "ssim_mean": float(np.mean(ssims)) if ssims else None,
        "lpips_max": max(lp) if lp else None,
        "lpips_mean": float(np.mean(lp)) if lp else None,
    }


def budget_use(vis: dict[str, Any], budget: VisibilityBudget) -> float:
    """How much of the budget the worst image of the sample uses: <= 1 fits, > 1 exceeds.

    One number so candidates can be ordered by measured visibility; LPIPS counts when measured."""
    parts = [(1.0 - vis["ssim_min"]) / max(1e-12, 1.0 - budget.min_ssim)]
    if vis.get("lpips_max") is not None:
        parts.append(vis["lpips_max"] / max(1e-12, budget.max_lpips))
    return float(max(parts))


def budget_notes(vis: dict[str, Any], budget: VisibilityBudget) -> list[str]:
    """Plain sentences on what exceeds the budget (empty when it fits)."""
    notes = []
    if vis["ssim_min"] < budget.min_ssim:
        notes.append(f"SSIM {vis['ssim_min']:.4f} < {budget.min_ssim} on the worst sample image")
    if vis.get("lpips_max") is not None and vis["lpips_max"] > budget.max_lpips:
        notes.append(f"LPIPS {vis['lpips_max']:.4f} > {budget.max_lpips} on the worst sample image")
    return notes


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


def choose_sample(items: Sequence[tuple[Path, str]], size: int) -> list[tuple[Path, str]]:
    """An evenly spaced sample by name (deterministic; spans the capture, as a walk around does)."""
    usable = sorted(
        {name: (src, name) for src, name in items if is_sfm_readable(name)}.values(),
        key=lambda t: t[1],
    )
    if len(usable) < 3:
        raise PreflightInputError(
            f"need at least 3 images COLMAP can read ({', '.join(sorted(SFM_SUFFIXES))}), got {len(usable)}"
        )
    if len(usable) <= size:
        return usable
    idx = sorted({round(i * (len(usable) - 1) / (size - 1)) for i in range(size)})
    return [usable[i] for i in idx]


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


# ---- the preflight ----------------------------------------------------------------------------------
def preflight(
    pairs_or_images: Sequence[ImageInput],
    ladder: Sequence[Candidate],
    budget: VisibilityBudget,
    options: PreflightOptions,
    out_dir: Path,
) -> AutoDecision:
    """Measure every candidate's visibility on a sample, then verify the ones within the budget,
    least visible first, until one is `protected` under every profile (see the module docstring)."""
    started = time.monotonic()
    deadline = started + options.time_budget_s
    out_dir = Path(out_dir)
    sample = choose_sample(normalise_inputs(pairs_or_images), options.sample_size)
    if not ladder:
        raise PreflightInputError("the candidate ladder is empty")
    clean_dir = out_dir / "sample"
    shutil.rmtree(clean_dir, ignore_errors=True)
    clean_dir.mkdir(parents=True)
    for src, name in sample:
        _link_or_copy(src, clean_dir / name)
    names = [name for _, name in sample]
    lpips_model, lpips_note = open_lpips(options.lpips_net)
    evidence = [_measure(c, i, clean_dir, names, lpips_model, budget, out_dir) for i, c in enumerate(ladder)]
    order = sorted(
        (e for e in evidence if e.status != FAILED and e.within_budget), key=lambda e: e.budget_use or 0.0
    )
    for e in evidence:
        if e.status != FAILED and not e.within_budget:
            e.status = OVER_BUDGET
    chosen: CandidateEvidence | None = None
    stopped_by_time = clean_failed = False
    cancel = threading.Event()
    timer = threading.Timer(max(0.0, deadline - time.monotonic()), cancel.set)
    timer.daemon = True
    timer.start()
    try:
        for e in order:
            if chosen is not None:
                e.status = NOT_NEEDED
                continue
            if stopped_by_time or clean_failed or time.monotonic() >= deadline:
                stopped_by_time = stopped_by_time or not clean_failed
                continue  # stays NOT_REACHED
            cand_dir = _candidate_dir(out_dir, evidence.index(e), e.name)
            _verify_candidate(e, clean_dir, cand_dir, out_dir, options, deadline, cancel)
            if e.status == PROTECTED:
                chosen = e
            elif e.status == TIMED_OUT:
                stopped_by_time = True
            elif e.status == INCONCLUSIVE:
                clean_failed = True  # the clean sample itself does not reconstruct: same for all
    finally:
        timer.cancel()
        shutil.rmtree(clean_dir, ignore_errors=True)
    lpips_checked = lpips_model is not None
    outcome, reason = _reason(chosen, evidence, budget, options, stopped_by_time, clean_failed)
    if not lpips_checked:
        reason += f" LPIPS NOT checked (the budget's LPIPS <= {budget.max_lpips} part): {lpips_note}."
    spec = PatchSpec.from_dict(chosen.spec) if chosen else None
    decision = AutoDecision(
        chosen=chosen.name if chosen else None, spec=spec, reason=reason, evidence=evidence,
        outcome=outcome, lpips_checked=lpips_checked, lpips_note=lpips_note, budget=budget,
        options=options, sample=names, elapsed_s=round(time.monotonic() - started, 1),
    )  # fmt: skip
    (out_dir / "decision.json").write_text(json.dumps(decision.to_dict(), indent=1))
    log.info("preflight decided", extra={"chosen": decision.chosen, "outcome": outcome,
                                         "elapsed_s": decision.elapsed_s})  # fmt: skip
    return decision


def _candidate_dir(out_dir: Path, index: int, name: str) -> Path:
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
    return out_dir / "candidates" / f"{index:02d}-{safe}"


def _measure(
    candidate: Candidate,
    index: int,
    clean_dir: Path,
    names: list[str],
    lpips_model: Any,
    budget: VisibilityBudget,
    out_dir: Path,
) -> CandidateEvidence:
    """Poison the sample with one candidate and measure its visibility (worst image counts)."""
    from poisoner.formats import poison_file

    spec = candidate.spec
    e = CandidateEvidence(candidate.name, candidate.why, spec.to_dict(), spec.spec_id)
    t0 = time.monotonic()
    images = _candidate_dir(out_dir, index, candidate.name) / "images"
    shutil.rmtree(images, ignore_errors=True)
    images.mkdir(parents=True)
    per_image = []
    try:
        for name in names:
            poison_file(clean_dir / name, images / name, spec)
            per_image.append(visibility(load_rgb(clean_dir / name), load_rgb(images / name), lpips_model))
    except Exception as exc:  # a candidate that cannot be applied here is recorded, not fatal
        e.status, e.error = FAILED, str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        shutil.rmtree(images, ignore_errors=True)
        return e
    e.visibility = summarise_visibility(per_image)
    e.budget_use = round(budget_use(e.visibility, budget), 4)
    e.budget_notes = budget_notes(e.visibility, budget)
    e.seconds = round(time.monotonic() - t0, 2)
    if not e.within_budget:
        shutil.rmtree(images, ignore_errors=True)
    return e


def _verify_candidate(
    e: CandidateEvidence,
    clean_dir: Path,
    cand_dir: Path,
    out_dir: Path,
    options: PreflightOptions,
    deadline: float,
    cancel: threading.Event,
) -> None:
    """Verifier I, one profile at a time; stops at the first profile that is not protected."""
    from verifier.verification import VerifyOptions, verify_folders

    t0 = time.monotonic()
    images, verify_dir = cand_dir / "images", cand_dir / "verify"
    status = PROTECTED
    try:
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
            report = verify_folders(clean_dir, images, verify_dir, [profile], vopts).profiles[profile]
            e.profiles[profile] = _profile_evidence(report)
            if cancel.is_set():
                status = TIMED_OUT
                break
            if report.verdict == "protected":
                continue
            status = INCONCLUSIVE if report.verdict == "inconclusive" else NOT_PROTECTED
            break
    finally:
        shutil.rmtree(verify_dir / ".cache", ignore_errors=True)
        if not options.keep_images:
            shutil.rmtree(images, ignore_errors=True)
    e.status = status
    e.seconds = round(e.seconds + time.monotonic() - t0, 2)


def _profile_evidence(report: Any) -> dict[str, Any]:
    vs = report.vs_clean or {}
    return {
        "verdict": report.verdict,
        "frac_within_5deg": vs.get("frac_within_5deg"),
        "median_rotation_error_deg": vs.get("median_rotation_error_deg"),
        "clean_registered": report.clean.get("registered"),
        "poisoned_registered": report.poisoned.get("registered"),
        "num_images": report.clean.get("num_images"),
        "crashes": report.poisoned.get("crashes") or [],
        "reasons": list(report.reasons)[:3],
        "seconds": round(report.finished_at - report.started_at, 1),
    }


def _pct(x: Any) -> str:
    return "n/a" if x is None else f"{100 * float(x):.0f}%"


def _reason(
    chosen: CandidateEvidence | None,
    evidence: list[CandidateEvidence],
    budget: VisibilityBudget,
    options: PreflightOptions,
    stopped_by_time: bool,
    clean_failed: bool,
) -> tuple[str, str]:
    over = [e.name for e in evidence if e.status == OVER_BUDGET]
    failed = [e.name for e in evidence if e.status == NOT_PROTECTED]
    budget_text = f"SSIM >= {budget.min_ssim}, LPIPS <= {budget.max_lpips}"
    if chosen is not None:
        per = ", ".join(f"{p} {_pct(v.get('frac_within_5deg'))} of cameras within 5 deg"
                        for p, v in chosen.profiles.items())  # fmt: skip
        vis = chosen.visibility
        lp = "" if vis.get("lpips_max") is None else f", LPIPS {vis['lpips_max']:.4f}"
        return "chosen", (
            f"{chosen.name}: the least visible candidate within the budget ({budget_text}) that Verifier I "
            f"confirms protected under every profile ({per}); "
            f"worst sample image SSIM {vis['ssim_min']:.4f}{lp}."
            + (f" Less visible but not protected: {', '.join(failed)}." if failed else "")
        )
    tail = (f" Over the budget: {', '.join(over)}." if over else "") + (
        f" Not protected: {', '.join(failed)}." if failed else ""
    )
    if clean_failed:
        return "inconclusive", (
            "inconclusive: COLMAP does not reconstruct the clean sample itself, so no candidate can be "
            "confirmed (never called protected on that basis)." + tail
        )
    if stopped_by_time:
        left = [e.name for e in evidence if e.status in (NOT_REACHED, TIMED_OUT)]
        return "time_budget", (
            f"stopped at the time budget ({options.time_budget_s:.0f} s) before any candidate was confirmed; "
            f"not verified: {', '.join(left)}." + tail
        )
    return "none_within_budget", f"{NO_CANDIDATE} ({budget_text})." + tail


# ---- child process entry ------------------------------------------------------------------------------
@dataclass(frozen=True)
class LadderEntry:
    """A ladder candidate as a job carries it (same fields as poisoner.ladder.Candidate)."""

    name: str
    spec: PatchSpec
    why: str = ""


def ladder_to_json(ladder: Sequence[Candidate | LadderEntry]) -> list[dict[str, Any]]:
    return [{"name": c.name, "why": c.why, "spec": c.spec.to_dict()} for c in ladder]


def ladder_from_json(data: Sequence[dict[str, Any]]) -> list[LadderEntry]:
    return [LadderEntry(d["name"], PatchSpec.from_dict(d["spec"]), d.get("why", "")) for d in data]


def run_job(job: dict[str, Any]) -> AutoDecision:
    """A preflight described by a JSON job (what the daemon's child runs). The job names its
    ladder; without one, poisoner.ladder's."""
    if "ladder" in job:
        ladder: list[Any] = ladder_from_json(job["ladder"])
    else:
        from poisoner.ladder import candidate_ladder

        ladder = list(candidate_ladder())
    exclude = set(job.get("exclude", []))
    ladder = [c for c in ladder if c.name not in exclude]
    options = dict(job.get("options", {}))
    if "profiles" in options:
        options["profiles"] = tuple(options["profiles"])
    return preflight(
        [(Path(src), name) for src, name in job["images"]],
        ladder,
        VisibilityBudget(**job.get("budget", {})),
        PreflightOptions(**options),
        Path(job["out_dir"]),
    )


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m verifier.auto JOB.json`: writes the decision JSON to job["result"] (atomically)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print("usage: python -m verifier.auto JOB.json", file=sys.stderr)
        return 2
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s %(message)s")
    job = json.loads(Path(args[0]).read_text())
    result = Path(job["result"])
    try:
        data = run_job(job).to_dict()
    except (PreflightInputError, ValueError, OSError) as exc:
        data = {"error": str(exc).splitlines()[0] if str(exc) else type(exc).__name__}
    tmp = result.with_name(".ppd-tmp-" + result.name)
    tmp.write_text(json.dumps(data))
    os.replace(tmp, result)
    return 0 if "error" not in data else 1


if __name__ == "__main__":
    sys.exit(main())
