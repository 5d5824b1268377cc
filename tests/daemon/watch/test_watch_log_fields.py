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


def test_a_name_that_is_not_utf8_is_one_clean_line_and_status_says_where_it_went(
    ppd_env: dict[str, Path], caplog: pytest.LogCaptureFixture
) -> None:
    """A black-box review (F7): the daemon quarantined caf\\xe9.png and logged Python's codec text at
    error level ("could not record it: 'utf-8' codec can't encode ..."), the name shown two ways
    (caf\\udce9 and caf\\xe9); `ppd status --failed` then said "0 quarantined" and named it nowhere."""
    import os

    from typer.testing import CliRunner

    from daemon.cli import app
    from daemon.cli.output import KeyValueFormatter

    staging = ppd_env["outbox"].parent / "staging"
    write_image(staging / "ok.png", 1)
    os.rename(write_image(staging / "x.png", 2), os.fsencode(staging) + b"/caf\xe9.png")
    caplog.set_level(logging.INFO)
    with running(ppd_env) as daemon:
        staging.rename(ppd_env["outbox"] / "odd")  # a shoot moved in whole
        wait_for(lambda: daemon.counts.quarantined >= 1 and daemon.counts.patched >= 1, 20, "both done")
        wait_idle(daemon)
    lines = [KeyValueFormatter().format(r) for r in caplog.records if r.levelno >= logging.WARNING]
    (line,) = [x for x in lines if "caf" in x]  # one line: the daemon's own for the file
    assert "codec" not in line and "udce9" not in line and "outcome=quarantined" in line, lines
    assert line.count("caf\\\\xe9.png") == 4, line  # msg, file, reason and to: one spelling
    status = CliRunner().invoke(app, ["status", "odd", "--failed"])
    held = ppd_env["outbox"].parent / "ppd-quarantine" / "odd" / "caf\\xe9.png"
    assert status.output.splitlines()[:2] == [
        "odd: 0 failed, 1 quarantined",
        f"  {held}: the file name is not valid UTF-8 (ppd records names as UTF-8): rename it and move it "
        "back into the outbox (quarantined)",
    ], status.output
