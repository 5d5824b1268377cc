"""The verdict of one profile: does the poisoned set stop the attacker's SfM from recovering poses?

Rule (justified by measurements in docs/VERIFIER.md):
- the clean run is the reference. If it crashed, timed out, or registered no more than half of the
  images in its largest model, nothing can be concluded: `inconclusive` (we never call a set protected
  because COLMAP also fails on the clean originals).
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

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any


class Verdict(StrEnum):
    """One profile's (or a dataset's) verdict; its value is what the Store and JSON files hold."""

    PROTECTED = "protected"
    WEAK = "weak"
    NOT_PROTECTED = "not_protected"
    SFM_CRASHED = "sfm_crashed"
    INCONCLUSIVE = "inconclusive"


# Module-level names kept for callers that import them (daemon.states).
PROTECTED = Verdict.PROTECTED
WEAK = Verdict.WEAK
NOT_PROTECTED = Verdict.NOT_PROTECTED
SFM_CRASHED = Verdict.SFM_CRASHED
INCONCLUSIVE = Verdict.INCONCLUSIVE
VERDICTS = tuple(Verdict)

# Each verdict in the words the user reads (CLI, status, report); daemon.states uses these too.
VERDICT_WORDS: dict[str, str] = {
    Verdict.PROTECTED: "protected",
    Verdict.WEAK: "weak",
    Verdict.NOT_PROTECTED: "NOT protected",
    Verdict.SFM_CRASHED: "could not be verified (SfM crashed)",
    Verdict.INCONCLUSIVE: "could not be verified (inconclusive)",
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
class Decision:
    """A verdict and the sentences that justify it."""

    verdict: Verdict
    reasons: list[str] = field(default_factory=list)


# Which of several COLMAP seeds' decisions a profile reports: the attacker keeps the run that
# recovered most, so the weakest decisive verdict (then the most cameras within the threshold); a crash
# or an unfinished run says nothing about the others and is reported only when no seed decided.
_SEED_RANK = {Verdict.NOT_PROTECTED: 0, Verdict.WEAK: 1, Verdict.PROTECTED: 2, Verdict.SFM_CRASHED: 3,
              Verdict.INCONCLUSIVE: 4}  # fmt: skip


def worst_seed(decisions: Sequence[Decision], fractions: Sequence[float | None]) -> int:
    """The index of the run a profile reports among its seeds' runs (decisions, and each run's
    fraction of cameras within the threshold, None where it gave no poses): the weakest decisive
    verdict, the most cameras recovered among equals, the first seed among ties."""
    return min(range(len(decisions)),
               key=lambda i: (_SEED_RANK[decisions[i].verdict], -(fractions[i] or 0.0), i))  # fmt: skip


def _pct(x: float) -> str:
    return f"{100 * x:.0f}%"


def _unusable_reference(clean: Mapping[str, Any], rule: VerdictRule) -> Decision | None:
    """Inconclusive when the clean run cannot serve as the reference, else None."""
    if clean.get("outcome") != "ok":
        why = f"clean SfM did not finish ({clean.get('outcome')}: {clean.get('error', '')})"
        return Decision(Verdict.INCONCLUSIVE, [why])
    n_images = int(clean.get("num_images") or 0)
    n_clean = int(clean.get("registered") or 0)
    # more than half, in one model: at exactly half (4 of 8, the rest in a second model) there is no one
    # reference, and a split poisoned run compared with it read as protected (a black-box review)
    if n_images == 0 or n_clean <= rule.clean_min_registered_frac * n_images:
        why = (
            f"clean SfM registered only {n_clean}/{n_images} images: "
            "no reliable reference, so no claim either way"
        )
        return Decision(Verdict.INCONCLUSIVE, [why])
    return None


def _unfinished_attack(poisoned: Mapping[str, Any], vs_clean: Mapping[str, Any] | None) -> Decision | None:
    """sfm_crashed or inconclusive when the poisoned run gave no poses to compare, else None."""
    outcome = poisoned.get("outcome")
    if outcome == "sfm_crashed":
        return Decision(
            Verdict.SFM_CRASHED,
            [
                f"poisoned SfM crashed ({poisoned.get('signal', 'signal')}) in "
                f"{max(1, len(poisoned.get('crashes') or []))} attempt(s); the clean set did not",
                "a crash stops this run but is not proof of protection: "
                "a rerun with other settings may succeed",
            ],
        )
    if outcome != "ok" or vs_clean is None:
        return Decision(
            Verdict.INCONCLUSIVE, [f"poisoned SfM did not finish ({outcome}: {poisoned.get('error', '')})"]
        )
    return None


def _rerun_line(poisoned: Mapping[str, Any]) -> list[str]:
    """The poisoned run that finished after a crash says so (its seed is not the one asked for)."""
    if poisoned.get("outcome") != "ok" or not poisoned.get("crashes"):
        return []
    return [
        f"poisoned SfM first crashed ({', '.join(poisoned['crashes'])}); these figures are from a rerun "
        "with another RANSAC seed"
    ]


def _pose_reasons(
    clean: Mapping[str, Any], poisoned: Mapping[str, Any], vs_clean: Mapping[str, Any], frac: float, deg: int
) -> list[str]:
    n_images, n_clean = int(clean.get("num_images") or 0), int(clean.get("registered") or 0)
    n_pois = int(poisoned.get("registered") or 0)
    reasons = [
        f"{_pct(frac)} of the {n_clean} clean cameras are recovered within {deg} deg "
        "by SfM on the poisoned set",
        f"poisoned SfM registered {n_pois}/{n_images} images in {poisoned.get('num_models', 0)} model(s) "
        f"(clean: {n_clean}/{n_images})",
    ]
    reasons += _rerun_line(poisoned)
    med = vs_clean.get("median_rotation_error_deg")
    if med is not None:
        reasons.append(f"median rotation error of registered poisoned cameras: {med:.1f} deg")
    return reasons


def decide(
    clean: Mapping[str, Any],
    poisoned: Mapping[str, Any],
    vs_clean: Mapping[str, Any] | None,
    rule: VerdictRule | None = None,
) -> Decision:
    """Verdict from the clean and poisoned SfM results and the poisoned-vs-clean pose metrics."""
    rule = rule or VerdictRule()
    unusable = _unusable_reference(clean, rule)
    if unusable is not None:  # no claim; a crash on the patched set is still said (a crash is an outcome)
        return Decision(unusable.verdict, unusable.reasons + _rerun_line(poisoned))
    early = _unfinished_attack(poisoned, vs_clean)
    if early is not None:
        return early
    assert vs_clean is not None  # _unfinished_attack returned a decision otherwise
    frac = float(vs_clean.get(f"frac_within_{rule.threshold_deg}deg") or 0.0)
    reasons = _pose_reasons(clean, poisoned, vs_clean, frac, rule.threshold_deg)
    if frac <= rule.protected_max_frac:
        return Decision(Verdict.PROTECTED, reasons)
    if frac <= rule.weak_max_frac:
        reasons.append(f"more than {_pct(rule.protected_max_frac)} of cameras survive: protection is partial")
        return Decision(Verdict.WEAK, reasons)
    reasons.append(
        f"NOT protected: more than {_pct(rule.weak_max_frac)} of cameras are recovered correctly, "
        "so this attacker gets a usable reconstruction"
    )
    return Decision(Verdict.NOT_PROTECTED, reasons)


_STRENGTH = {Verdict.NOT_PROTECTED: 0, Verdict.WEAK: 1, Verdict.PROTECTED: 2}

# The attackers a dataset's headline verdict counts. `masked` (the attacker masks the four corner
# regions out of SfM) counts too since issue 25's second round: the default's per-photo mark sits off
# the corners and held it on lego and dtu_scan37 (800 px, two COLMAP seeds each;
# bench/results/placement.md). It defeats every corner (watermark-like) mark by construction, so a
# corner design verified under it is NOT protected, which is the truth; masked_line says why.
HEADLINE_PROFILES = ("default", "hardened", "published", "global", "masked")
MASKED_PROFILE = "masked"
MASKED_MEANING = (
    "masked = an attacker who masks the four corner regions (20% x 20%) out of SfM: it defeats any "
    "corner (watermark-like) mark by construction; the default's per-photo mark sits off the corners "
    "and held it on lego and dtu_scan37 in our runs (800 px, two seeds each; dtu at 1600 px: 8%, one "
    "seed); a roaming mark is meant to survive it"
)


def overall(verdicts: Iterable[str]) -> Verdict:
    """The dataset's verdict is its weakest profile's (the attacker picks the pipeline that works).

    A crashed profile outranks "protected": that attacker reconstructs the originals (its clean run
    worked) and its run on the patched set died, so nothing says it fails on a rerun; calling the set
    protected would count the crash as protection. It never hides a weak or NOT protected profile.
    An inconclusive profile (its COLMAP did not reconstruct the originals either) is no threat
    measured, so it counts only when no profile gave an answer.
    """
    vs = list(verdicts)
    decided = [Verdict(v) for v in vs if v in _STRENGTH]
    crashed = Verdict.SFM_CRASHED in vs
    if decided:
        weakest = min(decided, key=_STRENGTH.__getitem__)
        return Verdict.SFM_CRASHED if crashed and weakest is Verdict.PROTECTED else weakest
    return Verdict.SFM_CRASHED if crashed else Verdict.INCONCLUSIVE


def not_holding(verdicts: Mapping[str, str]) -> list[str]:
    """The profiles (attackers) under which the protection does not hold: weak or NOT protected.

    A crashed or inconclusive profile is not among them: it told us nothing (see unverified)."""
    return [name for name, v in verdicts.items() if v in (Verdict.WEAK, Verdict.NOT_PROTECTED)]


def unverified(verdicts: Mapping[str, str]) -> list[str]:
    """The profiles that could not be verified (SfM crashed, inconclusive): no claim either way."""
    return [name for name, v in verdicts.items() if v not in _STRENGTH]


def holding_line(verdicts: Mapping[str, str]) -> str:
    """One plain sentence: the attackers (profiles) the protection does not hold under, and those
    it could not be verified under; never says it holds or fails where nothing was concluded."""
    failing, unknown = not_holding(verdicts), unverified(verdicts)
    if not failing and not unknown:
        return f"the protection holds under every profile run ({', '.join(verdicts)})"
    parts = []
    if failing:
        parts.append(f"does NOT hold under: {', '.join(failing)}")
    else:
        held = [name for name, v in verdicts.items() if v == Verdict.PROTECTED]
        if held:  # said only when nothing failed: the weakest answer is the one that counts
            parts.append(f"holds under: {', '.join(held)}")
    if unknown:
        parts.append(f"could not be verified under: {', '.join(unknown)}")
    return "the protection " + "; ".join(parts)


def headline(verdicts: Mapping[str, str]) -> dict[str, str]:
    """The profiles a headline verdict counts: HEADLINE_PROFILES among those run (all of them when
    none of those was run, e.g. `ppd verify --profile masked`)."""
    counted = {name: verdicts[name] for name in HEADLINE_PROFILES if name in verdicts}  # in that order
    return counted or dict(verdicts)


def headline_verdict(verdicts: Mapping[str, str]) -> Verdict:
    """The dataset's verdict: the weakest of its headline profiles (see HEADLINE_PROFILES)."""
    return overall(headline(verdicts).values())


def masked_line(verdicts: Mapping[str, str], corner_mark: bool | None) -> str | None:
    """The masked attacker in plain words, when it was run next to headline profiles (None otherwise).

    corner_mark: whether the dataset's mark lives in one corner (None: unknown)."""
    verdict = verdicts.get(MASKED_PROFILE)
    others = [name for name in verdicts if name in HEADLINE_PROFILES and name != MASKED_PROFILE]
    if verdict is None or not others:
        return None
    if verdict in (Verdict.NOT_PROTECTED, Verdict.WEAK):
        if corner_mark:
            return "NOT protected against an attacker who masks the corners (a corner mark cannot be)"
        return (
            f"{verdict_words(verdict)} against an attacker who masks the corners (counted in the "
            f"verdict above); {MASKED_MEANING}"
        )
    if verdict == Verdict.PROTECTED:
        return f"protected against an attacker who masks the corners too; {MASKED_MEANING}"
    return f"masked attacker: {verdict_words(verdict)}; {MASKED_MEANING}"


def left_out_of(sides: Iterable[Mapping[str, Any]]) -> list[str]:
    """The photos some SfM side did not read (its result's left_out), in name order."""
    return sorted({name for side in sides for name in side.get("left_out") or ()})


def left_out_line(names: Sequence[str], total: int | None = None) -> str:
    """One line: the photos no verdict covers, since COLMAP did not read them."""
    shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    count = f"{len(names)} of {total} photos" if total is not None else f"{len(names)} photo(s)"
    return (
        f"not measured: {count} ({shown}): COLMAP did not read them "
        "(a format it does not read, or sfm.log says why), so no verdict covers them"
    )


def measured_verdict(verdicts: Mapping[str, str], left_out: Sequence[str]) -> Verdict:
    """The dataset's verdict (headline_verdict), never "protected" while photos of the set were not
    measured (left_out: a counted profile's COLMAP did not read them): an attacker's COLMAP
    may read them."""
    verdict = headline_verdict(verdicts)
    return Verdict.INCONCLUSIVE if verdict is Verdict.PROTECTED and left_out else verdict


def sizes_line(sizes: Mapping[str, int]) -> str:
    """One line: the set's stored sizes, and the one camera per size its SfM runs used."""
    counts = ", ".join(f"{size}: {n}" for size, n in sizes.items())
    return (
        f"the photos have {len(sizes)} stored sizes ({counts}): every COLMAP run used one camera per size, "
        "on the originals and on the patched set (convert.py's single camera leaves out the photos of the "
        "other sizes; an attacker's COLMAP does not)"
    )
