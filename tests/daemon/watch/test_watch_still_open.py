"""A photo another program holds open for writing: the daemon skips it and says it patches it once
closed, which it does (its close re-arms the watcher). `ppd poison`, which patches nothing later, says
to run it again (tests/daemon/cli/test_cli_unsupported.py): the skip's reason is the fact alone, each
front end says what follows (a black-box review read the daemon's promise in `ppd -v poison`)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from daemon.protect.one_file import AppContext
from daemon.states import FileState
from testkit.daemon_proc import start_daemon, stop_daemon, wait_for
from testkit.photos import make_image
from testkit.reliability import DAEMON_ARGS


def _state(path: Path) -> str | None:
    ctx = AppContext.open()
    try:
        row = ctx.store.file(path)
    finally:
        ctx.close()
    return None if row is None else row["state"]


def test_the_daemon_says_it_patches_a_file_once_its_writer_closes_it(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    photo = make_image(tmp_path / "b.jpg", 2, size=(200, 150))
    writer = subprocess.Popen([sys.executable, "-c", f"f = open({str(photo)!r}, 'ab'); print(1, flush=True); "
                               "import time; time.sleep(60)"], stdout=subprocess.PIPE)  # fmt: skip
    target = ppd_env["outbox"] / "shoot" / "b.jpg"
    target.parent.mkdir()  # watched from the start: the rename is seen at once
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)  # the folders ppd_env made, under tmp_path
    try:
        assert writer.stdout is not None and writer.stdout.readline()  # open for writing now
        photo.rename(target)  # complete, but still open in the writer
        said = f"still open for writing by pid {writer.pid}; patched once it is closed"
        wait_for(lambda: said in daemon.log.read_text(), 30, "the daemon's skip line")
        writer.kill()  # its close re-arms the watcher: patched, as said
        writer.wait()
        wait_for(lambda: _state(target) == FileState.PATCHED, 30, "b.jpg patched once closed")
    finally:
        writer.kill()
        writer.wait()
        stop_daemon(daemon)
