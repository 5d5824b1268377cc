"""Issue 30: a verification's progress, read from pycolmap's own log lines, written as a small file
that `ppd status` (text and --json) shows while the verification runs."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from verifier.progress import (
    BoardState,
    ProfileProgress,
    ProgressBoard,
    apply_log_line,
    progress_line,
    read_progress,
    stage_estimate_s,
)

# lines as pycolmap 4.2.1 writes them (glog prefix included)
EXTRACT = "I20261126 05:31:59.245658 1404 feature_extraction.cc:270] Processed file [10/40]"
BLOCK = "I20261126 05:32:33.219924 1404 pairing.cc:214] Processing block [2/3, 1/3]"
VERIFY = "I20261126 05:32:53.910403 1404 feature_matching.cc:283] === Geometric verification ==="
REGISTER = (
    "I20261126 05:33:09.913587 1404 incremental_pipeline.cc:620] Registering image #5 (num_reg_frames=12)"
)


def test_pycolmap_log_lines_move_a_profile_through_its_stages() -> None:
    p = ProfileProgress("default")
    assert apply_log_line(p, EXTRACT, 40, now=100.0)
    assert (p.stage, p.done, p.total, p.unit, p.stage_started_at) == ("features", 10, 40, "images", 100.0)
    assert apply_log_line(p, EXTRACT.replace("10/40", "20/40"), 40, now=110.0)
    assert stage_estimate_s(p, now=110.0) == 10.0  # 20 images in 10 s: 20 more take 10 s
    assert apply_log_line(p, BLOCK, 40, now=120.0)
    assert (p.stage, p.done, p.total, p.unit) == ("matching", 3, 9, "blocks")
    assert apply_log_line(p, VERIFY, 40, now=130.0) and p.stage == "verification"
    assert apply_log_line(p, REGISTER, 40, now=140.0)
    assert (p.stage, p.done, p.total) == ("mapping", 12, 40)
    assert not apply_log_line(p, "I2026 timer.cc:90] Elapsed time: 0.002 [minutes]", 40, now=150.0)


def test_the_status_line_names_the_running_profile_its_place_and_stage() -> None:
    state = BoardState("castle", os.getpid(), started_at=1000.0, updated_at=1240.0, num_images=40, profiles=[
        ProfileProgress("default", stage="done", verdict="protected", started_at=1000.0, finished_at=1100.0),
        ProfileProgress("hardened", side="poisoned", stage="mapping", done=12, total=40, unit="images",
                        started_at=1100.0, stage_started_at=1180.0),
        ProfileProgress("published"),
    ])  # fmt: skip
    line = progress_line(state, now=1240.0)
    assert line == (
        "verifying, 4 min, hardened 2/3: poisoned mapping 12/40 images, 2 min, ~2 min left in this stage"
    )


def test_a_board_follows_a_childs_log_and_writes_its_file_atomically(tmp_path: Path) -> None:
    path = tmp_path / ".verifying.json"
    seen: list[BoardState] = []
    board = ProgressBoard(["default", "masked"], 40, "castle", path, seen.append)
    board.start()
    log = tmp_path / "sfm.log"
    log.write_text(EXTRACT + "\n")
    with board.side("default", "clean", log):
        assert json.loads(path.read_text())["profiles"][0]["side"] == "clean"
        deadline = time.monotonic() + 10
        while read_progress(path).profiles[0].done != 10 and time.monotonic() < deadline:
            time.sleep(0.2)
        with log.open("a") as fh:
            fh.write(REGISTER[:40])  # half a line: not read until it is whole
    state = read_progress(path)
    assert state is not None and state.profiles[0].stage == "features" and state.profiles[0].done == 10
    board.finish("default", "protected")
    assert read_progress(path).profiles[0].verdict == "protected"
    assert seen and seen[-1].profiles[0].stage == "done"
    board.close()
    assert not path.exists()  # the verification is over: status shows nothing running


def test_both_sides_of_a_profile_at_once_show_one_then_the_other(tmp_path: Path) -> None:
    """A profile's clean and poisoned sides run together (verifier.verification): its row follows
    the side that started first, then the other from its own log's start when the first ends."""
    board = ProgressBoard(["default"], 40, "castle")
    clean_log, poisoned_log = tmp_path / "clean.log", tmp_path / "poisoned.log"
    clean_log.write_text(EXTRACT + "\n")
    poisoned_log.write_text(EXTRACT + "\n" + VERIFY + "\n" + REGISTER + "\n")
    with contextlib.ExitStack() as poisoned_running:
        with board.side("default", "clean", clean_log):
            poisoned_running.enter_context(board.side("default", "poisoned", poisoned_log))
            board._read_logs()
            row = board.snapshot().profiles[0]
            assert (row.side, row.stage, row.done) == ("clean", "features", 10)  # not the poisoned log's
        board._read_logs()  # the clean side ended, the poisoned one runs on
        row = board.snapshot().profiles[0]
        assert (row.side, row.stage, row.done) == ("poisoned", "mapping", 12)


def test_the_same_sides_next_child_does_not_take_the_row_back_to_features(tmp_path: Path) -> None:
    board = ProgressBoard(["default"], 40, "castle")
    features_log, mapping_log = tmp_path / "features.log", tmp_path / "mapping.log"
    features_log.write_text(EXTRACT + "\n" + VERIFY + "\n")
    mapping_log.write_text("")
    with board.side("default", "clean", features_log):
        pass
    with board.side("default", "clean", mapping_log):  # the side's mapping child, its log still empty
        assert board.snapshot().profiles[0].stage == "verification"


def test_a_progress_file_left_by_a_dead_process_is_ignored(tmp_path: Path) -> None:
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    state = BoardState("castle", int(dead.stdout), 1.0, 2.0, 3, [ProfileProgress("default")])
    import msgspec

    (tmp_path / "p.json").write_bytes(msgspec.json.encode(state))
    assert read_progress(tmp_path / "p.json") is None
    (tmp_path / "p.json").write_text("{broken")
    assert read_progress(tmp_path / "p.json") is None


def test_ppd_status_shows_a_running_verification_in_text_and_json(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    from PIL import Image
    from typer.testing import CliRunner

    from daemon.cli import app
    from daemon.paths import AppPaths
    from daemon.verification.verify_state import progress_path

    runner = CliRunner()
    shoot = tmp_path / "castle"
    shoot.mkdir()
    for i in range(3):
        Image.new("RGB", (160, 120), (40 * i, 90, 200)).save(shoot / f"view{i}.png")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    data = json.loads(runner.invoke(app, ["status", "--json"]).stdout)
    assert data["datasets"][0]["verifying"] is None  # nothing running: nothing said
    # a verification of castle running in this process (the board writes what it would write)
    board = ProgressBoard(["default", "hardened"], 3, "castle", progress_path(AppPaths.from_env(), "castle"))
    board.start()
    try:
        board.finish("default", "protected")
        data = json.loads(runner.invoke(app, ["status", "--json"]).stdout)
        running = data["datasets"][0]["verifying"]
        assert running["label"] == "castle" and running["profiles"][0]["verdict"] == "protected"
        assert running["line"].startswith("verifying, ") and "1/2 profiles done" in running["line"]
        text = runner.invoke(app, ["status"]).stdout
        assert "castle: verifying, " in text
    finally:
        board.close()
    assert "verifying" not in runner.invoke(app, ["status"]).stdout


def test_the_terminal_board_has_a_line_per_profile() -> None:
    from daemon.cli.verify_progress import board_text

    state = BoardState("castle", os.getpid(), 1000.0, 1030.0, 40, [
        ProfileProgress("default", side="clean", stage="features", done=20, total=40, unit="images",
                        started_at=1000.0, stage_started_at=1010.0),
        ProfileProgress("hardened"),
    ])  # fmt: skip
    assert board_text(state, now=1030.0).splitlines() == [
        "verifying castle, 30 s",
        "  default   clean features 20/40 images, 30 s, ~20 s left in this stage",
        "  hardened  waiting",
    ]
