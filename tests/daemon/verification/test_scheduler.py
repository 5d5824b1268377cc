"""daemon.verification.scheduler: when a dataset's verification is due, one run at a time in a background
thread, stop() cancelling it, and the options a scheduled run gets from the config; a real AppContext (real
SQLite store and config file in a temporary folder)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from daemon.context import AppContext
from daemon.verification.scheduler import SchedulePolicy, VerificationScheduler, is_due


def open_ctx(ppd_env: dict[str, Path], config_toml: str = "") -> AppContext:
    """ppd's real context over the test's private folders, with this config.toml."""
    (ppd_env["config"] / "config.toml").write_text(config_toml)
    return AppContext.open()


@pytest.fixture
def ctx(ppd_env: dict[str, Path]) -> Iterator[AppContext]:
    context = open_ctx(
        ppd_env, '[verification]\nevery_new_files = 3\nperiod_hours = 1e6\nprofiles = ["default"]\n'
    )
    try:
        yield context
    finally:
        context.close()


def test_is_due_policy() -> None:
    policy = SchedulePolicy(min_new_files=20, period_s=3600)
    assert not is_due(0, None, 1e9, policy)
    assert not is_due(19, None, 1e9, policy)  # never ran, not enough files yet
    assert is_due(20, None, 1e9, policy)
    assert not is_due(5, 1e9 - 10, 1e9, policy)
    assert is_due(5, 1e9 - 3600, 1e9, policy)  # old run + something new


def test_policy_and_profiles_come_from_the_config(ctx: AppContext) -> None:
    sched = VerificationScheduler(ctx)
    assert (sched.policy.min_new_files, sched.policy.period_s, sched.policy.enabled) == (3, 1e6 * 3600, True)
    assert sched.profiles == ("default",)


def test_scheduler_runs_a_dataset_after_n_files_and_stop_cancels(ctx: AppContext) -> None:
    calls: list[str] = []
    cancelled = threading.Event()
    started = threading.Event()

    def slow_verify(ctx_: Any, dataset: str, profiles: tuple[str, ...], cancel: threading.Event) -> str:
        assert ctx_ is ctx and profiles == ("default",)
        calls.append(dataset)
        started.set()
        if cancel.wait(10):  # what verify_dataset does with the event: kills its child
            cancelled.set()
            return "cancelled"
        return "protected"

    sched = VerificationScheduler(ctx, verify=slow_verify, poll_s=0.05)
    sched.start()
    try:
        sched.on_protected("trip")
        sched.on_protected("trip")
        time.sleep(0.3)
        assert calls == []  # 2 < 3
        sched.on_protected("trip")
        assert started.wait(5)
        assert calls == ["trip"] and sched.running == "trip"
    finally:
        sched.stop(timeout=10)
    assert cancelled.is_set()
    assert sched.completed == [("trip", "cancelled")]


def test_last_run_in_the_store_makes_a_dataset_due_after_the_period(ppd_env: dict[str, Path]) -> None:
    ctx = open_ctx(ppd_env, "[verification]\nevery_new_files = 50\nperiod_hours = 1\n")
    try:
        ctx.store.add_verification_run("trip", "default", "protected", {}, 0.0, 1000.0, None, None)
        sched = VerificationScheduler(ctx, verify=lambda *a: "protected")
        sched.on_protected("trip")
        assert sched.due_dataset(now=1000.0 + 1800) is None  # ran half an hour ago, 1 < 50 files
        assert sched.due_dataset(now=1000.0 + 3600) == "trip"  # the period has passed since the stored run
        assert sched.run_once(now=1000.0 + 3600) == "trip" and sched.completed == [("trip", "protected")]
    finally:
        ctx.close()


def test_scheduled_runs_include_the_splat_stage_when_configured(ppd_env: dict[str, Path]) -> None:
    from daemon.config import Config

    off_toml, on_toml = (
        "[verification]\nevery_new_files = 5\n",
        "[verification]\nsplat = true\nsplat_budget_s = 60\n",
    )
    off, on = Config.from_toml(off_toml), Config.from_toml(on_toml)
    assert on.verification.splat and not off.verification.splat
    assert "splat = true" in on.to_toml()  # written back as configured
    for toml, wanted in ((off_toml, False), (on_toml, True)):
        ctx = open_ctx(ppd_env, toml)
        try:
            options = VerificationScheduler(ctx).verify_options()
            assert options.splat is wanted
            assert options.cancel is not None  # a stopping daemon still cancels the run
            if wanted:
                assert options.splat_options["time_budget_s"] == 60
        finally:
            ctx.close()


def test_scheduled_runs_take_the_configured_seeds(ppd_env: dict[str, Path]) -> None:
    from daemon.config import Config, ConfigError

    assert Config.from_toml("").verification.seeds == 1
    ctx = open_ctx(ppd_env, "[verification]\nseeds = 3\n")
    try:
        assert VerificationScheduler(ctx).verify_options().seeds == 3
    finally:
        ctx.close()
    refused = {"0": "from 1 to 10, got 0", "11": "from 1 to 10, got 11",
               "true": "expected `int`, got `bool`", "1.5": "expected `int`, got `float`"}  # fmt: skip
    for bad, said in refused.items():
        with pytest.raises(ConfigError, match=said):
            Config.from_toml(f"[verification]\nseeds = {bad}\n")


def test_keep_runs_is_a_config_field() -> None:
    from daemon.config import Config, ConfigError

    assert Config.from_toml("").verification.keep_runs == 5
    kept = Config.from_toml("[verification]\nkeep_runs = 2\n")
    assert kept.verification.keep_runs == 2 and "keep_runs = 2" in kept.to_toml()
    assert Config.from_toml(kept.to_toml()).verification.keep_runs == 2
    for bad in ("0", '"3"', "true"):
        with pytest.raises(ConfigError, match="keep_runs"):
            Config.from_toml(f"[verification]\nkeep_runs = {bad}\n")
