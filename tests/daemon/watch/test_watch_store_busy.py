"""`ppd watch` started while `ppd store rebuild` (or `ppd key new|import`) holds the store waits for
it, then watches (a black-box review: it exited 3, which the systemd unit does not restart, so a login
or a restart during a rebuild left the outbox unwatched, its new photos published unprotected, until
the user noticed). A real daemon process with a systemd-style notify socket, a real holder of the
store lock in another process, real photos."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from daemon.states import FileState
from daemon.store import Store
from testkit.daemon_proc import wait_for
from testkit.reliability import DAEMON_ARGS, REPO, app_paths, make_media, sha256, subprocess_env

HOLD_STORE = (
    "import sys; from pathlib import Path; from daemon.locks import store_alone\n"
    "with store_alone(Path(sys.argv[1])):\n"
    "    print('held', flush=True); sys.stdin.read()\n"
)


def _messages(sock: socket.socket, until: bytes, timeout: float) -> list[bytes]:
    """The notify datagrams received until one holds `until` (or the time is up)."""
    got: list[bytes] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sock.settimeout(max(0.05, deadline - time.monotonic()))
        try:
            got.append(sock.recv(4096))
        except TimeoutError:
            break
        if until in got[-1]:
            break
    return got


def test_a_daemon_started_during_a_rebuild_waits_for_it_then_protects_the_outbox(tmp_path: Path) -> None:
    paths = app_paths(tmp_path)
    shoot = paths.outbox / "shoot"
    photos = [make_media(shoot / f"v{i}.png", seed=i) for i in range(3)]
    before = {p: sha256(p) for p in photos}
    env = subprocess_env(tmp_path)
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD_STORE, str(paths.data_dir)], cwd=REPO, env=env,
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"

    sock_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    log = tmp_path / "watch.log"
    with open(log, "wb") as fh:
        daemon = subprocess.Popen(
            [sys.executable, "-m", "daemon.cli", "watch", *DAEMON_ARGS], cwd=REPO,
            env={**env, "NOTIFY_SOCKET": str(sock_path)}, stdout=fh, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:
        said = b"\n".join(_messages(sock, b"EXTEND_TIMEOUT_USEC=", 60))
        time.sleep(3.0)  # a refusal came within STORE_WAIT_S (2 s): exit 3, the unit left it down
        assert daemon.poll() is None, log.read_text()  # before: exit 3
        status = f"STATUS=waiting to start: ppd store rebuild is rebuilding the store (pid {holder.pid})"
        assert status.encode() in said, said
        assert b"EXTEND_TIMEOUT_USEC=" in said and b"READY=1" not in said, said  # the start clock pushed on
        assert all(sha256(p) == before[p] for p in photos)  # nothing touched without the store
        text = log.read_text()
        assert text.count("waiting to start") == 1, text  # said once, not every poll

        holder.communicate("")  # the rebuild ends
        assert holder.returncode == 0
        assert any(b"READY=1" in m for m in _messages(sock, b"READY=1", 60)), log.read_text()

        def protected() -> bool:
            store = Store(paths.db_path)
            try:
                rows = [store.file(p) for p in photos]
            finally:
                store.close()
            return all(r is not None and r["state"] == FileState.PATCHED for r in rows)

        wait_for(protected, 120, "the outbox's photos to be protected")
        assert all(sha256(p) != before[p] for p in photos)
    finally:
        if holder.poll() is None:
            holder.kill()
        daemon.terminate()
        code = daemon.wait(60)
        sock.close()
    assert code == 0, log.read_text()
    assert not os.path.exists(paths.data_dir / "locks" / "store.lock")
