"""`ppd verify`'s per-profile table: the clean column's figures vs clean (100%, 0°, AUC 1) only
where the clean run registered cameras to compare with; "-" otherwise (no claim over nothing)."""

from __future__ import annotations

from typing import Any

from rich.console import Console

from daemon.cli.verify_tables import json_safe, print_report, profile_table
from verifier.poses import compare_poses
from verifier.verdict import Verdict
from verifier.verification import ProfileReport, VerificationReport


def _rows(p: dict[str, Any]) -> dict[str, tuple[str, str]]:
    """Each row's (clean, poisoned) cells, by metric."""
    table = profile_table(p)
    metric, clean, pois = (list(c.cells) for c in table.columns)
    return {m: (c, q) for m, c, q in zip(metric, clean, pois, strict=True)}


def _profile(clean_registered: int, vs_clean: dict[str, Any] | None, verdict: str) -> dict[str, Any]:
    return {
        "profile": "default", "verdict": verdict, "reasons": [],
        "clean": {"outcome": "ok", "registered": clean_registered, "num_images": 8},
        "poisoned": {"outcome": "ok", "registered": 6, "num_images": 8}, "vs_clean": vs_clean,
    }  # fmt: skip


def test_no_clean_camera_shows_no_percentage() -> None:
    rows = _rows(_profile(0, compare_poses({}, {}), "inconclusive"))  # lego8: clean registered 0/8
    assert rows["images registered"] == ("0/8", "6/8")
    for t in (5, 10, 20):
        assert rows[f"cameras within {t}° of clean"] == ("-", "-")
    assert rows["median rotation error (°)"] == ("-", "-")
    assert rows["pair pose AUC@5/10/20 vs clean"][0] == "-"


def test_no_comparison_shows_no_percentage() -> None:
    p = _profile(8, None, "sfm_crashed")
    p["poisoned"] = {"outcome": "sfm_crashed", "signal": "SIGSEGV"}
    assert _rows(p)["cameras within 5° of clean"] == ("-", "-")


def test_a_real_reference_keeps_the_clean_column() -> None:
    vc = {
        "cameras_compared": 8, "frac_within_5deg": 0.125, "frac_within_10deg": 0.25, "frac_within_20deg": 0.5,
        "median_rotation_error_deg": 12.0, "auc_5": 0.1, "auc_10": 0.2, "auc_20": 0.3,
    }  # fmt: skip
    rows = _rows(_profile(8, vc, "protected"))
    assert rows["cameras within 5° of clean"] == ("100%", "12%")
    assert rows["median rotation error (°)"] == ("0", "12.00")
    assert rows["pair pose AUC@5/10/20 vs clean"] == ("1 / 1 / 1", "0.10 / 0.20 / 0.30")


def test_the_printed_report_of_an_inconclusive_run() -> None:
    """What `ppd verify lego8 --profile default` prints when the clean run registered 0 of 8 images."""
    p = _profile(0, compare_poses({}, {}), "inconclusive")
    prof = ProfileReport(
        profile="default", verdict=Verdict.INCONCLUSIVE, reasons=["clean SfM registered only 0/8"],
        clean=p["clean"], poisoned=p["poisoned"], vs_clean=p["vs_clean"],
    )  # fmt: skip
    report = VerificationReport("clean", "pois", "out", 8, {"default": prof})
    console = Console(record=True, width=160)
    print_report(json_safe(report.to_dict()), console)
    text = console.export_text()
    assert "could not be verified (inconclusive)" in text
    assert "100%" not in text and "does NOT hold" not in text
    assert "the protection could not be verified under: default" in text


def test_the_overall_line_names_the_attackers_that_were_not_measured() -> None:
    """16 lego views: only the global mapper reconstructed the originals; the overall line said
    "weakest of default, hardened, published, global, masked: protected" as if five had held."""
    from daemon.cli.verify_tables import overall_basis

    names = ("default", "hardened", "published", "global", "masked")
    one = {n: {"verdict": "protected" if n == "global" else "inconclusive"} for n in names}
    basis = overall_basis({"profiles": one, "verdict_counts": list(names)})
    assert basis == (
        "weakest of global; not measured under default, hardened, published, masked, whose COLMAP does "
        "not reconstruct the originals either"
    )
    plain = f"weakest of {', '.join(names)}"
    every = {n: {"verdict": "protected"} for n in names}
    assert overall_basis({"profiles": every, "verdict_counts": list(names)}) == plain
    none = {n: {"verdict": "inconclusive"} for n in names}
    assert overall_basis({"profiles": none, "verdict_counts": list(names)}) == plain


def test_status_gives_no_camera_fraction_for_a_profile_that_decided_nothing() -> None:
    """`ppd status DATASET` said "could not be verified (inconclusive), 0% of cameras within 5°": a 0%
    over a clean run of 3 cameras of 16 reads as protection."""
    import time

    from daemon.cli.status_cmd import verdict_text

    def run(verdict: str) -> dict[str, Any]:
        return {"verdict": verdict, "frac_within_5deg": 0.0, "finished_at": time.time()}

    for verdict in ("inconclusive", "sfm_crashed"):
        line = verdict_text("default", run(verdict), markup=False)
        assert "within 5°" not in line and line.startswith("default: could not be verified"), line
    held = verdict_text("global", run("protected"), markup=False)
    assert held.startswith("global: protected, 0% of cameras within 5°"), held
