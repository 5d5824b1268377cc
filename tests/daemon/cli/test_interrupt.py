"""An interrupted `ppd poison` is visible and resumable: `ppd status` counts the dataset's files
from its folder as well as its rows, Ctrl-C / SIGTERM end the run between files with one line and
the command that finishes it, and no process prints a traceback. Real `ppd` processes, real
signals, the real store."""

from __future__ import annotations

import contextlib
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
from collections.abc import Callable
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
    # the files line names a killed run's rows in words: "pending 2" was never explained (a review, F15)
    from daemon.cli.status_cmd import files_line

    line = files_line({"files": 5, "patched": 2, "pending": 2, "untracked": 1})
    assert "interrupted mid-patch 2" in line and "pending" not in line, line
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


def _words(text: str) -> str:
    """text with its lines joined: a line wrapped at the terminal's width (CI's 40 columns) reads whole."""
    return " ".join(text.split())


def _start_poison(
    shoot: Path, workers: str, err: list[str]
) -> tuple[subprocess.Popen[str], threading.Thread]:
    """`ppd poison shoot --workers N` in a session of its own (a terminal's foreground group), its
    stderr's lines appended to err as they come (by the thread)."""
    command = [sys.executable, "-m", "daemon.cli", "poison", str(shoot), "--workers", workers]
    env = dict(os.environ, PYTHONPATH=str(REPO))  # the terminal's width: lines are compared as words
    proc = subprocess.Popen(command, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)  # fmt: skip
    assert proc.stderr is not None
    return proc, _lines_of(proc.stderr, err)


def _ended(proc: subprocess.Popen[str], reader: threading.Thread, timeout: float) -> str:
    """proc's stdout once it exits within timeout (killed otherwise); its stderr read to the end."""
    assert proc.stdout is not None
    try:
        proc.wait(timeout=timeout)
    finally:
        proc.kill()
    reader.join(5)
    return proc.stdout.read()


def _until(done: Callable[[], bool], proc: subprocess.Popen[str], err: list[str], within: float = 60) -> None:
    deadline = time.monotonic() + within
    while not done():
        assert proc.poll() is None and time.monotonic() < deadline, err
        time.sleep(0.02)


@pytest.mark.parametrize("workers", ["1", "2"], ids=["serial", "workers"])
def test_ctrl_c_while_another_ppd_process_holds_the_file_leaves_the_wait_at_once(
    ppd_env: dict[str, Path], tmp_path: Path, workers: str
) -> None:
    """`ppd poison` meeting a clip `ppd watch` was encoding (a third black-box review, S7): Ctrl-C
    said "stopping after the file in progress" and kept waiting for the watch's file. The file is
    the other process's: the wait ends at once, the file untouched by this run, exit 130, and no
    line says a file of this run is finishing: none is. With workers, every file is another
    process's: the waits are in the workers, the Ctrl-C in their caller, which said that line
    anyway (a diff review); a file the pool had queued starts no wait after the Ctrl-C."""
    from daemon.locks import file_lock
    from daemon.store.vault import Vault

    shoot = tmp_path / "shoot"
    names = ["a.png"] if workers == "1" else ["a.png", "b.png", "c.png"]  # c.png: queued behind two waits
    busy = [make_image(shoot / name, i) for i, name in enumerate(names)]  # another ppd process works on them
    originals = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in busy}
    err: list[str] = []
    with contextlib.ExitStack() as held:  # this test is the other process: it holds every file's lock
        for path in busy:
            held.enter_context(file_lock(ppd_env["data"], path))
        proc, reader = _start_poison(shoot, workers, err)
        waiting = names[: int(workers)]  # the files the workers took first, each waited for (said after 2 s)
        _until(lambda: all(f"{n}: waiting for another ppd" in "".join(err) for n in waiting), proc, err)
        os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C: the whole group
        signalled = time.monotonic()
        out = _ended(proc, reader, timeout=10)  # the locks are still held: only leaving the waits ends it
        took = time.monotonic() - signalled
    said = _words("".join(err))
    assert proc.returncode == 130 and took < 3, (took, out, said)
    assert "Traceback" not in said
    for name in waiting:
        assert f"{name}: stopped waiting for another ppd process (pid {os.getpid()}) working on it" in said
    assert "stopping after the file in progress" not in said  # nothing of its own was in progress
    assert "c.png" not in said  # never started: no wait of its own to leave
    n = len(names)
    assert f"interrupted: patched 0, unchanged 0, skipped 0, failed 0; {n} of {n} not" in _words(out)
    for path, original in originals.items():
        assert hashlib.sha256(path.read_bytes()).hexdigest() == original  # untouched by this run
        assert not Vault(ppd_env["data"] / "vault").has(original)
    assert not list(shoot.glob(".ppd-tmp-*"))
    assert list((ppd_env["data"] / "locks" / "files").iterdir()) == []  # nothing left behind


def _lock_files_open(folder: Path) -> dict[int, set[str]]:
    """The lock files of folder each other process has open, by pid (Linux /proc; a removed one
    reads "NAME (deleted)")."""
    held: dict[int, set[str]] = {}
    for fd in Path("/proc").glob("[0-9]*/fd/*"):
        with contextlib.suppress(OSError):
            target = os.readlink(fd)
            if target.startswith(f"{folder}/") and int(fd.parts[2]) != os.getpid():
                held.setdefault(int(fd.parts[2]), set()).add(target)
    return held


def _paused_mid_file(folder: Path, other: str, paused: list[int]) -> bool:
    """Pause (SIGSTOP) a process that holds a lock file of folder besides other, one still held once
    paused: its file is in progress. Its pid goes to paused."""
    for pid, files in _lock_files_open(folder).items():
        own = {f for f in files if f != other and not f.endswith(" (deleted)")}
        if own:
            os.kill(pid, signal.SIGSTOP)
            paused.append(pid)
            assert own <= _lock_files_open(folder).get(pid, set()), "its file finished before the pause"
            return True
    return False


def test_ctrl_c_while_one_worker_waits_and_another_patches_says_the_file_in_progress(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """One worker waits for a file another ppd process works on, the other patches a file of the
    run's own: Ctrl-C says that file is finishing (it is), the wait ends at once, the file finishes.
    The patching worker is paused (SIGSTOP) mid-file, so that the Ctrl-C finds it there."""
    from daemon.locks import file_lock

    shoot, folder = tmp_path / "shoot", ppd_env["data"] / "locks" / "files"
    _photos(shoot, 1)  # IMG_0000.jpg: this run's own
    busy = make_image(shoot / "a.png", 0)
    err: list[str] = []
    paused: list[int] = []
    with file_lock(ppd_env["data"], busy):
        (busy_lock,) = [str(p) for p in folder.iterdir()]
        proc, reader = _start_poison(shoot, "2", err)
        try:
            _until(lambda: _paused_mid_file(folder, busy_lock, paused), proc, err)
            _until(lambda: "a.png: waiting for another ppd process" in "".join(err), proc, err)
            os.killpg(proc.pid, signal.SIGINT)
            _until(lambda: "a.png: stopped waiting" in "".join(err), proc, err, within=5)
        except BaseException:
            proc.kill()  # its workers end with it
            raise
        finally:
            for pid in paused:
                os.kill(pid, signal.SIGCONT)
        out = _ended(proc, reader, timeout=60)
    said = _words("".join(err))
    assert proc.returncode == 130, (out, said)
    assert "ppd: Ctrl-C: stopping after the file in progress; Ctrl-C again (after 3 s) stops now" in said
    assert "interrupted: patched 1, unchanged 0, skipped 0, failed 0; 1 of 2 not" in _words(out)
    assert "Traceback" not in said
