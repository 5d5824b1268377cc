"""One `ppd watch` per outbox, and none on a folder above or inside a watched one (a black-box review:
`ppd watch /outbox/nest` beside `ppd watch` on /outbox was accepted, and both processed the same
files). The locks themselves (in this process: flock locks exclude open file descriptions of one
process too), then the command line with a real daemon."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.locks import LockHeld, outbox_lock
from testkit.reliability import DAEMON_ARGS, REPO, kill_daemon, start_daemon, subprocess_env


def refused(data: Path, outbox: Path, why: str) -> None:
    with pytest.raises(LockHeld, match=why), outbox_lock(data, outbox):
        pass


def test_a_folder_inside_a_watched_outbox_is_refused_and_the_converse(tmp_path: Path) -> None:
    data, outbox, pid = tmp_path / "data", tmp_path / "outbox", os.getpid()
    nest = outbox / "nest"
    nest.mkdir(parents=True)
    (tmp_path / "elsewhere").mkdir()
    with outbox_lock(data, outbox):
        refused(data, nest, rf"\(pid {pid}\) is already watching {outbox}, which holds {nest}$")
        refused(data, outbox, rf"\(pid {pid}\) is already watching {outbox}$")
        with outbox_lock(data, tmp_path / "elsewhere"):  # a sibling: free
            pass
    with outbox_lock(data, nest), outbox_lock(data, outbox / "other"):  # two siblings below one folder
        refused(data, outbox, rf"\(pid {pid}\) is already watching {outbox}/(nest|other), inside {outbox}$")
        refused(data, tmp_path, rf"is already watching {outbox}/(nest|other), inside {tmp_path}$")
    with outbox_lock(data, outbox), outbox_lock(data, tmp_path / "elsewhere"):
        pass  # all released


def test_a_symlink_to_a_folder_inside_the_outbox_is_the_same_folder(tmp_path: Path) -> None:
    data, outbox = tmp_path / "data", tmp_path / "outbox"
    (outbox / "nest").mkdir(parents=True)
    (tmp_path / "link").symlink_to(outbox / "nest")
    with outbox_lock(data, outbox):
        refused(data, tmp_path / "link", "which holds")


def test_ppd_watch_on_a_folder_inside_a_watched_outbox_exits_3_with_one_line(tmp_path: Path) -> None:
    nest = tmp_path / "outbox" / "nest"
    nest.mkdir(parents=True)
    first = start_daemon(tmp_path, *DAEMON_ARGS)
    second = subprocess.Popen(
        [sys.executable, "-m", "daemon.cli", "watch", str(nest), *DAEMON_ARGS], env=subprocess_env(tmp_path),
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        out, err = second.communicate(timeout=60)
    except subprocess.TimeoutExpired:  # it was accepted, and watches (the defect)
        second.kill()
        out, err = second.communicate()
    finally:
        assert kill_daemon(first, signal.SIGTERM) == 0
    said = (err + out).strip()
    assert second.returncode == 3, said
    assert len(said.splitlines()) == 1, said
    flat = " ".join(said.split())
    assert (
        f"another ppd watch (pid {first.pid}) is already watching {tmp_path / 'outbox'}, which holds {nest}"
        in flat
    )
