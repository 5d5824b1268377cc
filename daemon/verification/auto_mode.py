"""Automatic mode in the daemon: a dataset with `spec = "auto"` runs the patch its latest
decision names (docs/AUTO.md).

Life of an automatic dataset:
1. first file: `Config.spec_for` gives the interim spec (`interim_spec`: the ladder's strongest
   candidate by design), so nothing is ever published unprotected;
2. the scheduler thread then has a child process (`python -m verifier.auto_search`, mode "interim")
   measure what a viewer sees of every candidate on the first files (FLIP against the
   [visibility] budget, no SfM, no LPIPS) and re-protects with the strongest candidate within the
   budget: a decision with trigger 'interim';
3. once `preflight.sample_size` files are protected, the preflight runs in a child process
   (`python -m verifier.auto_search`, SfM in grandchildren) on the vault originals; its decision
   (trigger 'preflight') is recorded with its evidence and the dataset is re-protected from the
   vault with the chosen spec;
4. a scheduled verification that finds a profile weak or not_protected escalates: the next
   candidate within the budget, by the visibility measured in the preflight, least visible first,
   skipping every candidate already found wanting (trigger 'escalation'); when none is left, the
   decision says "no candidate within the visibility budget protects this dataset" and the
   dataset keeps its current patch (the best it has), surfaced in `ppd status` and as an event.

Nothing here imports numpy, PIL, pycolmap or torch: poisoning and measuring happen in the child.
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from daemon.protect.job import Outcome
from daemon.protect.one_file import dataset_pairs, reprotect_dataset
from daemon.states import FileState
from poisoner.ladder import strongest_spec
from poisoner.spec import PatchSpec
from verifier.auto_options import (
    CandidateStatus,
    LadderEntry,
    PreflightJob,
    PreflightOptions,
    VisibilityBudget,
)
from verifier.supervise import run_child
from verifier.verdict import NOT_PROTECTED, WEAK

if TYPE_CHECKING:
    from daemon.context import AppContext
    from poisoner.ladder import Candidate

log = logging.getLogger(__name__)

NO_CANDIDATE = "no candidate within the visibility budget protects this dataset"
ESCALATE_ON = (WEAK, NOT_PROTECTED)  # verdicts that say the current patch is not enough
INTERIM_FILES = 3  # files measured for the interim choice
CHILD_GRACE_S = 300.0  # beyond the preflight's own time budget before its child is killed


PreflightRunner = Callable[[PreflightJob, float, "threading.Event | None"], dict[str, Any]]


# ---- settings ----------------------------------------------------------------------------------------
def settings_of(ctx: AppContext) -> tuple[VisibilityBudget, PreflightOptions]:
    """The [visibility] budget and [preflight] options in force (the defaults without a config)."""
    config = getattr(ctx, "config", None)
    if config is None:
        return VisibilityBudget(), PreflightOptions()
    return config.visibility, config.preflight


def is_auto(ctx: AppContext, dataset: str) -> bool:
    config = getattr(ctx, "config", None)
    return bool(config is not None and hasattr(config, "is_auto") and config.is_auto(dataset))


# ---- the ladder ---------------------------------------------------------------------------------------
def load_ladder() -> list[Candidate]:
    from poisoner.ladder import candidate_ladder

    return list(candidate_ladder())


def interim_spec() -> PatchSpec:
    """The spec an automatic dataset's first file gets: the ladder's strongest candidate by design
    (its last). Safest while nothing is measured; replaced within the budget by the interim step."""
    return strongest_spec()


def decided_spec(ctx: AppContext, dataset: str) -> PatchSpec | None:
    """The concrete spec of the latest decision that named one (None: no decision yet)."""
    for row in ctx.store.auto_decisions(dataset, limit=50):
        if row["spec_id"]:
            return ctx.store.get_spec(row["spec_id"])
    return None


def apply_spec(ctx: AppContext, dataset: str, spec: PatchSpec) -> int:
    """Re-protect the dataset from its vault originals with spec (nothing when it already has it).
    Returns the number of files re-protected."""

    current = ctx.store.dataset_spec(dataset)
    if current is not None and current.spec_id == spec.spec_id:
        return 0
    outcomes = reprotect_dataset(ctx, dataset, spec)
    failed = [o for o in outcomes if o.state == Outcome.FAILED]
    if failed:
        log.warning("re-protect left files", extra={"dataset": dataset, "failed": len(failed),
                                                     "first": failed[0].reason})  # fmt: skip
    return sum(1 for o in outcomes if o.state == Outcome.PATCHED)


# ---- step 2: the interim choice (FLIP, in the daemon) ---------------------------------------------
def dataset_images(ctx: AppContext, dataset: str) -> list[tuple[Path, str]]:
    """(vault original, file name) of every protected file: the originals under their names."""

    return [(original, Path(protected).name) for original, protected in dataset_pairs(ctx, dataset)]


def interim_job(
    ctx: AppContext, dataset: str, ladder: Sequence[Candidate | LadderEntry] | None = None
) -> PreflightJob:
    """The child's interim job: the first protected files' vault originals, the ladder, the budget."""
    budget, options = settings_of(ctx)
    images = dataset_images(ctx, dataset)[:INTERIM_FILES]
    if not images:
        raise ValueError(f"dataset {dataset!r} has no protected file to measure yet")
    out_dir = Path(ctx.paths.runs_dir) / dataset / f"auto-interim-{time.strftime('%Y%m%dT%H%M%S')}"
    return PreflightJob(
        images=[(str(src), name) for src, name in images],
        out_dir=str(out_dir),
        result=str(out_dir / "interim.result.json"),
        ladder=[LadderEntry(c.name, c.spec, c.why) for c in (ladder or load_ladder())],
        budget=budget,
        options=options,
        mode="interim",
    )


def run_interim(
    ctx: AppContext,
    dataset: str,
    ladder: Sequence[Candidate | LadderEntry] | None = None,
    cancel: threading.Event | None = None,
    runner: PreflightRunner | None = None,
) -> dict[str, Any]:
    """Measure the ladder on the first protected files (in the child: the daemon neither poisons
    nor measures here); record and apply the interim decision. A failed child raises."""
    job = interim_job(ctx, dataset, ladder)
    choice = (runner or run_preflight_child)(job, job.options.time_budget_s + CHILD_GRACE_S, cancel)
    if "error" in choice:
        raise RuntimeError(f"auto interim: {choice['error']}")
    cand = next(c for c in job.ladder or () if c.name == choice["chosen"])
    budget, within, files = job.budget, bool(choice["within_budget"]), len(job.images)
    reason = (
        f"interim: {cand.name}, the strongest candidate within the budget ({budget.describe()}) on "
        f"{files} file(s); protection is checked by the preflight"
        if within
        else f"interim: no candidate within the budget ({budget.describe()}) on {files} file(s); "
        f"using the least visible measured, {cand.name}, until the preflight decides"
    )
    evidence = {"measured": choice["measured"], "within_budget": within}
    ctx.store.add_auto_decision(dataset, cand.name, cand.spec, reason, evidence, "interim")
    reprotected = apply_spec(ctx, dataset, cand.spec)
    log.info("auto interim", extra={"dataset": dataset, "candidate": cand.name, "reprotected": reprotected})
    return {"candidate": cand.name, "reason": reason, "reprotected": reprotected}


# ---- step 3: the preflight, in a child process -----------------------------------------------------
def run_preflight_child(
    job: PreflightJob, timeout_s: float, cancel: threading.Event | None
) -> dict[str, Any]:
    """`python -m verifier.auto_search JOB.json` at low priority in its own process group; killed (group)
    on cancel or after timeout_s. Returns the child's result as JSON data (an AutoDecision, or an
    InterimChoice for an interim job), or {"error": ...}."""
    from poisoner.atomic import atomic_write_bytes

    out_dir = Path(job.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    job_file = out_dir / "job.json"
    atomic_write_bytes(job_file, msgspec.json.encode(job))
    result = Path(job.result)
    log_file = out_dir / "preflight.log"
    from verifier.childenv import child_env

    ended = run_child(
        [sys.executable, "-m", "verifier.auto_search", str(job_file)], env=child_env(),
        log_path=log_file, append_log=True, timeout_s=timeout_s, cancel=cancel, nice=10, grace_s=10.0,
    )  # fmt: skip
    if ended.kind == "cancelled":
        return {"error": "preflight cancelled"}
    if ended.kind == "timeout":
        return {"error": f"preflight timed out after {timeout_s:.0f} s"}
    if ended.kind == "crashed":
        return {"error": f"preflight child killed by {ended.signal_name} (see {log_file})"}
    if not result.is_file():
        return {"error": f"preflight child exited {ended.returncode} without a result (see {log_file})"}
    return dict(json.loads(result.read_text()))


def preflight_job(
    ctx: AppContext,
    dataset: str,
    exclude: Sequence[str] = (),
    ladder: Sequence[Candidate | LadderEntry] | None = None,
) -> PreflightJob:
    """The child's job: the dataset's vault originals, the ladder, the config's budget and options."""
    budget, options = settings_of(ctx)
    out_dir = Path(ctx.paths.runs_dir) / dataset / f"auto-{time.strftime('%Y%m%dT%H%M%S')}"
    return PreflightJob(
        images=[(str(src), name) for src, name in dataset_images(ctx, dataset)],
        out_dir=str(out_dir),
        result=str(out_dir / "decision.result.json"),
        ladder=[LadderEntry(c.name, c.spec, c.why) for c in (ladder or load_ladder())],
        budget=budget,
        options=options,
        exclude=sorted(exclude),
    )


def record_decision(ctx: AppContext, dataset: str, decision: Mapping[str, Any], trigger: str) -> int:
    """Store a preflight decision (verifier.auto_search.AutoDecision as JSON data) and apply its spec."""
    spec = PatchSpec.from_dict(decision["spec"]) if decision.get("spec") else None
    decision_id = ctx.store.add_auto_decision(
        dataset, decision.get("chosen"), spec, str(decision["reason"]), dict(decision), trigger
    )
    if spec is not None:
        apply_spec(ctx, dataset, spec)
    else:
        surface_no_candidate(ctx, dataset, str(decision["reason"]))
    return decision_id


def surface_no_candidate(ctx: AppContext, dataset: str, reason: str) -> None:
    """Say it where people look: an event (ppd status shows the decision) and a warning in the log."""
    ctx.store.add_event(dataset, None, "auto_no_candidate", {"reason": reason})
    log.warning("auto mode: %s", reason, extra={"dataset": dataset})


def run_preflight(
    ctx: AppContext,
    dataset: str,
    trigger: str = "preflight",
    exclude: Sequence[str] = (),
    cancel: threading.Event | None = None,
    runner: PreflightRunner = run_preflight_child,
    ladder: Sequence[Candidate | LadderEntry] | None = None,
) -> dict[str, Any]:
    """Run a preflight on the dataset's vault originals and record its decision."""
    job = preflight_job(ctx, dataset, exclude, ladder)
    decision = runner(job, job.options.time_budget_s + CHILD_GRACE_S, cancel)
    if "error" in decision:
        ctx.store.add_event(dataset, None, "auto_preflight_failed", {"error": decision["error"]})
        log.warning("auto preflight failed", extra={"dataset": dataset, "error": decision["error"]})
        return decision
    record_decision(ctx, dataset, decision, trigger)
    return decision


def has_measured_decision(ctx: AppContext, dataset: str) -> bool:
    return any(r["trigger"] in ("preflight", "manual") for r in ctx.store.auto_decisions(dataset, limit=200))


def next_step(ctx: AppContext, dataset: str) -> str | None:
    """What automatic mode should do now for a dataset: 'interim', 'preflight' or None."""
    if not is_auto(ctx, dataset):
        return None
    decisions = ctx.store.auto_decisions(dataset, limit=200)
    if any(r["trigger"] in ("preflight", "manual", "escalation") for r in decisions):
        return None
    protected = ctx.store.counts(dataset)[FileState.PATCHED]
    if protected >= settings_of(ctx)[1].sample_size:
        return "preflight"
    if not decisions and protected > 0:
        return "interim"
    return None


# ---- step 4: escalation ---------------------------------------------------------------------------
def needs_escalation(verdicts: Mapping[str, str]) -> bool:
    """A headline profile that is weak or not_protected means this patch is not enough for this
    dataset (masked included: verifier.verdict.headline). Crashed/inconclusive runs
    prove nothing either way and do not move the dataset."""
    from verifier.verdict import headline

    return any(v in ESCALATE_ON for v in headline(verdicts).values())


def failed_candidates(decisions: Sequence[Mapping[str, Any]]) -> set[str]:
    """Candidate names found wanting: not protected in a preflight, or escalated away from."""
    failed: set[str] = set()
    for row in decisions:
        ev = row.get("evidence") or {}
        failed.update(ev.get("failed", []))
        for cand in ev.get("evidence", []) if isinstance(ev.get("evidence"), list) else []:
            if cand.get("status") == CandidateStatus.NOT_PROTECTED:
                failed.add(cand["name"])
    return failed


def next_candidate(measured: Sequence[Mapping[str, Any]], failed: set[str]) -> Mapping[str, Any] | None:
    """The least visible candidate within the budget (by measured budget use) not yet found wanting."""
    fits = [e for e in measured if e.get("budget_use") is not None and e["budget_use"] <= 1.0
            and e.get("status") not in (CandidateStatus.FAILED, CandidateStatus.OVER_BUDGET)
            and e["name"] not in failed]  # fmt: skip
    return min(fits, key=lambda e: e["budget_use"]) if fits else None


def escalate(
    ctx: AppContext,
    dataset: str,
    verdicts: Mapping[str, str],
    cancel: threading.Event | None = None,
    runner: PreflightRunner = run_preflight_child,
) -> dict[str, Any] | None:
    """After a verification of an automatic dataset: move to the next candidate when needed.

    Returns what was decided (None when the verdicts need nothing)."""
    if not is_auto(ctx, dataset) or not needs_escalation(verdicts):
        return None
    decisions = ctx.store.auto_decisions(dataset, limit=200)
    current = next((r["candidate"] for r in decisions if r["candidate"]), None)
    failed = failed_candidates(decisions) | ({current} if current else set())
    measured_row = next((r for r in decisions if r["trigger"] in ("preflight", "manual")), None)
    summary = ", ".join(f"{p} {v}" for p, v in verdicts.items())
    if measured_row is None:  # only an interim choice so far: measure now, without the failed ones
        decision = run_preflight(ctx, dataset, "escalation", sorted(failed), cancel, runner)
        return {"candidate": decision.get("chosen"), "reason": decision.get("reason", decision.get("error"))}
    nxt = next_candidate(measured_row["evidence"].get("evidence", []), failed)
    evidence = {"verdicts": dict(verdicts), "from": current, "failed": sorted(failed),
                "measured_in_decision": measured_row["id"]}  # fmt: skip
    if nxt is None:
        reason = (
            f"{NO_CANDIDATE}: {current or 'the current patch'} verified {summary}, and every "
            f"candidate within the budget has been found wanting ({', '.join(sorted(failed))})"
        )
        ctx.store.add_auto_decision(dataset, None, None, reason, evidence, "escalation")
        surface_no_candidate(ctx, dataset, reason)
        return {"candidate": None, "reason": reason}
    spec = PatchSpec.from_dict(nxt["spec"])
    reason = (f"escalation: {current} verified {summary}; moved to {nxt['name']}, the next least visible "
              f"candidate within the budget (budget use {nxt['budget_use']:.2f})")  # fmt: skip
    evidence["visibility"] = nxt.get("visibility", {})
    ctx.store.add_auto_decision(dataset, nxt["name"], spec, reason, evidence, "escalation")
    reprotected = apply_spec(ctx, dataset, spec)
    log.info("auto escalation", extra={"dataset": dataset, "from": current, "to": nxt["name"],
                                        "reprotected": reprotected})  # fmt: skip
    return {"candidate": nxt["name"], "reason": reason, "reprotected": reprotected}


def verdicts_of(report: Any) -> dict[str, str]:
    """{profile: verdict} of a verification report (VerificationReport or its dict)."""
    profiles = getattr(report, "profiles", None)
    if profiles is None and isinstance(report, Mapping):
        profiles = report.get("profiles")
    if not isinstance(profiles, Mapping):
        return {}
    return {name: str(getattr(p, "verdict", None) or (p.get("verdict") if isinstance(p, Mapping) else ""))
            for name, p in profiles.items()}  # fmt: skip


# ---- status ---------------------------------------------------------------------------------------
def status_text(ctx_or_store: Any, dataset: str) -> str | None:
    """One line for `ppd status`: the automatic decision now in force (None: never decided)."""
    store = getattr(ctx_or_store, "store", ctx_or_store)
    rows = store.auto_decisions(dataset, limit=1)
    if not rows:
        return None
    row = rows[0]
    if row["candidate"] is None:
        return f"auto: {NO_CANDIDATE} ({row['trigger']})"
    return f"auto: {row['candidate']} ({row['trigger']})"

