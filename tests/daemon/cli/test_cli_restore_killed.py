"""`ppd restore` SIGKILLed at a chosen point (a child process kills itself there, as a crash would stop
it): what it leaves must be recognised by the next run, and the user's files never lost or mistaken."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from testkit.kill_loops import REPO
from testkit.photos import make_image

runner = CliRunner()

# the child runs `ppd ARGS` with HOOK (Python lines) applied first; HOOK kills the process where it says
CHILD = (
    "import os, signal, sys\n"
    "{hook}\n"
    "from daemon.cli import app\n"
    "sys.argv = ['ppd', *sys.argv[1:]]\n"
    "app()\n"
)


def _killed_ppd(hook: str, *args: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-c", CHILD.format(hook=hook), *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == -signal.SIGKILL, (done.returncode, done.stdout, done.stderr)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# the first write into a file (not stdout/stderr) writes half its bytes, then SIGKILL: a copy cut midway
HALF_A_COPY = """
real_write = os.write
def write(fd, data):
    if fd > 2:
        real_write(fd, bytes(data)[: len(data) // 2])
        os.kill(os.getpid(), signal.SIGKILL)
    return real_write(fd, data)
os.write = write
"""


def test_a_force_restore_killed_while_keeping_the_users_file_aside(ppd_env: dict[str, Path],
                                                                   tmp_path: Path) -> None:  # fmt: skip
    """Before: the copy was made under its final name in DATA/displaced, so a kill mid-copy left half a
    file that looked like the user's version kept (and the next try kept the whole one as `-1`)."""
    shoot = tmp_path / "shoot"
    original = _sha(make_image(shoot / "v0.png", 0))
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    other = make_image(shoot / "v0.png", 42, size=(200, 100)).read_bytes()  # a new photo, same name
    _killed_ppd(HALF_A_COPY, "restore", str(shoot / "v0.png"), "--force")
    assert (shoot / "v0.png").read_bytes() == other  # not replaced: the copy was not made
    kept = [p for p in (ppd_env["data"] / "displaced").rglob("*") if p.is_file()]
    assert all(p.name.startswith(".ppd-tmp-") for p in kept), kept  # nothing that looks like a kept copy
    again = runner.invoke(app, ["restore", str(shoot / "v0.png"), "--force"])
    assert again.exit_code == 0 and _sha(shoot / "v0.png") == original, again.output
    (copy,) = [p for p in (ppd_env["data"] / "displaced").rglob("*") if p.is_file()]  # the leftover swept
    assert copy.read_bytes() == other and not copy.name.startswith(".")
