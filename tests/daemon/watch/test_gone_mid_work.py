"""A file that goes while the daemon patches it (deleted, or its folder renamed): a real daemon with
its worker processes, real inotify events, a real store. Found by a black-box review: the file
counted `failed` (a warning naming `[Errno 2] No such file or directory`), then `removed` as well,
and a folder renamed under the daemon said `removed` twice for one file."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import pytest

from daemon.states import FileState
from poisoner.atomic import TEMP_PREFIX
from testkit.daemon_proc import wait_for
from testkit.photos import write_image
from tests.daemon.watch.test_watcher import running, store_of, wait_idle

# Big enough that its patch takes a while (~0.5 s on a free core), so it is still in flight when the
# test sees its attempt marker appear and pulls it away.
BIG = 2000


def in_flight(data: Path, timeout: float = 30.0) -> None:
    """Until a worker holds an attempt marker: the file's heavy work has begun."""
    deadline = time.monotonic() + timeout
    while not any((data / "attempts").glob("*.json")):
        assert time.monotonic() < deadline, "no file was ever in flight"
        time.sleep(0.005)


def lines(caplog: pytest.LogCaptureFixture, name: str) -> list[logging.LogRecord]:
    return [r for r in caplog.records if getattr(r, "file", "").endswith(f"/{name}")]


def ppd_leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if p.name.startswith(TEMP_PREFIX)]


def test_a_file_deleted_mid_patch_counts_once_as_removed(
    ppd_env: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    src = write_image(tmp_path / "stage" / "p0.png", 1, size=BIG)
    ds = ppd_env["outbox"] / "d"
    ds.mkdir()
    caplog.set_level(logging.INFO, logger="daemon.watch")
    with running(ppd_env) as daemon:
        os.rename(src, ds / "p0.png")
        in_flight(ppd_env["data"])
        (ds / "p0.png").unlink()
        wait_for(lambda: daemon.counts.removed >= 1, 30, "the deletion counted")
        wait_idle(daemon)
        counts = daemon.counts
    assert (counts.failed, counts.removed, counts.patched) == (0, 1, 0), counts
    said = lines(caplog, "p0.png")
    assert [r.getMessage() for r in said] == ["removed p0.png"], [r.getMessage() for r in said]
    assert said[0].levelno == logging.INFO and said[0].outcome == "removed"  # type: ignore[attr-defined]
    assert not any(r.levelno >= logging.WARNING for r in caplog.records), caplog.text
    row = store_of(ppd_env).file(ds / "p0.png")
    assert row is None or row["state"] == FileState.REMOVED, row
    assert os.listdir(ds) == []  # nothing of ppd's left where the file was


def test_a_folder_renamed_mid_patch_counts_each_file_once(
    ppd_env: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    stage = tmp_path / "stage"
    small = [write_image(stage / f"s{i}.png", 10 + i) for i in range(3)]
    big = write_image(stage / "p0.png", 1, size=BIG)
    ds, renamed = ppd_env["outbox"] / "d", ppd_env["outbox"] / "d2"
    ds.mkdir()
    caplog.set_level(logging.INFO, logger="daemon.watch")
    with running(ppd_env) as daemon:
        for f in small:
            os.rename(f, ds / f.name)
        wait_for(lambda: daemon.counts.patched >= 3, 30, "the small files patched")
        wait_idle(daemon)
        os.rename(big, ds / big.name)
        in_flight(ppd_env["data"])
        os.rename(ds, renamed)
        wait_for(lambda: daemon.counts.removed >= 4 and daemon.counts.patched >= 4, 60, "gone, p0 new")
        wait_idle(daemon)
        counts = daemon.counts
    # 3 patched files moved (their new paths: unchanged, ppd's own output), p0 patched at its new
    # path; each old path removed once
    assert (counts.failed, counts.removed, counts.patched) == (0, 4, 4), counts
    for name in ("s0.png", "s1.png", "s2.png", "p0.png"):
        said = [r for r in lines(caplog, name) if r.file.startswith(f"{ds}/")]  # type: ignore[attr-defined]
        assert [r.getMessage() for r in said if r.outcome == "removed"] == [f"removed {name}"], name  # type: ignore[attr-defined]
    assert not any(r.levelno >= logging.WARNING for r in caplog.records), caplog.text
    store = store_of(ppd_env)
    assert store.file(renamed / "p0.png")["state"] == FileState.PATCHED
    assert all(store.file(ds / n)["state"] == FileState.REMOVED for n in ("s0.png", "s1.png", "s2.png"))
    assert ppd_leftovers(renamed) == []
