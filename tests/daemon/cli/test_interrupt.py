"""An interrupted `ppd poison` is visible and resumable: `ppd status` counts the dataset's files
from its folder as well as its rows, Ctrl-C / SIGTERM end the run between files with one line and
the command that finishes it, and no process prints a traceback. Real `ppd` processes, real
signals, the real store."""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.datasets.folder_count import (
    count_folder,
    folder_media,
    not_patched_yet,
    resume_command,
    with_folder,
)
from testkit.photos import make_image

REPO = Path(__file__).resolve().parents[3]
runner = CliRunner()


def status_of(name: str) -> dict:
    result = runner.invoke(app, ["status", name, "--json"])
    assert result.exit_code == 0, result.output
    (d,) = json.loads(result.output)["datasets"]
    return d


# ---- the count, from the folder and the rows (CliRunner: runs by default) -----------------------
def test_status_counts_the_folders_files_that_no_run_reached(ppd_env: dict, tmp_path: Path) -> None:
    shoot = tmp_path / "castle"
    for i in range(3):
        make_image(shoot / f"view{i}.png", i)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    for i in range(3, 8):  # what an interrupted run leaves: originals no row mentions
        make_image(shoot / f"view{i}.png", i)
    (shoot / "notes.txt").write_text("not a photo")  # not media: not a file of the dataset
    (shoot / ".hidden.png").write_bytes(b"x")

    d = status_of("castle")
    assert d["counts"]["files"] == 8 and d["patched"] == 3 and d["not_patched_yet"] == 5
    assert d["counts"]["untracked"] == 5 and d["folder"]["on_disk"] == 8
    assert d["resume"] == shlex.join(["ppd", "poison", str(shoot)])  # a folder with a space is quoted
    text = runner.invoke(app, ["status", "castle"]).output
    said = f"castle: patched 3 of 8; 5 not patched yet: run `{d['resume']}`"
    assert " ".join(said.split()) in " ".join(text.split())
    assert "ppd verify" not in text  # verifying half a dataset says nothing: finish it first
    assert "files 8: not patched yet 5, patched 3" in text

    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    d = status_of("castle")
    assert d["counts"]["files"] == 8 and d["patched"] == 8
    assert d["not_patched_yet"] == 0 and d["resume"] is None


def test_out_copies_count_for_their_inputs_and_resume_keeps_out(ppd_env: dict, tmp_path: Path) -> None:
    shoot, out = tmp_path / "castle", tmp_path / "pub"
    for i in range(2):
        make_image(shoot / "sub" / f"view{i}.png", i)
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(out)]).exit_code == 0
    make_image(shoot / "sub" / "view2.png", 2)
    d = status_of("castle")
    assert d["counts"]["files"] == 3 and d["patched"] == 2 and d["not_patched_yet"] == 1
    assert d["folder"]["copies"] == str(out / "castle")  # OUT/DATASET, whatever folders lie below
    assert d["resume"] == shlex.join(["ppd", "poison", str(shoot), "--out", str(out)])  # never in place


def test_count_folder_leaves_out_masks_temporaries_and_other_files(tmp_path: Path) -> None:
    folder = tmp_path / "set"
    for name in ("a.jpg", "b.png", "masks/a.png", ".ppd-tmp-x.jpg", "readme.md", ".git/c.jpg"):
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(b"x")
    assert [p.name for p in folder_media(folder, skip=[folder / "masks"])] == ["a.jpg", "b.png"]
    rows = [{"path": str(folder / "a.jpg"), "state": "patched"}]
    count = count_folder(folder, rows, skip=[folder / "masks"])
    assert count.exists and count.on_disk == 2 and count.untracked == [folder / "b.png"]
    counts = with_folder({"files": 1, "patched": 1, "pending": 0}, count)
    assert counts["files"] == 2 and not_patched_yet(counts) == 1
    assert not_patched_yet({"files": 3, "pending": 2, "untracked": 0}) == 2  # unfinished rows too
    assert resume_command("other", count) == shlex.join(["ppd", "poison", str(folder), "--dataset", "other"])
    gone = count_folder(tmp_path / "gone", rows)
    assert not gone.exists and gone.untracked == []


# ---- a real run stopped by a real signal (subprocesses) -----------------------------------------
def _photos(folder: Path, n: int) -> None:
    """n JPEG photos heavy enough (noise at 1200x900) that a run takes a few seconds."""
    rng = np.random.default_rng(7)
    folder.mkdir(parents=True)
    base = rng.integers(0, 256, (900, 1200, 3), dtype=np.uint8)
    for i in range(n):
        Image.fromarray(np.roll(base, 37 * i, axis=1)).save(folder / f"IMG_{i:04d}.jpg", quality=92)


def _patched_rows(db: Path) -> int:
    if not db.exists():
        return 0
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1) as conn:
            return conn.execute("SELECT COUNT(*) FROM files WHERE state = 'patched'").fetchone()[0]
    except sqlite3.Error:
        return 0


@pytest.mark.integration
@pytest.mark.parametrize(
    ("workers", "signum", "group"),
    [("1", signal.SIGINT, True), ("2", signal.SIGINT, True), ("2", signal.SIGTERM, False)],
    ids=["serial-ctrl-c", "workers-ctrl-c", "workers-sigterm"],
)
def test_a_signal_mid_run_leaves_a_true_status_and_a_run_that_finishes(
    ppd_env: dict[str, Path], tmp_path: Path, workers: str, signum: int, group: bool
) -> None:
    shoot, n = tmp_path / "shoot", 23
    _photos(shoot, n)
    env = dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="200")  # a message on one line, at any width
    command = [sys.executable, "-m", "daemon.cli", "poison", str(shoot), "--workers", workers]
    # group: a terminal's Ctrl-C reaches every process of the foreground group (workers too)
    proc = subprocess.Popen(command, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while _patched_rows(ppd_env["data"] / "ppd.sqlite3") < 1:  # the moment: the first file is done
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    os.killpg(proc.pid, signum) if group else proc.send_signal(signum)
    out, err = proc.communicate(timeout=120)

    assert proc.returncode == 130, (out, err)
    assert "Traceback" not in err and "Traceback" not in out, err
    key = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"  # said at once, before the file ends
    assert f"ppd: {key}: stopping after the file in progress; {key} again (after 3 s) stops now" in err, err
    (start,) = [i for i, x in enumerate(out.splitlines()) if x.startswith("interrupted:")]
    line = " ".join(" ".join(out.splitlines()[start:]).split())  # wrapped at spaces to the width
    resume = shlex.join(["ppd", "poison", str(shoot), "--workers", workers])
    assert " ".join(f"not patched yet: run `{resume}` to finish".split()) in line
    d = status_of("shoot")
    on_disk = len(list(shoot.glob("*.jpg")))
    assert d["counts"]["files"] == on_disk == n  # the folder's files, not only the rows
    assert d["patched"] >= 1 and d["patched"] + d["not_patched_yet"] == n, d["counts"]
    assert d["patched"] < n and d["resume"] == shlex.join(["ppd", "poison", str(shoot)])
    assert f"{n - d['patched']} of {n} not patched yet" in line  # the run's line and status agree
    assert not list(shoot.glob(".ppd-tmp-*"))  # nothing half-written

    resumed = subprocess.run([sys.executable, "-m", "daemon.cli", "poison", str(shoot)], env=env, cwd=REPO,
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    d = status_of("shoot")
    assert d["patched"] == d["counts"]["files"] == n and d["not_patched_yet"] == 0


# ---- Ctrl-C while another ppd process works on the file (subprocesses) ---------------------------
def _lines_of(stream: IO[str], into: list[str]) -> threading.Thread:
    """A thread that appends each line of stream to into (a wait of 600 s never blocks the test)."""
    thread = threading.Thread(target=lambda: into.extend(iter(stream.readline, "")), daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize("workers", ["1", "2"], ids=["serial", "workers"])
def test_ctrl_c_while_another_ppd_process_holds_the_file_leaves_the_wait_at_once(
    ppd_env: dict[str, Path], tmp_path: Path, workers: str
) -> None:
    """`ppd poison` meeting a clip `ppd watch` was encoding (a third black-box review, S7): Ctrl-C
    said "stopping after the file in progress" and kept waiting for the watch's file. The file is
    the other process's: the wait ends at once, the file untouched by this run, exit 130."""
    from daemon.locks import file_lock
    from daemon.store.vault import Vault

    shoot = tmp_path / "shoot"
    busy = make_image(shoot / "a.png", 0)  # another ppd process works on it: this test holds its lock
    if workers == "2":  # a worker waits while another patches b.png: the worker's wait ends too
        make_image(shoot / "b.png", 1)
    original = hashlib.sha256(busy.read_bytes()).hexdigest()
    env = dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="200")  # a message on one line, at any width
    command = [sys.executable, "-m", "daemon.cli", "poison", str(shoot), "--workers", workers]
    err: list[str] = []
    with file_lock(ppd_env["data"], busy):
        proc = subprocess.Popen(command, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, start_new_session=True)  # fmt: skip
        assert proc.stdout is not None and proc.stderr is not None
        reader = _lines_of(proc.stderr, err)
        deadline = time.monotonic() + 60
        while not any("a.png: waiting for another ppd process" in line for line in err):  # after 2 s
            assert proc.poll() is None and time.monotonic() < deadline, err
            time.sleep(0.05)
        if workers == "2":
            while _patched_rows(ppd_env["data"] / "ppd.sqlite3") < 1:
                assert proc.poll() is None and time.monotonic() < deadline, err
                time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C: the whole group
        signalled = time.monotonic()
        try:
            proc.wait(timeout=10)  # the lock is still held: only leaving the wait ends the run
        finally:
            proc.kill()
        took = time.monotonic() - signalled
        out = proc.stdout.read()
        reader.join(5)
    said = "".join(err)
    assert proc.returncode == 130 and took < 3, (took, out, said)
    assert "Traceback" not in said
    assert f"a.png: stopped waiting for another ppd process (pid {os.getpid()}) working on it" in said
    if workers == "1":  # nothing of its own was in progress
        assert "stopping after the file in progress" not in said
    patched = 1 if workers == "2" else 0
    assert f"interrupted: patched {patched}, unchanged 0, skipped 0, failed 0; 1 of {patched + 1} not" in out
    assert hashlib.sha256(busy.read_bytes()).hexdigest() == original  # untouched by this run
    assert not Vault(ppd_env["data"] / "vault").has(original) and not list(shoot.glob(".ppd-tmp-*"))
    assert list((ppd_env["data"] / "locks" / "files").iterdir()) == []  # nothing left behind
