"""Files the daemon cannot patch leave the outbox; a file that keeps killing ppd is quarantined, not
retried in a loop; a writer that keeps a file open stalls nothing and gets nothing partial patched
(real daemon processes, real files)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from daemon.paths import AppPaths
from daemon.protect.one_file import AppContext, protect_file, restore_file
from daemon.states import FileState
from daemon.store import Store
from testkit.reliability import (
    DAEMON_ARGS,
    REPO,
    app_paths,
    kill_daemon,
    sha256,
    start_daemon,
    wait_for,
    write_image,
)

pytestmark = pytest.mark.integration


def _row(paths: AppPaths, path: Path) -> dict | None:
    store = Store(paths.db_path)
    try:
        return store.file(path)
    finally:
        store.close()


def test_a_file_ppd_cannot_patch_leaves_the_outbox(tmp_path: Path) -> None:
    paths = app_paths(tmp_path)
    (paths.outbox / "ds").mkdir(parents=True)
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)
    try:
        bad = paths.outbox / "ds" / "sub" / "bad.jpg"
        stage = tmp_path / "bad.jpg"
        stage.write_bytes(b"this is not a photo at all")
        bad.parent.mkdir()
        os.rename(stage, bad)
        moved = tmp_path / "ppd-quarantine" / "ds" / "sub" / "bad.jpg"
        wait_for(lambda: moved.is_file() and not bad.exists(), 30, "the bad file quarantined")
        assert moved.read_bytes() == b"this is not a photo at all"
        wait_for(lambda: (_row(paths, bad) or {}).get("state") == FileState.QUARANTINED, 10, "row")
        assert "\n" not in _row(paths, bad)["error"]
    finally:
        assert kill_daemon(daemon, signal.SIGTERM) == 0


def test_after_a_death_the_file_is_retried_in_a_child_process(
    tmp_path: Path, ppd_env: dict[str, Path]
) -> None:
    """A process killed while patching a file (as the OOM killer would) leaves its attempt marker;
    the next attempt runs the poisoner isolated, so a file that kills its process cannot take the
    daemon down again (no crash loop), and a file that was not the cause is simply patched."""
    photo = write_image(ppd_env["outbox"] / "ds" / "boom.png", seed=3)
    die = (
        "import os; from pathlib import Path; from daemon.protect.quarantine import attempt\n"
        f"with attempt(Path({str(ppd_env['data'])!r}), Path({str(photo)!r}), 'ds'):\n"
        "    os.kill(os.getpid(), 9)"
    )
    ppd_env["data"].mkdir(parents=True, exist_ok=True)
    done = subprocess.run([sys.executable, "-c", die], cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == -9
    from daemon.protect.quarantine import crashed_attempts

    assert [c.path for c in crashed_attempts(ppd_env["data"])] == [photo]
    ctx = AppContext.open()
    try:
        outcome = protect_file(photo, ctx)
        assert outcome.state == "patched", outcome
        assert crashed_attempts(ppd_env["data"]) == []
    finally:
        ctx.close()


def test_an_isolated_poisoner_that_dies_is_a_one_line_failure(tmp_path: Path) -> None:
    import threading

    from daemon.protect.poisoning import PoisonerDied, poison_isolated
    from poisoner.ladder import default_spec
    from poisoner.provenance import Marker

    src = write_image(tmp_path / "big.png", seed=1, size=2048)
    before = set(os.listdir("/proc"))
    errors: list[BaseException] = []

    def run() -> None:
        try:
            marker = Marker.placeholder(bytes(32), "x", "0" * 64)
            poison_isolated("image", src, tmp_path / "out.png", default_spec(), marker, False)
        except BaseException as exc:  # the test inspects it
            errors.append(exc)

    worker = threading.Thread(target=run)
    worker.start()
    child = None
    deadline = time.monotonic() + 30
    while child is None and time.monotonic() < deadline:
        for pid in set(os.listdir("/proc")) - before:
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue
            if b"daemon.protect.child" in cmd and pid.isdigit():
                child = int(pid)
        time.sleep(0.01)
    assert child is not None
    os.kill(child, signal.SIGKILL)  # what the OOM killer does
    worker.join(60)
    assert len(errors) == 1 and isinstance(errors[0], PoisonerDied)
    assert "signal 9" in str(errors[0]) and "\n" not in str(errors[0])


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_stalled_writer_nothing_partial_is_patched(ppd_env: dict[str, Path], suffix: str) -> None:
    """Before: the partial file was patched and the vault kept a hard link that the writer's later
    bytes corrupted. Now: skipped while open for writing, patched once complete, restorable."""
    src = write_image(ppd_env["outbox"].parent / f"whole{suffix}", seed=4, size=256)
    data = src.read_bytes()
    target = ppd_env["outbox"] / "ds" / f"slow{suffix}"
    target.parent.mkdir(parents=True)
    writer = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time\n"
         f"f = open({str(target)!r}, 'wb'); whole = open({str(src)!r}, 'rb').read()\n"
         f"f.write(whole[: {len(data) // 2}]); f.flush()\n"
         "print('stalled', flush=True); sys.stdin.readline()\n"
         f"f.write(whole[{len(data) // 2}:]); f.close()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    ctx = AppContext.open()
    try:
        assert writer.stdout is not None and writer.stdout.readline().strip() == "stalled"
        partial = sha256(target)
        outcome = protect_file(target, ctx)
        assert outcome.state == "skipped" and f"open for writing by pid {writer.pid}" in outcome.reason
        assert not ctx.vault.has(partial) and ctx.store.file(target) is None
        writer.communicate("go\n", timeout=30)
        time.sleep(0.6)  # the /proc scan is reused for 0.5 s
        assert sha256(target) == sha256(src)
        done = protect_file(target, ctx)
        assert done.state == "patched" and done.original_sha256 == sha256(src)
        assert not ctx.vault.has(partial)
        assert restore_file(ctx, target).state == "restored" and target.read_bytes() == data
    finally:
        if writer.poll() is None:
            writer.kill()
        ctx.close()


def test_truncated_file_without_a_writer_is_refused_before_the_vault(ppd_env: dict[str, Path]) -> None:
    src = write_image(ppd_env["outbox"].parent / "whole.png", seed=5, size=256)
    cut = ppd_env["outbox"] / "ds" / "cut.png"
    cut.parent.mkdir(parents=True)
    cut.write_bytes(src.read_bytes()[:-200])
    ctx = AppContext.open()
    try:
        outcome = protect_file(cut, ctx)
        assert outcome.state == "failed" and "incomplete" in outcome.reason
        assert not ctx.vault.has(sha256(cut))
    finally:
        ctx.close()


def test_an_isolated_poisoner_returns_the_report_poison_to_does(tmp_path: Path) -> None:
    """A file patched in the isolated child (after a poisoner crash) is said like any other: where
    its mark went and why (issue 25's per-file note), what was kept; before, the report was lost."""
    from daemon.protect.job import place_note, report_detail
    from daemon.protect.poisoning import poison_isolated, poison_to
    from poisoner.ladder import default_spec
    from poisoner.provenance import Marker

    src = write_image(tmp_path / "photo.png", seed=4, size=640)
    marker = Marker.placeholder(bytes(32), "x", "0" * 64)
    here = poison_to("image", src, tmp_path / "here.png", default_spec(), marker=marker, keep_location=False)
    child = poison_isolated("image", src, tmp_path / "child.png", default_spec(), marker, False)
    assert child is not None and child.place is not None
    assert (tmp_path / "child.png").read_bytes() == (tmp_path / "here.png").read_bytes()
    assert report_detail(child) == report_detail(here)
    assert place_note(child) == place_note(here)
    assert not (tmp_path / "child.png.report").exists()  # the hand-over file is gone
