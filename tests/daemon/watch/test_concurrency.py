"""One owner per outbox and per file, with real processes: two `ppd watch` and a `ppd poison` on
one outbox (issue 20, row 2), and the per-file lock across processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

from daemon.locks import LockHeld, file_lock, outbox_lock
from daemon.states import FileState
from daemon.store import Store
from testkit.reliability import (
    DAEMON_ARGS,
    REPO,
    app_paths,
    check_invariants,
    kill_daemon,
    sha256,
    start_daemon,
    subprocess_env,
    wait_for,
    write_image,
)

pytestmark = pytest.mark.integration


def _ppd(root: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", *args], env=subprocess_env(root), cwd=REPO,
        capture_output=True, text=True, timeout=timeout,
    )  # fmt: skip


def test_outbox_lock_names_the_holder_and_file_lock_waits_then_says_who(tmp_path: Path) -> None:
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time; from pathlib import Path; from daemon.locks import file_lock, outbox_lock\n"
         f"d = Path({str(tmp_path)!r})\n"
         "with outbox_lock(d, Path('/o')), file_lock(d, Path('/o/a.jpg')):\n"
         "    print('held', flush=True); time.sleep(30)"],
        cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(
            LockHeld, match=rf"another ppd watch \(pid {holder.pid}\) is already watching /o$"
        ), outbox_lock(tmp_path, Path("/o")):
            pass
        started = time.monotonic()
        with pytest.raises(
            LockHeld, match=rf"a\.jpg is being worked on by another ppd process \(pid {holder.pid}\)"
        ), file_lock(tmp_path, Path("/o/a.jpg"), wait_s=0.5):
            pass
        assert time.monotonic() - started >= 0.5
        with file_lock(tmp_path, Path("/o/b.jpg"), wait_s=0):  # another file: free
            pass
    finally:
        holder.kill()
        holder.wait()
    with outbox_lock(tmp_path, Path("/o")), file_lock(tmp_path, Path("/o/a.jpg"), wait_s=5):
        pass  # the kernel released both when the holder died


def test_two_daemons_and_a_cli_on_one_outbox(tmp_path: Path) -> None:
    """Before: up to 38 of 40 files patched on disk but recorded failed, some poisoned twice."""
    paths = app_paths(tmp_path)
    stage = tmp_path / "stage"
    sources = [write_image(stage / f"{i:02d}.jpg", seed=i, size=384) for i in range(16)]
    originals = {paths.outbox / "ds" / s.name: sha256(s) for s in sources}
    (paths.outbox / "ds").mkdir(parents=True)
    first = start_daemon(tmp_path, *DAEMON_ARGS)
    try:
        second = _ppd(tmp_path, "watch", *DAEMON_ARGS, timeout=120)
        assert second.returncode != 0
        said = " ".join((second.stderr + second.stdout).split())  # rich wraps long lines
        assert f"another ppd watch (pid {first.pid}) is already watching" in said, said[-500:]
        for src, dst in zip(sources, originals, strict=True):
            os.rename(src, dst)
        cli = _ppd(tmp_path, "poison", str(paths.outbox / "ds"))
        assert cli.returncode == 0, cli.stdout + cli.stderr
        store = Store(paths.db_path)

        def settled() -> bool:
            rows = {r["path"]: r for r in store.files("ds")}
            return all(rows.get(str(p), {}).get("state") == FileState.PATCHED for p in originals)

        wait_for(settled, 120, "every file patched")
        time.sleep(1.0)  # any late second run would show now
        rows = {r["path"]: r for r in store.files("ds")}
        patches = Counter(e["path"] for e in store.events("ds") if e["kind"] == "patched")
        store.close()
    finally:
        code = kill_daemon(first, signal.SIGTERM)
    assert code == 0
    stranded = [p for p in originals if rows[str(p)]["state"] != FileState.PATCHED]
    assert stranded == []
    for p, original in originals.items():
        assert rows[str(p)]["original_sha256"] == original, f"{p.name} poisoned twice"
        assert sha256(p) == rows[str(p)]["poisoned_sha256"]
        assert patches[str(p)] == 1, f"{p.name} patched {patches[str(p)]} times"
    assert check_invariants(paths, originals) == []
