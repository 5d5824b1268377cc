"""`ppd restore NAME` while `ppd watch` is still patching a drop in that dataset (a black-box review, F13):
it said "restored N", exit 0, of the files patched so far, nothing of those the daemon held, and the
daemon then marked them. Now a file the restore meets mid-patch is waited for (its lock) and restored;
the files the daemon has yet to patch are counted in one line that says what to do, exit 3 (another
ppd holds them). A real `ppd watch`, real watchdog events, a real writer process."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from daemon.states import FileState
from daemon.store import Store
from testkit.cli import said
from testkit.daemon_proc import REPO, start_daemon, stop_daemon, wait_for
from testkit.photos import make_image, make_shoot
from testkit.reliability import DAEMON_ARGS


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _state(data: Path, path: Path) -> str | None:
    store = Store(data / "ppd.sqlite3")
    try:
        row = store.file(path)
    finally:
        store.close()
    return None if row is None else row["state"]


def test_a_photo_the_daemon_has_yet_to_patch_is_said_not_restored(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The third photo of a drop is still open in its writer: the daemon patches it once it is closed.
    The restore puts the two patched ones back and says the third is not, exit 3; once the daemon is
    idle, the same command restores it."""
    data, shoot = ppd_env["data"], ppd_env["outbox"] / "shoot"
    make_shoot(shoot, 2)
    originals = {p: _sha(p) for p in shoot.iterdir()}
    photo = make_image(tmp_path / "v2.png", 2)
    originals[shoot / "v2.png"] = _sha(photo)
    writer = subprocess.Popen([sys.executable, "-c", f"f = open({str(photo)!r}, 'ab'); print(1, flush=True); "
                               "import time; time.sleep(60)"], stdout=subprocess.PIPE)  # fmt: skip
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)  # the folders ppd_env made, under tmp_path
    try:
        wait_for(lambda: all(_state(data, p) == FileState.PATCHED for p in originals if p.exists()), 60,
                 "the first two patched")  # fmt: skip
        assert writer.stdout is not None and writer.stdout.readline()  # open for writing now
        late = photo.rename(shoot / "v2.png")  # complete, but its writer has not closed it
        code, text = said("restore", "shoot")
        assert code == 3, text  # before: 0, and the daemon marked v2.png afterwards
        assert "restored 2" in text, text
        assert (
            "ppd: not restored: 1 file(s) of dataset 'shoot' that the running ppd watch (pid "
            f"{daemon.pid}) is patching or has yet to patch; it marks them: run `ppd restore shoot` "
            "again when it is idle" in text
        ), text
        writer.kill()  # closed: the daemon patches it, as the line said
        writer.wait()
        wait_for(lambda: _state(data, late) == FileState.PATCHED, 60, "v2.png patched once closed")
        code, text = said("restore", "shoot")
        assert code == 0 and "restored 1, removed 0, unchanged 0, failed 0" in text, text
        assert "not restored" not in text, text
    finally:
        writer.kill()
        writer.wait()
        stop_daemon(daemon)
    assert {p: _sha(p) for p in originals} == originals


def test_a_photo_the_daemon_is_patching_is_waited_for_and_restored(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The restore comes while the daemon patches the photo (its row pending, the file still the
    original): it said "unchanged 1" (state is pending), exit 0, and the daemon then marked it. Now the
    restore waits for the file's lock, then puts the original back."""
    data, shoot = ppd_env["data"], ppd_env["outbox"] / "shoot"
    big = make_image(tmp_path / "stage" / "big.png", 7, size=(3000, 2000))  # seconds to patch
    original = _sha(big)
    shoot.mkdir()
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)
    try:
        photo = big.rename(shoot / "big.png")
        wait_for(lambda: _state(data, photo) == FileState.PENDING, 60, "big.png being patched")
        code, text = said("restore", "shoot")
        assert code == 0 and "restored 1, removed 0, unchanged 0, failed 0" in text, text
        wait_for(lambda: _state(data, photo) == FileState.RESTORED, 10, "recorded restored")
    finally:
        stop_daemon(daemon)
    assert _sha(photo) == original  # before: ppd's output, the restore having said "unchanged"
    assert _state(data, photo) == FileState.RESTORED


@pytest.mark.parametrize("holder", ["watch", "poison"])
def test_a_file_held_past_the_lock_wait_is_said_and_the_others_are_restored(
    ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch, holder: str
) -> None:
    """Another ppd process still works on b.png when the restore's wait for its lock ends (the daemon
    encoding a long video: 600 s; 1 s here). The lock's error ended `ppd restore shoot` there, exit 3,
    with one line: c.png never restored, and no line said a.png was. Now a.png and c.png are restored
    and said, and b.png is counted in the running ppd watch's line, or (another `ppd poison` holds it)
    named with its holder; exit 3 either way: another ppd holds it."""
    from daemon.context import AppContext

    data, shoot = ppd_env["data"], ppd_env["outbox"] / "shoot"
    for i, name in enumerate(["a.png", "b.png", "c.png"]):
        make_image(shoot / name, i)
    originals = {p: _sha(p) for p in shoot.iterdir()}
    assert said("poison", str(shoot))[0] == 0
    opened = AppContext.open.__func__  # type: ignore[attr-defined]

    def short_wait(cls: type[AppContext], *args: Any, **kwargs: Any) -> AppContext:
        ctx: AppContext = opened(cls, *args, **kwargs)
        ctx.lock_wait_s = 1.0
        return ctx

    monkeypatch.setattr(AppContext, "open", classmethod(short_wait))
    watch = f"outbox_lock(d, Path({str(ppd_env['outbox'])!r})), " if holder == "watch" else ""
    held = subprocess.Popen(
        [sys.executable, "-c",
         "import time; from pathlib import Path; from daemon.locks import file_lock, outbox_lock\n"
         f"d = Path({str(data)!r})\n"
         f"with {watch}file_lock(d, Path({str(shoot / 'b.png')!r})):\n"
         "    print('held', flush=True); time.sleep(60)"],
        cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert held.stdout is not None and held.stdout.readline().strip() == "held"
        code, text = said("restore", "shoot")
    finally:
        held.kill()
        held.wait()
    assert code == 3, text
    assert "restored 2, removed 0, unchanged 0, failed 0" in text, text
    if holder == "watch":
        assert (
            f"ppd: not restored: 1 file(s) of dataset 'shoot' that the running ppd watch (pid {held.pid}) "
            "is patching or has yet to patch" in text
        ), text
        assert "being worked on" not in text, text  # said once, in that line
    else:
        assert (
            f"ppd: not restored: {shoot / 'b.png'}: b.png is being worked on by another ppd process "
            f"(pid {held.pid}); waited 1 s, try later" in text
        ), text
    assert {p.name for p in originals if _sha(p) == originals[p]} == {"a.png", "c.png"}
    assert _state(data, shoot / "b.png") == FileState.PATCHED
    code, text = said("restore", "shoot")  # the holder gone: the same command restores it
    assert code == 0 and "restored 1, removed 0, unchanged 0, failed 0" in text, text
    assert {p: _sha(p) for p in originals} == originals
