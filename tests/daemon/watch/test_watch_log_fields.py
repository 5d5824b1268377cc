"""The daemon's lines, from a real daemon on real files (a black-box review): a symlink quarantined
says the fields every file's line carries; a file waited for is said "incomplete, waiting" once at
info (re-checks at debug), and once complete it is `event=new`, not `changed` (ppd's own waiting
row made it look seen before)."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import pytest

from testkit.daemon_proc import wait_for
from testkit.photos import write_image
from tests.daemon.watch.test_watcher import FAST, running, wait_idle


def test_a_symlink_quarantined_says_the_fields_of_every_file_line(
    ppd_env: dict[str, Path], caplog: pytest.LogCaptureFixture
) -> None:
    outside = write_image(ppd_env["outbox"].parent / "elsewhere" / "real.png", 4)
    ds = ppd_env["outbox"] / "shoot"
    ds.mkdir()
    caplog.set_level(logging.INFO, logger="daemon.watch")
    with running(ppd_env) as daemon:
        (ds / "link.png").symlink_to(outside)
        wait_for(lambda: daemon.counts.quarantined >= 1, 20, "the link quarantined")
        wait_idle(daemon)
    (line,) = [r for r in caplog.records if "link.png" in r.getMessage()]
    assert line.getMessage() == "quarantined link.png" and line.levelno == logging.WARNING
    moved = ppd_env["outbox"].parent / "ppd-quarantine" / "shoot" / "link.png"
    fields = {k: getattr(line, k, None) for k in ("event", "dataset", "file", "outcome", "to")}
    assert fields == {
        "event": "new", "dataset": "shoot", "file": str(ds / "link.png"), "outcome": "quarantined",
        "to": str(moved),
    }  # fmt: skip
    assert "symlink" in line.reason  # type: ignore[attr-defined]


def test_a_file_waited_for_is_said_once_and_is_new_once_complete(
    ppd_env: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = write_image(tmp_path / "whole.png", seed=8, size=256).read_bytes()
    target = ppd_env["outbox"] / "trip" / "cut.png"
    target.parent.mkdir()
    caplog.set_level(logging.DEBUG, logger="daemon.watch")
    with running(ppd_env, dataclasses.replace(FAST, incomplete_wait_s=60.0)) as daemon:
        target.write_bytes(data[: len(data) // 2])  # a writer that paused half way
        wait_for(lambda: daemon.counts.skipped >= 3, 30, "three checks of the half file")
        with open(target, "ab") as fh:  # the writer goes on
            fh.write(data[len(data) // 2 :])
        wait_for(lambda: daemon.counts.patched >= 1, 60, "the completed file patched")
        wait_idle(daemon)
    waiting = [r for r in caplog.records if r.getMessage().startswith("incomplete, waiting for its writer")]
    assert len(waiting) >= 3
    assert [r.levelno for r in waiting] == [logging.INFO] + [logging.DEBUG] * (len(waiting) - 1)
    (patched,) = [r for r in caplog.records if r.getMessage() == "patched cut.png"]
    assert patched.event == "new"  # type: ignore[attr-defined]
