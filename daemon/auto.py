"""Automatic mode in the daemon: a dataset with `spec = "auto"` runs the patch its latest
decision names (docs/AUTO.md).

Life of an automatic dataset:
1. first file: `Config.spec_for` gives the interim spec (`interim_spec`: the ladder's strongest
   candidate by design), so nothing is ever published unprotected;
2. the scheduler thread then measures SSIM of every candidate on the first files (no torch here:
   LPIPS waits for the preflight) and re-protects with the strongest candidate within the SSIM
   budget: a decision with trigger 'interim';
3. once `preflight.sample_size` files are protected, the preflight runs in a child process
   (`python -m verifier.auto`, SfM in grandchildren) on the vault originals; its decision
   (trigger 'preflight') is recorded with its evidence and the dataset is re-protected from the
   vault with the chosen spec;
4. a scheduled verification that finds a profile weak or not_protected escalates: the next
   candidate within the budget, by the visibility measured in the preflight, least visible first,
   skipping every candidate already found wanting (trigger 'escalation'); when none is left, the
   decision says "no candidate within the visibility budget protects this dataset" and the
   dataset keeps its current patch (the best it has), surfaced in `ppd status` and as an event.

Nothing here imports pycolmap or torch.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.states import FileState
from poisoner.ladder import strongest_spec
from poisoner.spec import PatchSpec
from verifier.supervise import run_child

if TYPE_CHECKING:
    from daemon.config import Config
    from daemon.context import AppContext
    from poisoner.ladder import Candidate

log = logging.getLogger(__name__)

NO_CANDIDATE = "no candidate within the visibility budget protects this dataset"
ESCALATE_ON = ("weak", "not_protected")  # verdicts that say the current patch is not enough
INTERIM_FILES = 3  # files measured for the interim choice
CHILD_GRACE_S = 300.0  # beyond the preflight's own time budget before its child is killed


# ---- settings -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class AutoSettings:
    min_ssim: float = 0.99
    max_lpips: float = 0.02
    sample_size: int = 12
    time_budget_s: float = 900.0
    profiles: tuple[str, ...] = ("default", "hardened")

    @classmethod
    def from_config(cls, config: Config | None) -> AutoSettings:
        if config is None:
            return cls()
        vis, pre = config.visibility, config.preflight
        return cls(vis.min_ssim, vis.max_lpips, pre.sample_size, pre.time_budget_s, tuple(pre.profiles))

    def budget_dict(self) -> dict[str, float]:
        return {"min_ssim": self.min_ssim, "max_lpips": self.max_lpips}

    def options_dict(self) -> dict[str, Any]:
        return {"sample_size": self.sample_size, "time_budget_s": self.time_budget_s,
                "profiles": list(self.profiles)}  # fmt: skip


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
    from daemon.pipeline import Outcome
    from daemon.protect import reprotect_dataset

    current = ctx.store.dataset_spec(dataset)
    if current is not None and current.spec_id == spec.spec_id:
        return 0
    outcomes = reprotect_dataset(ctx, dataset, spec)
    failed = [o for o in outcomes if o.state == Outcome.FAILED]
    if failed:
        log.warning("re-protect left files", extra={"dataset": dataset, "failed": len(failed),
                                                     "first": failed[0].reason})  # fmt: skip
    return sum(1 for o in outcomes if o.state == Outcome.PATCHED)


# ---- step 2: the interim choice (SSIM only, in the daemon) ---------------------------------------
def dataset_images(ctx: AppContext, dataset: str) -> list[tuple[Path, str]]:
    """(vault original, file name) of every protected file: the originals under their names."""
    from daemon.protect import dataset_pairs

    return [(original, Path(protected).name) for original, protected in dataset_pairs(ctx, dataset)]


def choose_interim(
    ladder: Sequence[Candidate], min_ssim: float, images: Sequence[tuple[Path, str]]
) -> tuple[Candidate, list[dict[str, Any]], bool]:
    """The strongest candidate (latest in the ladder) whose worst SSIM on images meets min_ssim.

    Returns (candidate, evidence, within_budget). With none within the SSIM budget, the least
    visible one measured (within_budget False: the caller says so)."""
    from poisoner.formats import poison_file
    from verifier.auto import load_rgb, whole_image_ssim

    evidence: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix=".ppd-auto-") as tmp:
        for index in range(len(ladder) - 1, -1, -1):
            cand = ladder[index]
            folder = Path(tmp) / str(index)
            folder.mkdir()
            try:
                ssims = []
                for src, name in images:
                    named = folder / f"clean-{name}"
                    os.link(src, named) if _same_fs(src, folder) else named.write_bytes(src.read_bytes())
                    out = folder / name
                    poison_file(named, out, cand.spec)
                    ssims.append(whole_image_ssim(load_rgb(named), load_rgb(out)))
            except Exception as exc:  # does not fit these images: recorded, next one
                evidence.append({"name": cand.name, "error": str(exc).splitlines()[0]})
                continue
            evidence.append({"name": cand.name, "spec_id": cand.spec.spec_id, "ssim_min": min(ssims)})
            if min(ssims) >= min_ssim:
                return cand, evidence, True
    measured = [e for e in evidence if "ssim_min" in e]
    if not measured:
        raise ValueError("no candidate of the ladder applies to these images")
    best = max(measured, key=lambda e: e["ssim_min"])
    return next(c for c in ladder if c.name == best["name"]), evidence, False


def run_interim(
    ctx: AppContext, dataset: str, ladder: Sequence[Candidate] | None = None
) -> dict[str, Any]:
    """Measure the ladder on the first protected files; record and apply the interim decision."""
    settings = AutoSettings.from_config(ctx.config)
    images = dataset_images(ctx, dataset)[:INTERIM_FILES]
    if not images:
        raise ValueError(f"dataset {dataset!r} has no protected file to measure yet")
    cand, evidence, within = choose_interim(ladder or load_ladder(), settings.min_ssim, images)
    reason = (
        f"interim: {cand.name}, the strongest candidate with SSIM >= {settings.min_ssim} on "
        f"{len(images)} file(s); LPIPS and protection are checked by the preflight"
        if within
        else f"interim: no candidate within SSIM >= {settings.min_ssim} on {len(images)} file(s); "
        f"using the least visible measured, {cand.name}, until the preflight decides"
    )
    ctx.store.add_auto_decision(dataset, cand.name, cand.spec, reason,
                                {"measured": evidence, "within_budget": within}, "interim")  # fmt: skip
    reprotected = apply_spec(ctx, dataset, cand.spec)
    log.info("auto interim", extra={"dataset": dataset, "candidate": cand.name, "reprotected": reprotected})
    return {"candidate": cand.name, "reason": reason, "reprotected": reprotected}


# ---- step 3: the preflight, in a child process -----------------------------------------------------
PreflightRunner = Callable[[dict[str, Any], float, "threading.Event | None"], dict[str, Any]]


def run_preflight_child(
    job: dict[str, Any], timeout_s: float, cancel: threading.Event | None
) -> dict[str, Any]:
    """`python -m verifier.auto JOB.json` at low priority in its own process group; killed (group)
    on cancel or after timeout_s. Returns the decision dict, or {"error": ...}."""
    out_dir = Path(job["out_dir"])
    out_dir.mkdir(parents=True, exist_ok=True)
    job_file = out_dir / "job.json"
    job_file.write_text(json.dumps(job))
    result = Path(job["result"])
    log_file = out_dir / "preflight.log"
    ended = run_child(
        [sys.executable, "-m", "verifier.auto", str(job_file)],
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
    settings: AutoSettings,
    exclude: Sequence[str] = (),
    ladder: Sequence[Candidate] | None = None,
) -> dict[str, Any]:
    from verifier.auto import ladder_to_json

    out_dir = Path(ctx.paths.runs_dir) / dataset / f"auto-{time.strftime('%Y%m%dT%H%M%S')}"
    return {
        "ladder": ladder_to_json(ladder or load_ladder()),
        "images": [[str(src), name] for src, name in dataset_images(ctx, dataset)],
        "budget": settings.budget_dict(),
        "options": settings.options_dict(),
        "out_dir": str(out_dir),
        "result": str(out_dir / "decision.result.json"),
        "exclude": sorted(exclude),
    }


def record_decision(ctx: AppContext, dataset: str, decision: Mapping[str, Any], trigger: str) -> int:
    """Store a preflight decision (verifier.auto.AutoDecision.to_dict()) and apply its spec."""
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
    ladder: Sequence[Candidate] | None = None,
) -> dict[str, Any]:
    """Run a preflight on the dataset's vault originals and record its decision."""
    settings = AutoSettings.from_config(ctx.config)
    job = preflight_job(ctx, dataset, settings, exclude, ladder)
    decision = runner(job, settings.time_budget_s + CHILD_GRACE_S, cancel)
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
    if protected >= AutoSettings.from_config(ctx.config).sample_size:
        return "preflight"
    if not decisions and protected > 0:
        return "interim"
    return None


# ---- step 4: escalation ---------------------------------------------------------------------------
def needs_escalation(verdicts: Mapping[str, str]) -> bool:
    """A profile that is weak or not_protected means this patch is not enough for this dataset.
    Crashed/inconclusive runs prove nothing either way and do not move the dataset."""
    return any(v in ESCALATE_ON for v in verdicts.values())


def failed_candidates(decisions: Sequence[Mapping[str, Any]]) -> set[str]:
    """Candidate names found wanting: not protected in a preflight, or escalated away from."""
    failed: set[str] = set()
    for row in decisions:
        ev = row.get("evidence") or {}
        failed.update(ev.get("failed", []))
        for cand in ev.get("evidence", []) if isinstance(ev.get("evidence"), list) else []:
            if cand.get("status") == "not_protected":
                failed.add(cand["name"])
    return failed


def next_candidate(measured: Sequence[Mapping[str, Any]], failed: set[str]) -> Mapping[str, Any] | None:
    """The least visible candidate within the budget (by measured budget use) not yet found wanting."""
    fits = [e for e in measured if e.get("budget_use") is not None and e["budget_use"] <= 1.0
            and e.get("status") not in ("failed", "over_budget") and e["name"] not in failed]  # fmt: skip
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


def _same_fs(src: Path, folder: Path) -> bool:
    try:
        return os.stat(src).st_dev == os.stat(folder).st_dev
    except OSError:
        return False
