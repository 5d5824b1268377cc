"""A symlinked folder in the outbox (a review, rev8 F3): never followed, so its photos stay unmarked
while a publisher that follows links ships them. The daemon said nothing of one there at its start, and
"not a regular file, left alone" at info of one made while it ran. Now it warns of each link once, at
warning level, with the photos in it: at its start's catch-up, when one appears, and when a folder
holding one is moved in; a catch-up again (lost events) does not repeat it."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from testkit.daemon_proc import wait_for
from testkit.photos import make_shoot
from tests.daemon.watch.test_watcher import running, wait_idle


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno == logging.WARNING and "symlinked" in r.getMessage()
    ]


def test_each_symlinked_folder_is_warned_of_once_with_its_photos(
    ppd_env: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    outbox = ppd_env["outbox"]
    elsewhere, more = make_shoot(tmp_path / "elsewhere", 3), make_shoot(tmp_path / "more", 2)
    (outbox / "kitchen").mkdir()
    (outbox / "kitchen" / "day2").symlink_to(elsewhere)  # there at the start
    caplog.set_level(logging.INFO, logger="daemon.watch")
    with running(ppd_env) as daemon:
        wait_idle(daemon)
        (tmp_path / "garden").symlink_to(more)
        (tmp_path / "garden").rename(outbox / "garden")  # one appears
        nest = tmp_path / "nest"
        nest.mkdir()
        (nest / "inner").symlink_to(elsewhere)
        nest.rename(outbox / "nest")  # a folder holding one is moved in
        wait_for(lambda: len(_warnings(caplog)) >= 3, 30, "three links warned of")
        daemon.catch_up()  # as after lost events: said once already
        wait_idle(daemon)
    said = sorted(_warnings(caplog))
    assert said == sorted([
        f"symlinked folder {outbox / 'garden'} -> {more}: 2 photo(s) or video(s) in it NOT protected (ppd "
        "never follows a link; a publisher that does ships them): put the folder itself in place of the link",
        f"symlinked folder {outbox / 'kitchen' / 'day2'} -> {elsewhere}: 3 photo(s) or video(s) in it NOT "
        "protected (ppd never follows a link; a publisher that does ships them): put the folder itself in "
        "place of the link",
        f"symlinked folder {outbox / 'nest' / 'inner'} -> {elsewhere}: 3 photo(s) or video(s) in it NOT "
        "protected (ppd never follows a link; a publisher that does ships them): put the folder itself in "
        "place of the link",
    ]), said  # fmt: skip
    assert not list(elsewhere.glob(".ppd*")) and daemon.counts.patched == 0  # never followed
