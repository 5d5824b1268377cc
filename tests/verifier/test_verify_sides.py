"""Issue 30: a profile's clean and poisoned SfM side by side where cores allow, with the figures
they give one after the other (real pycolmap, a small generated set)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from tests.verifier.test_verify_shared import SHARING, SMALL, figures, poison_folder
from verifier.synthetic import render_scene
from verifier.verification import VerifyOptions, sides_at_once, verify_folders


def test_sides_go_together_while_each_running_side_keeps_two_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("PPD_VERIFY_SIDES", raising=False)
    assert sides_at_once(workers=4, cores=16) == 2  # eight sides on 16 cores
    assert sides_at_once(workers=5, cores=16) == 1
    assert sides_at_once(workers=2, cores=8) == 2
    assert sides_at_once(workers=2, cores=4) == 1
    assert sides_at_once(workers=1, cores=2) == 2  # one profile: its two sides on the two cores
    assert sides_at_once(workers=2, cores=2) == 1  # two profiles already fill them
    assert sides_at_once(workers=1, cores=1) == 2  # one core: max(2, 0) — still only two children
    monkeypatch.setenv("PPD_VERIFY_SIDES", "1")
    assert sides_at_once(workers=1, cores=16) == 1
    monkeypatch.setenv("PPD_VERIFY_SIDES", "2")
    assert sides_at_once(workers=8, cores=2) == 2


@pytest.mark.integration
def test_sides_side_by_side_give_the_figures_of_one_after_the_other(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    render_scene(tmp_path / "clean", SMALL)
    poisoned = poison_folder(tmp_path / "clean", tmp_path / "poisoned")
    options = VerifyOptions(timeout_s=300, camera_params=SMALL.camera_params(), visibility_images=0)
    reports = {}
    threads = {}
    for sides in ("1", "2"):
        monkeypatch.setenv("PPD_VERIFY_SIDES", sides)
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="verifier.sfm"):
            reports[sides] = verify_folders(tmp_path / "clean", poisoned, tmp_path / sides, SHARING, options)
        threads[sides] = {r.threadName for r in caplog.records if r.getMessage() == "sfm child started"}
    assert figures(reports["2"]) == figures(reports["1"])
    assert reports["1"].profiles["default"].clean["registered"] == SMALL.num_views  # a real reference
    # side by side: each side's child was started from a thread of its profile's own pair
    assert {"ppd-default_0", "ppd-default_1"} <= threads["2"]
    assert not any(t.startswith("ppd-default") for t in threads["1"])
