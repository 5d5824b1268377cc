"""The daemon says what it did: a real `ppd watch` process, real files dropped in its outbox, a
real Ctrl-C. One key=value line per file (event, dataset, file, outcome, seconds), one count per
file in the stop summary, no traceback, workers drained."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from daemon.protect.one_file import AppContext
from daemon.states import FileState
from testkit.photos import make_image

REPO = Path(__file__).resolve().parents[3]
pytestmark = pytest.mark.integration


class Watch:
    """`ppd watch` in its own process group (a terminal's Ctrl-C reaches the whole group)."""

    def __init__(self) -> None:
        env = dict(os.environ, PYTHONPATH=str(REPO))
        env.pop("PPD_LOG_LEVEL", None)
        command = [sys.executable, "-m", "daemon.cli", "watch", "--no-verify", "--debounce", "0.3"]
        self.proc = subprocess.Popen(
            command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True,
        )  # fmt: skip
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, what: str, test, timeout: float = 60) -> None:
        deadline = time.monotonic() + timeout
        while not test():
            assert self.proc.poll() is None, "\n".join(self.lines)
            assert time.monotonic() < deadline, f"timed out waiting for {what}:\n" + "\n".join(self.lines)
            time.sleep(0.05)

    def ctrl_c(self) -> int:
        os.killpg(self.proc.pid, signal.SIGINT)
        rc = self.proc.wait(timeout=120)
        self._reader.join(10)
        return rc


def rows(ppd_env: dict[str, Path], dataset: str) -> list[dict]:
    ctx = AppContext.open()
    try:
        return ctx.store.files(dataset) if ctx.store.dataset(dataset) else []
    finally:
        ctx.close()


FIELD = re.compile(r'(\w+)=("(?:[^"\\]|\\.)*"|\S+)')


def fields(line: str) -> dict[str, str]:
    """key=value pairs of one log line, a quoted value (a path with a space) unquoted as
    daemon.cli.output._field quotes it."""
    unescape = {"n": "\n"}
    return {
        key: re.sub(r"\\(.)", lambda m: unescape.get(m[1], m[1]), value[1:-1])
        if value.startswith('"')
        else value
        for key, value in FIELD.findall(line)
    }


def test_the_daemon_names_each_file_once_and_stops_cleanly_on_ctrl_c(ppd_env: dict[str, Path]) -> None:
    watch = Watch()
    watch.wait_for("ready", lambda: any("ppd watch ready" in x for x in watch.lines))
    kitchen = ppd_env["outbox"] / "kitchen"
    staging = ppd_env["outbox"].parent / "staging"
    kitchen.mkdir()
    for i in range(5):  # written elsewhere, moved in whole: as a camera app or a sync client does
        shutil.move(make_image(staging / f"IMG_{i}.png", i, size=(640, 480)), kitchen / f"IMG_{i}.png")
    (staging / "notes.jpg").write_text("a text file with a photo's name")
    shutil.move(staging / "notes.jpg", kitchen / "notes.jpg")
    watch.wait_for("5 patched, 1 quarantined", lambda: sorted(r["state"] for r in rows(ppd_env, "kitchen"))
                   == [FileState.PATCHED.value] * 5 + [FileState.QUARANTINED.value])  # fmt: skip
    watch.wait_for("the quarantine line", lambda: any("outcome=quarantined" in x for x in watch.lines))
    rc = watch.ctrl_c()
    text = "\n".join(watch.lines)

    assert rc == 0, text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text
    per_file = [fields(x) for x in watch.lines if "outcome=" in x]
    names = sorted(Path(f["file"]).name for f in per_file)
    assert names == [*(f"IMG_{i}.png" for i in range(5)), "notes.jpg"]
    for f in per_file:  # every line names its event, dataset, file, outcome and time
        assert f["event"] == "new" and f["dataset"] == "kitchen" and float(f["seconds"]) >= 0
        assert f["outcome"] == ("quarantined" if f["file"].endswith("notes.jpg") else "patched")
    (quarantined,) = [x for x in watch.lines if "outcome=quarantined" in x]
    assert "not a recognised image" in quarantined and "incomplete" not in quarantined
    assert "to=" in quarantined  # where the file went
    # one count per file: the quarantined upload is not "failed" as well
    assert "stopped: patched 5, failed 0, quarantined 1" in text
    assert "idle worker" not in text  # quiet otherwise
    warnings = [x for x in watch.lines if "level=warning" in x and "outcome=" not in x]
    assert all("notes.jpg" in x for x in warnings), warnings  # each names its file


def test_ctrl_c_with_files_in_flight_drains_the_workers(ppd_env: dict[str, Path]) -> None:
    watch = Watch()
    watch.wait_for("ready", lambda: any("ppd watch ready" in x for x in watch.lines))
    shoot, staging = ppd_env["outbox"] / "shoot", ppd_env["outbox"].parent / "staging"
    originals = {}
    shoot.mkdir()
    for i in range(12):
        src = make_image(staging / f"IMG_{i}.png", i, size=(1600, 1200))
        originals[f"IMG_{i}.png"] = src.read_bytes()
        shutil.move(src, shoot / f"IMG_{i}.png")
    watch.wait_for("a first file", lambda: any("outcome=patched" in x for x in watch.lines))
    rc = watch.ctrl_c()  # the workers are busy with the next ones
    text = "\n".join(watch.lines)

    assert rc == 0 and "Traceback" not in text and "KeyboardInterrupt" not in text, text
    assert "stopped:" in text
    by_path = {Path(r["path"]).name: r for r in rows(ppd_env, "shoot")}
    for name, before in originals.items():  # each file whole: the original, or patched with its row
        now = (shoot / name).read_bytes()
        row = by_path.get(name)
        if now == before:
            assert row is None or row["state"] != FileState.PATCHED.value, name
        else:
            assert row is not None and row["state"] == FileState.PATCHED.value, name
    assert not list(shoot.glob(".ppd-tmp-*"))
    patched_lines = [x for x in watch.lines if "outcome=patched" in x]
    assert len(patched_lines) == sum(r["state"] == FileState.PATCHED.value for r in by_path.values())
