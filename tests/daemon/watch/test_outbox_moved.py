"""The outbox moved to another disk (PPD_OUTBOX set anew, `ppd service install` again, as the README
says) and `ppd watch` started on it, as a real process. An eighth black-box review (F1): its catch-up
recorded each patched photo as moved, under the dataset whose folder still named the old outbox; `ppd
restore kitchen` then deleted them as `--out` copies ("restored 0, removed 3", exit 0), and `ppd dataset
forget` removed their only originals. The dataset follows its folder now, said once in the log, and
restore puts the originals back where the photos are; a file it cannot follow is never deleted."""

from __future__ import annotations

import hashlib
import shlex
import shutil
from pathlib import Path

import pytest

from daemon.context import AppContext
from testkit.cli import said
from testkit.daemon_proc import start_daemon, stop_daemon, wait_for
from testkit.photos import make_image, make_shoot
from testkit.reliability import DAEMON_ARGS


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _rows(paths: list[Path]) -> list[dict[str, object] | None]:
    ctx = AppContext.open()
    try:
        return [ctx.store.file(p) for p in paths]
    finally:
        ctx.close()


def _all(paths: list[Path], state: str) -> bool:
    return all((row or {}).get("state") == state for row in _rows(paths))


def _patched_shoot(outbox: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """outbox/kitchen, 3 photos patched by `ppd poison` on that outbox: their originals' hashes by name."""
    monkeypatch.setenv("PPD_OUTBOX", str(outbox))
    shoot = make_shoot(outbox / "kitchen", 3)
    originals = {p.name: _sha(p) for p in shoot.iterdir()}
    code, text = said("poison", str(shoot))
    assert code == 0, text
    return originals


@pytest.mark.parametrize("watched", [False, True], ids=["stopped-during-the-move", "watching-the-move"])
def test_ppd_watch_follows_a_moved_outbox_and_restore_gives_the_originals_back(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, watched: bool
) -> None:
    old, new = tmp_path / "Outbox 1", tmp_path / "disk 2" / "Outbox"
    originals = _patched_shoot(old, monkeypatch)
    make_image(old / "loose.png", 7)  # the outbox's own dataset, "default"
    assert said("poison", str(old / "loose.png"))[0] == 0
    olds = [old / "kitchen" / n for n in originals] + [old / "loose.png"]
    news = [new / "kitchen" / n for n in originals] + [new / "loose.png"]
    new.parent.mkdir()
    if watched:  # the service still on the old outbox sees it leave (records the files removed, makes the
        # outbox again, empty)
        daemon = start_daemon(tmp_path, *DAEMON_ARGS, outbox=old)
        try:
            old.rename(new)
            wait_for(lambda: _all(olds, "removed"), 30, "the old outbox's files recorded removed")
        finally:
            stop_daemon(daemon)
    else:
        old.rename(new)
    monkeypatch.setenv("PPD_OUTBOX", str(new))
    daemon = start_daemon(tmp_path, *DAEMON_ARGS, outbox=new)
    try:
        wait_for(lambda: _all(news, "patched"), 30, "the moved photos recorded patched where they are")
    finally:
        stop_daemon(daemon)
    log = " ".join(daemon.log.read_text().split())
    assert log.count(f"dataset kitchen's folder moved: {old / 'kitchen'} -> {new / 'kitchen'}") == 1, log
    assert log.count(f"dataset default's folder moved: {old} -> {new}") == 1, log
    assert "outcome=patched" not in log, log  # nothing marked twice
    code, shown = said("status", "kitchen")
    assert code == 0 and "files 3: patched 3" in shown, shown
    assert "gone" not in shown and "copies" not in shown, shown
    code, text = said("restore", "kitchen")
    assert code == 0 and "restored 3, removed 0" in text, text
    assert {p.name: _sha(p) for p in (new / "kitchen").iterdir()} == originals


def test_restore_never_deletes_a_moved_photo_it_cannot_follow_as_an_out_copy(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The photos moved into a subfolder of the new outbox (not at their relative paths: ppd cannot tell
    the folder moved): the daemon carries their rows there, outside the dataset's recorded folder, which
    is gone. Restore took such a row for an `--out` copy and deleted the photo; forget then removed its
    original. Now restore refuses (exit 1), naming the command that follows the folder, and forget keeps
    the originals; a real `--out` copy of a folder since deleted is removed as before (ppd recorded
    writing it as one)."""
    old, new = tmp_path / "Outbox 1", tmp_path / "Outbox 2"
    originals = _patched_shoot(old, monkeypatch)
    day = new / "kitchen" / "day 1"
    day.mkdir(parents=True)
    for name in originals:
        (old / "kitchen" / name).rename(day / name)
    shutil.rmtree(old)
    marked = {p.name: _sha(p) for p in day.iterdir()}
    monkeypatch.setenv("PPD_OUTBOX", str(new))
    daemon = start_daemon(tmp_path, *DAEMON_ARGS, outbox=new)
    try:
        wait_for(lambda: _all([day / n for n in originals], "patched"), 30, "the moved photos' rows carried")
    finally:
        stop_daemon(daemon)

    code, text = said("restore", "kitchen")
    assert code == 1 and "restored 0, removed 0" in text, text
    assert (f"lies outside the folder of dataset 'kitchen', {old / 'kitchen'}, which is gone, and ppd has no "
            "record of writing it as an --out copy") in text, text  # fmt: skip
    assert "`ppd dataset set kitchen --root NEWFOLDER` (the folder it is in now)" in text, text
    assert {p.name: _sha(p) for p in day.iterdir()} == marked  # nothing deleted, nothing changed
    code, text = said("dataset", "forget", "kitchen")
    assert code == 2 and "has 3 patched file(s) still there" in text, text  # the originals kept

    code, text = said("dataset", "set", "kitchen", "--root", str(new / "kitchen"))  # the way it names
    assert code == 0, text
    code, text = said("restore", "kitchen")
    assert code == 0 and "restored 3, removed 0" in text, text
    assert {p.name: _sha(p) for p in day.iterdir()} == originals

    source, out = tmp_path / "shoots" / "garden", tmp_path / "site"
    make_shoot(source, 2)
    code, text = said("poison", str(source), "--out", str(out))
    assert code == 0, text
    shutil.rmtree(source)  # the shoot deleted; its published copies are still ppd's to remove
    code, text = said("restore", "garden")
    assert code == 0 and "removed 2" in text, text
    assert not any((out / "garden").glob("*.png")), shlex.join(map(str, (out / "garden").iterdir()))
