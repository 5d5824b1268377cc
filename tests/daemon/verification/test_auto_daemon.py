"""Automatic mode in the daemon: config, the auto_decisions table, escalation through the real
scheduler and Store (re-protecting real files from the vault), and the preflight child."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path
from typing import Any

import pytest

from daemon.protect.one_file import AppContext, protect_file
from daemon.states import FileState
from daemon.verification import auto_mode as daemon_auto
from daemon.verification.scheduler import SchedulePolicy, VerificationScheduler
from daemon.verification.verify import record_report
from poisoner.spec import PatchSpec
from verifier.auto_search import LadderEntry, PreflightJob
from verifier.synthetic import SyntheticOptions, render_scene
from verifier.verification import ProfileReport, VerificationReport

A = LadderEntry("a-small", PatchSpec(patch_size=0.05), "least visible")
B = LadderEntry("b-moved", PatchSpec(patch_size=0.06, position="bottom-right"), "next")
C = LadderEntry("c-huge", PatchSpec(patch_size=0.4), "over budget")




# ---- escalation (pure parts) -------------------------------------------------------------------------------
def _measured(
    name: str, use: float, status: str = "not_reached", spec: PatchSpec | None = None
) -> dict[str, Any]:
    return {"name": name, "budget_use": use, "status": status, "spec": (spec or PatchSpec()).to_dict(),
            "visibility": {"noticeable_area_max": 0.01 * use}}  # fmt: skip


def test_next_candidate_is_least_visible_within_budget_not_failed() -> None:
    measured = [_measured("b", 0.6), _measured("a", 0.3, "not_protected"), _measured("c", 1.4, "over_budget"),
                _measured("d", 0.9)]  # fmt: skip
    failed = daemon_auto.failed_candidates([{"evidence": {"evidence": measured}}])
    assert failed == {"a"}
    assert daemon_auto.next_candidate(measured, failed)["name"] == "b"
    assert daemon_auto.next_candidate(measured, failed | {"b"})["name"] == "d"
    assert daemon_auto.next_candidate(measured, failed | {"b", "d"}) is None  # c is over the budget


def test_which_verdicts_escalate() -> None:
    assert daemon_auto.needs_escalation({"default": "protected", "hardened": "not_protected"})
    assert daemon_auto.needs_escalation({"default": "weak"})
    assert not daemon_auto.needs_escalation({"default": "protected", "hardened": "protected"})
    assert not daemon_auto.needs_escalation({"default": "sfm_crashed", "hardened": "inconclusive"})
    # the masked attacker counts (issue 25, round 2): a mark it defeats is not enough
    assert daemon_auto.needs_escalation({"default": "protected", "masked": "not_protected"})
    assert not daemon_auto.needs_escalation({"default": "protected", "masked": "protected"})


# ---- escalation through the scheduler, with the real Store, vault and files --------------------------------
@pytest.fixture
def auto_ctx(ppd_env: dict[str, Path]) -> Any:
    # LPIPS (reported only, slow on a shared CPU) is tested in test_auto
    config = '[preflight]\nlpips_net = "none"\n[datasets.trip]\nspec = "auto"\n'
    (ppd_env["config"] / "config.toml").write_text(config)
    ctx = AppContext.open()
    yield ctx
    ctx.close()


def _protect_scene(ctx: AppContext, outbox: Path, spec: PatchSpec, views: int = 4) -> list[Path]:
    trip = outbox / "trip"
    render_scene(trip, SyntheticOptions(num_views=views, width=160, height=160))
    files = sorted(trip.glob("*.png"))
    for p in files:
        assert protect_file(p, ctx, spec=spec).state == "patched"
    return files


def _report(verdicts: dict[str, str]) -> VerificationReport:
    """What verify_dataset returns (the real classes); the SfM itself is tested in test_verification."""
    profiles = {
        p: ProfileReport(profile=p, verdict=v, reasons=[f"{v} (test)"], clean={"outcome": "ok"},
                         poisoned={"outcome": "ok"}, vs_clean={"frac_within_5deg": 0.9}, started_at=1.0,
                         finished_at=2.0)  # fmt: skip
        for p, v in verdicts.items()
    }
    return VerificationReport("c", "p", "o", 4, profiles)


def test_escalation_moves_to_next_candidate_then_says_none_is_left(
    auto_ctx: AppContext, ppd_env: dict[str, Path]
) -> None:
    ctx = auto_ctx
    files = _protect_scene(ctx, ppd_env["outbox"], A.spec)
    preflight_evidence = {
        "chosen": "a-small", "outcome": "chosen", "reason": "test preflight",
        "options": {"profiles": ["default", "hardened"]},
        "evidence": [_measured("a-small", 0.3, "protected", A.spec), _measured("b-moved", 0.5, spec=B.spec),
                     _measured("c-huge", 9.0, "over_budget", C.spec)],
    }  # fmt: skip
    ctx.store.add_auto_decision("trip", "a-small", A.spec, "test preflight", preflight_evidence, "preflight")
    before = {str(p): ctx.store.file(p)["poisoned_sha256"] for p in files}

    def verify(ctx_: Any, dataset: str, profiles: tuple[str, ...], cancel: threading.Event) -> Any:
        report = _report({"default": "protected", "hardened": "not_protected"})
        record_report(ctx_, dataset, report)
        return report

    policy = SchedulePolicy(min_new_files=1)
    sched = VerificationScheduler(ctx, policy, ("default", "hardened"), verify=verify)
    sched.on_protected("trip")
    assert sched.run_once() == "trip"
    latest = ctx.store.latest_auto_decision("trip")
    assert latest["trigger"] == "escalation" and latest["candidate"] == "b-moved"
    assert "hardened not_protected" in latest["reason"]
    assert ctx.store.dataset_spec("trip") == B.spec  # the dataset now runs B ...
    for p in files:  # ... and every file was re-protected from its vault original with it
        row = ctx.store.file(p)
        assert row["spec_id"] == B.spec.spec_id and row["poisoned_sha256"] != before[str(p)]
        assert row["state"] == FileState.PATCHED
    assert daemon_auto.decided_spec(ctx, "trip") == B.spec
    assert daemon_auto.status_text(ctx, "trip") == "auto: b-moved (escalation)"

    sched.on_protected("trip")
    assert sched.run_once() == "trip"  # B fails too: nothing within the budget is left (C is over it)
    latest = ctx.store.latest_auto_decision("trip")
    assert latest["candidate"] is None and latest["spec_id"] is None
    assert latest["reason"].startswith(daemon_auto.NO_CANDIDATE)
    assert daemon_auto.status_text(ctx, "trip") == f"auto: {daemon_auto.NO_CANDIDATE} (escalation)"
    from daemon.cli.status_queries import dataset_status  # what `ppd status` shows per dataset

    assert dataset_status(ctx, "trip")["auto"] == f"auto: {daemon_auto.NO_CANDIDATE} (escalation)"
    assert any(e["kind"] == "auto_no_candidate" for e in ctx.store.events("trip"))
    assert ctx.store.dataset_spec("trip") == B.spec  # keeps the best it has; never unprotected


def test_protected_verdicts_do_not_escalate(auto_ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    ctx = auto_ctx
    _protect_scene(ctx, ppd_env["outbox"], A.spec, views=3)
    ctx.store.add_auto_decision("trip", "a-small", A.spec, "r", {"evidence": []}, "preflight")
    assert daemon_auto.escalate(ctx, "trip", {"default": "protected"}) is None
    assert daemon_auto.escalate(ctx, "trip", {"default": "sfm_crashed"}) is None
    assert ctx.store.latest_auto_decision("trip")["trigger"] == "preflight"


def test_next_step_interim_then_preflight(auto_ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    ctx = auto_ctx
    assert daemon_auto.next_step(ctx, "trip") is None  # nothing protected yet
    _protect_scene(ctx, ppd_env["outbox"], C.spec, views=3)
    assert daemon_auto.next_step(ctx, "trip") == "interim"
    # the interim measures what a viewer sees of each candidate on the files, strongest first
    result = daemon_auto.run_interim(ctx, "trip", ladder=[A, B, C])
    assert result["candidate"] == "b-moved", result  # C (last, strongest) is over the FLIP budget
    measured = ctx.store.latest_auto_decision("trip")["evidence"]["measured"]
    assert [m["name"] for m in measured] == ["c-huge", "b-moved"]  # stopped at the first that fits
    assert not measured[0]["within_budget"] and measured[0]["visibility"]["noticeable_area_max"] > 0.01
    assert measured[1]["within_budget"] and measured[1]["budget_use"] <= 1.0
    assert ctx.store.dataset_spec("trip") == B.spec and result["reprotected"] == 3
    assert daemon_auto.next_step(ctx, "trip") is None  # 3 < sample_size 12
    assert daemon_auto.next_step(ctx, "other") is None  # not automatic


def test_preflight_child_records_a_plain_no_candidate_decision(
    auto_ctx: AppContext, ppd_env: dict[str, Path]
) -> None:
    """The real child process (python -m verifier.auto_search) on the vault originals; only an over-budget
    candidate, so it decides without SfM."""
    ctx = auto_ctx
    _protect_scene(ctx, ppd_env["outbox"], A.spec, views=3)
    decision = daemon_auto.run_preflight(ctx, "trip", ladder=[C])
    assert "error" not in decision, decision
    assert decision["chosen"] is None and decision["outcome"] == "none_within_budget"
    row = ctx.store.latest_auto_decision("trip")
    assert row["trigger"] == "preflight" and row["candidate"] is None
    assert daemon_auto.NO_CANDIDATE in row["reason"]
    assert row["evidence"]["evidence"][0]["status"] == "over_budget"
    assert row["evidence"]["evidence"][0]["visibility"]["noticeable_area_max"] > 0.01  # FLIP recorded
    assert row["evidence"]["options"]["lpips_net"] == "none"  # the config's options reached the child
    assert row["evidence"]["evidence"][0]["visibility"]["display_width"] == 160  # own width: not blown up
    assert ctx.store.dataset_spec("trip") == A.spec  # unchanged: nothing better within the budget


def test_preflight_child_cancel_kills_it(tmp_path: Path) -> None:
    out = tmp_path / "o"
    job = PreflightJob(images=[], out_dir=str(out), result=str(out / "r.json"), ladder=[A])
    cancel = threading.Event()
    cancel.set()
    assert daemon_auto.run_preflight_child(job, 60, cancel) == {"error": "preflight cancelled"}


def test_preflight_child_bad_input_is_one_line(tmp_path: Path) -> None:
    job = PreflightJob(images=[(str(tmp_path / "x.png"), "x.png")], out_dir=str(tmp_path / "o"),
                       result=str(tmp_path / "o" / "r.json"), ladder=[A])  # fmt: skip
    result = daemon_auto.run_preflight_child(job, 120, None)
    assert "at least 3 images" in result["error"] and "\n" not in result["error"]


def test_cli_show_prints_decisions(auto_ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    from typer.testing import CliRunner

    from daemon.cli import app

    ctx = auto_ctx
    _protect_scene(ctx, ppd_env["outbox"], A.spec, views=3)
    ctx.store.add_auto_decision("trip", None, None, daemon_auto.NO_CANDIDATE, {}, "escalation")
    result = CliRunner().invoke(app, ["auto", "trip", "--show"])
    assert result.exit_code == 0, result.output
    assert "escalation" in result.output and "no candidate within" in result.output
    missing = CliRunner().invoke(app, ["auto", "nosuch", "--show"])
    assert missing.exit_code == 2 and "no dataset" in missing.output
    shutil.rmtree(ppd_env["outbox"] / "trip")


def test_interim_runs_in_the_child_and_the_daemon_side_stays_light(
    auto_ctx: AppContext, ppd_env: dict[str, Path]
) -> None:
    """The daemon hands the interim to the child (mode "interim"); importing its side loads nothing
    heavy, and the child's choice needs no torch and no pycolmap."""
    import subprocess
    import sys

    ctx = auto_ctx
    _protect_scene(ctx, ppd_env["outbox"], C.spec, views=3)
    jobs: list[PreflightJob] = []

    def runner(job: PreflightJob, timeout_s: float, cancel: threading.Event | None) -> dict[str, Any]:
        jobs.append(job)
        return daemon_auto.run_preflight_child(job, timeout_s, cancel)

    assert daemon_auto.run_interim(ctx, "trip", ladder=[A, B, C], runner=runner)["candidate"] == "b-moved"
    (job,) = jobs
    assert job.mode == "interim" and len(job.images) == 3
    assert [c.name for c in job.ladder or []] == ["a-small", "b-moved", "c-huge"]
    with pytest.raises(RuntimeError, match="auto interim: .*cancelled"):
        daemon_auto.run_interim(ctx, "trip", ladder=[A, B, C], cancel=_set(threading.Event()))
    code = (
        "import sys\n"
        "import daemon.verification.auto_mode, daemon.config, daemon.verification.scheduler\n"
        "light = [m for m in ('numpy', 'PIL', 'flip_evaluator', 'torch', 'pycolmap') if m in sys.modules]\n"
        "from pathlib import Path\n"
        "from verifier.auto_search import LadderEntry, VisibilityBudget, choose_interim\n"
        "from poisoner.spec import PatchSpec\n"
        f"imgs = [(p, p.name) for p in sorted(Path({str(ppd_env['outbox'] / 'trip')!r}).glob('*.png'))]\n"
        "ladder = [LadderEntry('x', PatchSpec(patch_size=6)), LadderEntry('y', PatchSpec(patch_size=60))]\n"
        "choice = choose_interim(ladder, VisibilityBudget(), imgs)\n"
        "heavy = [m in sys.modules for m in ('torch', 'pycolmap')]\n"
        "print(light, choice.chosen, choice.within_budget, *heavy)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["[]", "x", "True", "False", "False"], out.stdout + out.stderr


def _set(event: threading.Event) -> threading.Event:
    event.set()
    return event


def test_cli_auto_on_a_dataset_says_the_scene_hint_from_the_vault_originals(
    auto_ctx: AppContext, ppd_env: dict[str, Path]
) -> None:
    """The hint reads the dataset's originals (vault files named by hash, no suffix) under its name."""
    from typer.testing import CliRunner

    from daemon.cli import app
    from daemon.cli.scene_note import PREFIX

    _protect_scene(auto_ctx, ppd_env["outbox"], A.spec, views=3)  # the textured render
    result = CliRunner().invoke(app, ["auto", "trip", "--sample", "3", "--time-budget", "1", "--no-apply"])
    assert result.exit_code in (0, 1), result.output
    assert f"{PREFIX}trip: richly textured everywhere" in result.output, result.output
    shutil.rmtree(ppd_env["outbox"] / "trip")
