"""The verdict of one profile: does the poisoned set stop the attacker's SfM from recovering poses?

Rule (justified by measurements in docs/VERIFIER.md):
- the clean run is the reference. If it crashed, timed out, or registered fewer than half of the
  images, nothing can be concluded: `inconclusive` (we never call a set protected because COLMAP
  also fails on the clean originals).
- the poisoned run was killed by a signal: `sfm_crashed`. The attacker's run died, but a rerun with
  other settings may not: this is recorded as its own outcome, not as protection.
- otherwise f5 = fraction of the clean run's registered cameras that the poisoned run registers
  with a rotation within 5 deg of the clean solution (after a robust similarity alignment;
  unregistered = failure):
    f5 <= 0.25 -> `protected`    (at most a quarter of the cameras usable: no coherent model)
    f5 <= 0.60 -> `weak`         (a partial, distorted model is likely)
    f5 >  0.60 -> `not_protected` (the attacker recovers most cameras: the patch did not work)
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

PROTECTED = "protected"
WEAK = "weak"
NOT_PROTECTED = "not_protected"
SFM_CRASHED = "sfm_crashed"
INCONCLUSIVE = "inconclusive"
VERDICTS = (PROTECTED, WEAK, NOT_PROTECTED, SFM_CRASHED, INCONCLUSIVE)

# Each verdict in the words the user reads (CLI, status, report); daemon.states uses these too.
VERDICT_WORDS = {
    PROTECTED: "protected",
    WEAK: "weak",
    NOT_PROTECTED: "NOT protected",
    SFM_CRASHED: "could not be verified (SfM crashed)",
    INCONCLUSIVE: "could not be verified (inconclusive)",
}


def verdict_words(verdict: str) -> str:
    """One profile's verdict in the words the user reads."""
    return VERDICT_WORDS.get(verdict, verdict)


@dataclass(frozen=True)
class VerdictRule:
    protected_max_frac: float = 0.25
    weak_max_frac: float = 0.60
    threshold_deg: int = 5
    clean_min_registered_frac: float = 0.5


@dataclass(frozen=True)
class Verdict:
    verdict: str
    reasons: list[str] = field(default_factory=list)


def _pct(x: float) -> str:
    return f"{100 * x:.0f}%"


def decide(
    clean: Mapping[str, Any],
    poisoned: Mapping[str, Any],
    vs_clean: Mapping[str, Any] | None,
    rule: VerdictRule | None = None,
) -> Verdict:
    """Verdict from the clean and poisoned SfM results and the poisoned-vs-clean pose metrics."""
    rule = rule or VerdictRule()
    if clean.get("outcome") != "ok":
        return Verdict(
            INCONCLUSIVE, [f"clean SfM did not finish ({clean.get('outcome')}: {clean.get('error', '')})"]
        )
    n_images = int(clean.get("num_images") or 0)
    n_clean = int(clean.get("registered") or 0)
    if n_images == 0 or n_clean < rule.clean_min_registered_frac * n_images:
        return Verdict(
            INCONCLUSIVE,
            [
                f"clean SfM registered only {n_clean}/{n_images} images: "
                "no reliable reference, so no claim either way"
            ],
        )
    outcome = poisoned.get("outcome")
    if outcome == "sfm_crashed":
        return Verdict(
            SFM_CRASHED,
            [
                f"poisoned SfM crashed ({poisoned.get('signal', 'signal')}) in "
                f"{max(1, len(poisoned.get('crashes') or []))} attempt(s); the clean set did not",
                "a crash stops this run but is not proof of protection: "
                "a rerun with other settings may succeed",
            ],
        )
    if outcome != "ok" or vs_clean is None:
        return Verdict(
            INCONCLUSIVE, [f"poisoned SfM did not finish ({outcome}: {poisoned.get('error', '')})"]
        )
    key = f"frac_within_{rule.threshold_deg}deg"
    frac = float(vs_clean.get(key) or 0.0)
    n_pois = int(poisoned.get("registered") or 0)
    reasons = [
        f"{_pct(frac)} of the {n_clean} clean cameras are recovered within {rule.threshold_deg} deg "
        f"by SfM on the poisoned set",
        f"poisoned SfM registered {n_pois}/{n_images} images in {poisoned.get('num_models', 0)} model(s) "
        f"(clean: {n_clean}/{n_images})",
    ]
    if poisoned.get("crashes"):
        reasons.append(
            f"poisoned SfM first crashed ({', '.join(poisoned['crashes'])}); these figures are from a rerun "
            "with another RANSAC seed"
        )
    med = vs_clean.get("median_rotation_error_deg")
    if med is not None:
        reasons.append(f"median rotation error of registered poisoned cameras: {med:.1f} deg")
    if frac <= rule.protected_max_frac:
        return Verdict(PROTECTED, reasons)
    if frac <= rule.weak_max_frac:
        reasons.append(f"more than {_pct(rule.protected_max_frac)} of cameras survive: protection is partial")
        return Verdict(WEAK, reasons)
    reasons.append(
        f"NOT protected: more than {_pct(rule.weak_max_frac)} of cameras are recovered correctly, "
        "so this attacker gets a usable reconstruction"
    )
    return Verdict(NOT_PROTECTED, reasons)


_STRENGTH = {NOT_PROTECTED: 0, WEAK: 1, PROTECTED: 2}


def overall(verdicts: Iterable[str]) -> str:
    """The dataset's verdict is its weakest profile's (the attacker picks the pipeline that works).

    Crashed/inconclusive profiles count only when no profile gave a real answer.
    """
    vs = list(verdicts)
    decided = [v for v in vs if v in _STRENGTH]
    if decided:
        return min(decided, key=_STRENGTH.__getitem__)
    if SFM_CRASHED in vs:
        return SFM_CRASHED
    return INCONCLUSIVE
