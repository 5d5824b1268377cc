"""run_child(): real child processes end as exited, crashed (signal), timeout or cancelled, and a
kill reaches the child's whole process group (a grandchild it started dies with it)."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

from verifier.supervise import run_child

# A child that starts a grandchild (sleeping long), writes the grandchild's pid, then sleeps itself.
_FAMILY = (
    "import subprocess, sys, time\n"
    "g = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
    "open(sys.argv[1], 'w').write(str(g.pid))\n"
    "time.sleep(60)\n"
)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie still answers kill(0): it has ended, its parent just has not reaped it
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def _wait_for_file(path: Path, limit_s: float = 20.0) -> None:
    deadline = time.monotonic() + limit_s
    while not (path.is_file() and path.read_text()) and time.monotonic() < deadline:
        time.sleep(0.05)


def _gone(pid: int, limit_s: float = 5.0) -> bool:
    deadline = time.monotonic() + limit_s
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not _alive(pid)


def test_exit_code_stdin_and_log(tmp_path: Path) -> None:
    code = "import sys; data = sys.stdin.read(); print('got', data); sys.exit(3)"
    ended = run_child([sys.executable, "-c", code], log_path=tmp_path / "c.log", stdin_data=b"job")
    assert (ended.kind, ended.returncode) == ("exited", 3)
    assert "got job" in (tmp_path / "c.log").read_text()


def test_a_signal_is_a_crash_with_its_name(tmp_path: Path) -> None:
    code = "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)"
    ended = run_child([sys.executable, "-c", code], log_path=tmp_path / "c.log")
    assert ended.kind == "crashed" and ended.signal_name == "SIGSEGV" and ended.returncode == -11


def test_timeout_kills_the_whole_group(tmp_path: Path) -> None:
    pid_file = tmp_path / "grandchild.pid"
    started = time.monotonic()
    family = [sys.executable, "-c", _FAMILY, str(pid_file)]
    ended = run_child(family, log_path=tmp_path / "c.log", timeout_s=3.0)
    assert ended.kind == "timeout" and time.monotonic() - started < 30
    assert pid_file.is_file() and _gone(int(pid_file.read_text()))


def test_cancel_kills_the_whole_group(tmp_path: Path) -> None:
    pid_file = tmp_path / "grandchild.pid"
    cancel = threading.Event()
    setter = threading.Thread(target=lambda: (_wait_for_file(pid_file), cancel.set()))
    setter.start()
    family = [sys.executable, "-c", _FAMILY, str(pid_file)]
    ended = run_child(family, log_path=tmp_path / "c.log", cancel=cancel)
    setter.join()
    assert ended.kind == "cancelled"
    assert _gone(int(pid_file.read_text()))


# A parent that runs a sleeping child through run_child; the child sets itself up as ppd's children do
# (adopt_child_setup, first thing), then writes its pid and its niceness.
_CHILD = (
    "import os, sys, time\n"
    "from verifier.supervise import adopt_child_setup\n"
    "adopt_child_setup()\n"
    "open(sys.argv[1], 'w').write(f'{os.getpid()} {os.nice(0)}')\n"
    "time.sleep(60)\n"
)
_PARENT = (
    "import sys\n"
    "from pathlib import Path\n"
    "from verifier.supervise import run_child\n"
    f"code = {_CHILD!r}\n"
    "run_child([sys.executable, '-c', code, sys.argv[1]], log_path=Path(sys.argv[2]), nice=5)\n"
)


def test_a_child_dies_with_its_parent(tmp_path: Path) -> None:
    """A parent killed outright (SIGKILL: no handler, no kill_group) takes its SfM child with it:
    the child lives in its own session, so nothing else would stop it."""
    import signal
    import subprocess

    from verifier.childenv import child_env

    pid_file = tmp_path / "child.pid"
    parent = subprocess.Popen(
        [sys.executable, "-c", _PARENT, str(pid_file), str(tmp_path / "c.log")], env=child_env()
    )
    try:
        _wait_for_file(pid_file)
        child, niceness = map(int, pid_file.read_text().split())
        assert _alive(child) and niceness == os.nice(0) + 5  # the parent's nice=5, applied by the child
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
        assert _gone(child), "the child outlived its killed parent"
    finally:
        if parent.poll() is None:
            parent.kill()
        left = pid_file.read_text().split() if pid_file.is_file() else []
        if left and _alive(int(left[0])):
            os.kill(int(left[0]), signal.SIGKILL)


def test_every_child_ppd_starts_sets_itself_up_and_no_fork_runs_python() -> None:
    """run_child's children and the isolated poisoner lower their priority and die with their parent
    themselves (adopt_child_setup): a preexec_fn ran CPython's after-fork cleanup in the forked child,
    which freed another thread's PyAV scaler there and hung on that thread's lock (a CI run hung 15
    minutes in `ppd verify`). No Popen of ppd takes a preexec_fn."""
    import ast
    import importlib.util

    for module in ("verifier.child", "verifier.splat.stage", "verifier.auto_search", "daemon.protect.child"):
        spec = importlib.util.find_spec(module)
        assert spec is not None and spec.origin is not None
        tree = ast.parse(Path(spec.origin).read_text())
        main = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "main")
        calls = [n.func.id for n in ast.walk(main)
                 if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]  # fmt: skip
        assert "adopt_child_setup" in calls, module
    root = Path(__file__).resolve().parents[2]
    for package in ("daemon", "poisoner", "verifier"):
        for source in (root / package).rglob("*.py"):
            tree = ast.parse(source.read_text())
            keywords = [k.arg for n in ast.walk(tree) if isinstance(n, ast.Call) for k in n.keywords]
            assert "preexec_fn" not in keywords, source
