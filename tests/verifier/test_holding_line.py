"""Where the protection holds, does not hold, or could not be verified: the sentence `ppd verify`,
its report.json and the HTML report print. A crashed or inconclusive profile told us nothing, so it
is never counted as "does NOT hold" (nor as "holds")."""

from __future__ import annotations

from verifier import verdict as vd
from verifier.html_report import _holding_text
from verifier.poses import compare_poses
from verifier.verification import ProfileReport, VerificationReport


def test_every_profile_protected_keeps_the_plain_sentence() -> None:
    line = vd.holding_line({"default": "protected", "hardened": "protected"})
    assert line == "the protection holds under every profile run (default, hardened)"


def test_an_inconclusive_profile_could_not_be_verified_and_does_not_fail() -> None:
    verdicts = {"default": "inconclusive"}
    assert vd.holding_line(verdicts) == "the protection could not be verified under: default"
    assert vd.not_holding(verdicts) == [] and vd.unverified(verdicts) == ["default"]


def test_a_crashed_profile_next_to_a_protected_one() -> None:
    verdicts = {"default": vd.PROTECTED, "hardened": vd.SFM_CRASHED}
    assert (
        vd.holding_line(verdicts)
        == "the protection holds under: default; could not be verified under: hardened"
    )


def test_failing_and_unverified_profiles_are_both_said() -> None:
    verdicts = {
        "default": "inconclusive",
        "hardened": "not_protected",
        "global": "sfm_crashed",
        "masked": "weak",
    }
    assert vd.holding_line(verdicts) == (
        "the protection does NOT hold under: hardened, masked; could not be verified under: default, global"
    )
    assert vd.not_holding(verdicts) == ["hardened", "masked"]
    assert vd.unverified(verdicts) == ["default", "global"]


def _profile(name: str, verdict: vd.Verdict) -> ProfileReport:
    """lego8's default profile as QA saw it: the clean run registered 0 of 8 images."""
    clean = {"outcome": "ok", "registered": 0, "num_images": 8}
    poisoned = {"outcome": "ok", "registered": 6, "num_images": 8}
    return ProfileReport(profile=name, verdict=verdict, reasons=[], clean=clean, poisoned=poisoned,
                         vs_clean=compare_poses({}, {}))  # fmt: skip


def test_the_summary_of_an_inconclusive_verification_makes_no_claim() -> None:
    report = VerificationReport("c", "p", "o", 8, {"default": _profile("default", vd.INCONCLUSIVE)})
    summary = "\n".join(report.summary_lines())
    assert "does NOT hold" not in summary
    assert "the protection could not be verified under: default" in summary
    assert report.not_holding() == [] and report.verdict == vd.INCONCLUSIVE
    profiles = {
        "default": _profile("default", vd.INCONCLUSIVE),
        "hardened": _profile("hardened", vd.NOT_PROTECTED),
    }
    both = VerificationReport("c", "p", "o", 8, profiles)
    assert (
        "the protection does NOT hold under: hardened; could not be verified under: default"
        in (both.to_dict()["summary"])
    )


def test_the_html_report_says_could_not_be_verified() -> None:
    text = _holding_text({"default": {"verdict": "inconclusive"}, "hardened": {"verdict": "protected"}})
    assert text is not None and text.startswith(
        "The protection holds under: hardened; could not be verified under: default (not run here:"
    )
    assert "does NOT hold" not in text


def test_no_clean_camera_gives_no_fraction() -> None:
    """Zero registered clean cameras: every figure vs clean is undefined (None), not a vacuous 100%."""
    vc = compare_poses({}, {})
    assert vc["cameras_compared"] == 0
    assert all(vc[f"frac_within_{t}deg"] is None for t in (5, 10, 20))
    assert vc["median_rotation_error_deg"] is None and vc["auc_5"] is None
