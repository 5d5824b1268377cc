"""Schedules verification runs inside the daemon: one at a time, in a background thread.

The daemon calls `on_protected(dataset)` after each protected file. A dataset becomes due when
`min_new_files` files were protected since its last run, or when its last run is older than
`period_s` and something new arrived since. The run itself (verify.verify_dataset, here) launches SfM child
processes at low priority; `stop()` cancels a running child. Nothing here imports pycolmap.

Automatic mode (daemon.verification.auto_mode, docs/AUTO.md) runs in the same thread, before verifications: an
automatic dataset's interim choice after its first file, its preflight once enough files are
protected, and escalation right after a verification of it found the patch weak.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from daemon.config import Config
    from daemon.context import AppContext

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SchedulePolicy:
    min_new_files: int = 20  # a run after this many newly protected files
    period_s: float = 24 * 3600.0  # or when the last run is older than this (and files are new)
    enabled: bool = True
    splat: bool = False  # include Verifier II's splat stage
    splat_budget_s: float = 150.0
    seeds: int = 1  # the attacker's COLMAP runs per profile (VerifyOptions.seeds)

    @classmethod
    def from_config(cls, config: Config) -> SchedulePolicy:
        """From the daemon Config's [verification] table (every_new_files, period_hours, ...)."""
        ver = config.verification
        return cls(
            min_new_files=int(ver.every_new_files),
            period_s=float(ver.period_hours) * 3600,
            enabled=bool(ver.enabled),
            splat=bool(ver.splat),
            splat_budget_s=float(ver.splat_budget_s),
            seeds=int(ver.seeds),
        )


def is_due(new_files: int, last_finished: float | None, now: float, policy: SchedulePolicy) -> bool:
    """Whether a dataset with new_files protected since its last run (finished at last_finished) is due."""
    if new_files <= 0:
        return False
    if new_files >= policy.min_new_files:
        return True
    return last_finished is not None and now - last_finished >= policy.period_s


VerifyFn = Callable[..., Any]


class VerificationScheduler:
    def __init__(
        self,
        ctx: AppContext,
        policy: SchedulePolicy | None = None,
        profiles: tuple[str, ...] | None = None,
        verify: VerifyFn | None = None,
        poll_s: float = 30.0,
        preflight_runner: Callable[..., dict[str, Any]] | None = None,
    ) -> None:
        self.ctx = ctx
        self.policy = policy or SchedulePolicy.from_config(ctx.config)
        self.profiles = profiles or tuple(ctx.config.verification.profiles)
        self._verify = verify
        self._preflight_runner = preflight_runner  # auto_mode.run_preflight_child by default
        self._auto_pending: set[str] = set()  # automatic datasets that may need an auto step
        self._poll_s = poll_s
        self._lock = threading.Lock()
        self._new: dict[str, int] = {}
        self._last: dict[str, float | None] = {}
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._cancel = threading.Event()
        self._thread: threading.Thread | None = None
        self.running: str | None = None
        self.completed: list[tuple[str, str]] = []  # (dataset, verdict or error) of this process's runs

    # ---- daemon hooks ---------------------------------------------------------------------------
    def on_protected(self, dataset: str) -> None:
        auto = self._is_auto(dataset)
        if not self.policy.enabled and not auto:
            return
        with self._lock:
            if auto:
                self._auto_pending.add(dataset)
            if self.policy.enabled:
                self._new[dataset] = self._new.get(dataset, 0) + 1
        self._wake.set()

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stopping.clear()
        self._cancel.clear()
        self._thread = threading.Thread(target=self._loop, name="ppd-verify", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> None:
        """Stop the thread; a running SfM child is killed (its run is recorded as cancelled)."""
        self._stopping.set()
        self._cancel.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    # ---- scheduling -------------------------------------------------------------------------------
    def _last_finished(self, dataset: str) -> float | None:
        if dataset not in self._last:
            latest = None
            try:
                latest = self.ctx.store.latest_verification(dataset)
            except Exception:  # a store problem must not stop the daemon
                log.exception("latest_verification failed", extra={"dataset": dataset})
            self._last[dataset] = (
                float(latest["finished_at"]) if latest and latest.get("finished_at") else None
            )
        return self._last[dataset]

    def due_dataset(self, now: float | None = None) -> str | None:
        now = time.time() if now is None else now
        with self._lock:
            candidates = sorted(self._new.items(), key=lambda kv: -kv[1])
        for dataset, count in candidates:
            if is_due(count, self._last_finished(dataset), now, self.policy):
                return dataset
        return None

    # ---- automatic mode -----------------------------------------------------------------------------
    def _is_auto(self, dataset: str) -> bool:
        return self.ctx.config.is_auto(dataset)

    def _runner_kwargs(self) -> dict[str, Any]:
        return {"runner": self._preflight_runner} if self._preflight_runner is not None else {}

    def run_auto_once(self) -> str | None:
        """One automatic-mode step (interim or preflight) for a dataset that needs it; its name or None."""
        from daemon.verification import auto_mode as auto

        with self._lock:
            pending = sorted(self._auto_pending)
        for dataset in pending:
            try:
                step = auto.next_step(self.ctx, dataset)
                if step is None:
                    if auto.has_measured_decision(self.ctx, dataset):
                        with self._lock:
                            self._auto_pending.discard(dataset)  # decided: only escalation from now
                    continue
                self.running = f"auto {step}: {dataset}"
                if step == "interim":
                    result = auto.run_interim(self.ctx, dataset, cancel=self._cancel)
                    self.completed.append((dataset, f"auto interim: {result['candidate']}"))
                else:
                    decision = auto.run_preflight(
                        self.ctx, dataset, cancel=self._cancel, **self._runner_kwargs()
                    )
                    self.completed.append((dataset, f"auto preflight: {decision.get('chosen')}"))
                    with self._lock:
                        self._auto_pending.discard(dataset)
                return dataset
            except Exception as exc:  # automatic mode failing must not stop protection or verification
                log.exception("auto step failed", extra={"dataset": dataset})
                self.completed.append((dataset, f"auto error: {exc}"))
                with self._lock:
                    self._auto_pending.discard(dataset)  # retried when its next file arrives
            finally:
                self.running = None
                del self.completed[:-50]
        return None

    def _after_verification(self, dataset: str, result: Any) -> None:
        """Escalation hook: an automatic dataset whose verification found the patch weak moves on."""
        if not self._is_auto(dataset):
            return
        from daemon.verification import auto_mode as auto

        try:
            outcome = auto.escalate(
                self.ctx, dataset, auto.verdicts_of(result), cancel=self._cancel, **self._runner_kwargs()
            )
        except Exception as exc:  # a failed escalation is logged; the dataset keeps its patch
            log.exception("auto escalation failed", extra={"dataset": dataset})
            self.completed.append((dataset, f"auto escalation error: {exc}"))
            return
        if outcome is not None:
            self.completed.append((dataset, f"auto escalation: {outcome.get('candidate')}"))

    def run_once(self, now: float | None = None) -> str | None:
        """Run the most due dataset (synchronously); returns its name or None."""
        dataset = self.due_dataset(now)
        if dataset is None:
            return None
        with self._lock:
            self._new[dataset] = 0  # files arriving during the run count towards the next one
        self.running = dataset
        try:
            result = self._run(dataset)
            self.completed.append((dataset, str(getattr(result, "verdict", result))))
            self._after_verification(dataset, result)
        except Exception as exc:  # a failed verification is logged and retried after the next files
            log.exception("verification failed", extra={"dataset": dataset})
            self.completed.append((dataset, f"error: {exc}"))
        finally:
            del self.completed[:-50]  # a long-lived daemon keeps only the recent outcomes
            self.running = None
            self._last[dataset] = time.time()
        return dataset

    def _run(self, dataset: str) -> Any:
        if self._verify is not None:
            return self._verify(self.ctx, dataset, self.profiles, self._cancel)
        from daemon.verification.verify import verify_dataset

        return verify_dataset(self.ctx, dataset, self.profiles, self.verify_options())

    def verify_options(self) -> Any:
        """What a scheduled run does: the policy's splat stage and seeds when configured, cancellable."""
        from verifier.verification import VerifyOptions

        options = VerifyOptions(cancel=self._cancel, splat=self.policy.splat, seeds=self.policy.seeds)
        options.splat_options["time_budget_s"] = self.policy.splat_budget_s
        return options

    def _loop(self) -> None:
        while not self._stopping.is_set():
            self._wake.wait(self._poll_s)
            self._wake.clear()
            if self._stopping.is_set():
                break
            while not self._stopping.is_set() and (
                self.run_auto_once() is not None or self.run_once() is not None
            ):
                pass
