"""Short CI versions of bench/bench_kill_loops.py: `ppd poison` (a real CLI process) SIGKILLed at
random instants and run again, and a deleted store followed by a second run and a restore."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from daemon.watch.watcher import scan_outbox
from poisoner.atomic import clear_stale_temps
from testkit.kill_loops import REPO, poison_loop, store_deleted_round

pytestmark = pytest.mark.integration


def test_sigkilled_ppd_poison_then_run_again_loses_nothing_and_leaves_nothing(tmp_path: Path) -> None:
    result = poison_loop(tmp_path, kills=4, seed=3, per_kill=8, video_every=0, pid_only_every=2)
    assert result["kills"] == 4
    assert result["findings"] == []
    for figure in ("invariants", "not_patched", "double", "not_restorable", "corrupt", "leftovers"):
        assert result[figure] == 0, (figure, result)
    assert result.get("pid-only kills after which its processes ran on", 0) == 0, result


def test_store_deleted_no_double_poisoning_and_every_original_restored(tmp_path: Path) -> None:
    result = store_deleted_round(tmp_path, files=6, seed=1)
    assert result["poisoned twice (bytes changed by the second run)"] == 0
    assert result["originals not in the vault"] == 0
    assert result["restore exit non-zero"] == 0
    assert result["not restored to the original bytes"] == 0
    assert result["leftovers"] == 0


WRITER = (
    "import os, sys, time; from poisoner.atomic import create_temp_at\n"
    "d = os.open(sys.argv[1], os.O_RDONLY | os.O_DIRECTORY)\n"
    "name, fd = create_temp_at(d, '.png'); os.write(fd, b'half a png')\n"
    "print(name, flush=True); time.sleep(60)"
)


def _writer(folder: Path) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(folder)], cwd=REPO, text=True,
                            env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE)  # fmt: skip
    assert proc.stdout is not None
    return proc, proc.stdout.readline().strip()


def test_a_killed_writers_young_temporary_goes_at_the_next_run_a_live_ones_stays(tmp_path: Path) -> None:
    """Before: a temporary under 10 s old (60 s for the daemon's start-up scan) stayed after the
    next run, because an unlocked young one might be a live writer's between create and lock."""
    folder = tmp_path / "ds"
    folder.mkdir()
    dead, dead_name = _writer(folder)
    live, live_name = _writer(folder)
    try:
        dead.send_signal(signal.SIGKILL)
        dead.wait()
        assert (folder / dead_name).exists() and (folder / live_name).exists()
        result = scan_outbox(tmp_path, frozenset({".png"}), tmp_grace_s=60.0)
        assert result.stale_temps_removed == [folder / dead_name]
        assert not (folder / dead_name).exists()
        assert (folder / live_name).read_bytes() == b"half a png"  # a living writer's: kept
        dir_fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
        try:
            assert clear_stale_temps(dir_fd) == []
        finally:
            os.close(dir_fd)
    finally:
        live.kill()
        live.wait()
    dir_fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        assert clear_stale_temps(dir_fd) == [live_name]  # its writer died: gone at once
    finally:
        os.close(dir_fd)


def test_a_writer_that_closed_within_the_scan_cache_does_not_skip_the_file(ppd_env: dict[str, Path]) -> None:
    """Before: a /proc scan taken while the file was open for writing (here by this process, as
    when ppd's own temporary is renamed in place) was reused for 0.5 s, and the file was skipped
    as 'still open for writing by pid <ppd itself>' after the writer had closed it."""
    import daemon.platform.linux
    from daemon.protect.one_file import AppContext, protect_file
    from testkit.photos import write_image

    photo = write_image(ppd_env["outbox"] / "ds" / "a.png", seed=3)
    fd = os.open(photo, os.O_WRONLY)
    assert daemon.platform.linux.writers_of(os.stat(photo), fresh=True) == [os.getpid()]  # now cached
    os.close(fd)
    ctx = AppContext.open()
    try:
        outcome = protect_file(photo, ctx)
    finally:
        ctx.close()
    assert outcome.state == "patched", outcome.reason
