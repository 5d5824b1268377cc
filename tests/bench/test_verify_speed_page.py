"""bench/bench_verify_speed.py's page: a rewrite keeps the rounds written by hand under its table."""

from __future__ import annotations

from pathlib import Path

import pytest

import bench.bench_verify_speed as speed

ROW = {
    "date": "2026-12-06 20:00", "label": "this CPU", "set": "lego 40 views, width 800",
    "baseline": {"wall_s": 40.0, "load_before": 1.0, "load_after": 1.5},
    "first": {"wall_s": 200.0, "load_before": 1.5, "load_after": 2.0, "verdict": "protected"},
}  # fmt: skip


def test_a_rewrite_keeps_the_hand_written_rounds(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    page = tmp_path / "verify_speed.md"
    page.write_text(
        "# old title\n\n| old table |\n\n## Round 12: written by hand\n\nA finding.\n\n"
        "## Round 11: older\n\n- kept too\n\n\n" + speed.PER_STAGE + "\n\n### an old stage table\n",
        encoding="utf-8",
    )
    monkeypatch.setattr(speed, "RESULTS_MD", page)
    speed.write_page([ROW])
    text = page.read_text(encoding="utf-8")
    assert "| 2026-12-06 20:00 | this CPU | lego 40 views, width 800 | 40 s | 200 s | 5.00x |" in text
    assert "## Round 12: written by hand\n\nA finding.\n\n## Round 11: older\n\n- kept too\n\n" in text
    assert text.index("5.00x") < text.index("## Round 12") < text.index(speed.PER_STAGE)
    assert "| old table |" not in text and "### an old stage table" not in text  # written anew
    speed.write_page([ROW])
    assert page.read_text(encoding="utf-8") == text  # a second rewrite changes nothing


def test_a_page_elsewhere_starts_from_the_repositorys_rounds(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where the results go elsewhere (a lent machine's $OUT), the page written there carries the
    repository's rounds, so copying it back loses none."""
    monkeypatch.setattr(speed, "RESULTS_MD", tmp_path / "verify_speed.md")
    speed.write_page([ROW])
    text = (tmp_path / "verify_speed.md").read_text(encoding="utf-8")
    assert "## Round 1\n" in text and "## Round 11:" in text
