"""Atomic replacement: the destination is the old file or the complete new one, never a mix."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from poisoner.atomic import (
    TEMP_PREFIX,
    atomic_output,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    clear_stale_temps,
    create_temp_at,
    is_temp_name,
)


def test_replaces_and_keeps_permissions(tmp_path: Path) -> None:
    dst = tmp_path / "a.bin"
    dst.write_bytes(b"old")
    os.chmod(dst, 0o640)
    atomic_write_bytes(dst, b"new content")
    assert dst.read_bytes() == b"new content"
    assert (dst.stat().st_mode & 0o777) == 0o640
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(TEMP_PREFIX)]


def test_an_error_while_writing_leaves_the_original_and_no_temp(tmp_path: Path) -> None:
    dst = tmp_path / "a.bin"
    dst.write_bytes(b"original")
    with pytest.raises(RuntimeError), atomic_output(dst) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("encoder died")
    assert dst.read_bytes() == b"original"
    assert list(tmp_path.iterdir()) == [dst]


_WRITER = """
import sys, time
from pathlib import Path
from poisoner.atomic import atomic_output
dst = Path(sys.argv[1])
with atomic_output(dst) as tmp:
    with open(tmp, "wb") as fh:
        for _ in range(400):
            fh.write(b"N" * 4096)
            fh.flush()
            time.sleep(0.001)
"""


def test_sigkill_at_random_instants_never_leaves_a_partial_file(tmp_path: Path) -> None:
    dst = tmp_path / "a.bin"
    original = b"O" * 10_000
    complete = b"N" * 4096 * 400
    outcomes = set()
    for delay in (0.0, 0.05, 0.1, 0.2, 0.3, 0.45, 0.7, 1.2):
        dst.write_bytes(original)
        proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(dst)], cwd=Path(__file__).parents[2])
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        data = dst.read_bytes()
        assert data in (original, complete), f"partial file after kill at {delay}s ({len(data)} bytes)"
        outcomes.add(data == complete)
    assert False in outcomes  # at least one kill landed mid-write, so the test exercised the crash


def test_write_text_replaces_with_the_encoded_text_and_keeps_permissions(tmp_path: Path) -> None:
    dst = tmp_path / "page.html"
    dst.write_text("old page")
    os.chmod(dst, 0o600)
    atomic_write_text(dst, "<p>caf\u00e9</p>")
    assert dst.read_bytes() == "<p>caf\u00e9</p>".encode()
    assert (dst.stat().st_mode & 0o777) == 0o600
    atomic_write_text(dst, "caf\u00e9", encoding="latin-1")
    assert dst.read_bytes() == b"caf\xe9"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["page.html"]


def test_write_json_round_trips_with_indent_and_default(tmp_path: Path) -> None:
    dst = tmp_path / "result.json"
    atomic_write_json(dst, {"b": [1, 2], "a": None}, indent=1)
    assert json.loads(dst.read_text()) == {"b": [1, 2], "a": None}
    assert dst.read_text() == json.dumps({"b": [1, 2], "a": None}, indent=1)
    atomic_write_json(dst, {"path": tmp_path}, default=str)
    assert json.loads(dst.read_text()) == {"path": str(tmp_path)}


def test_write_json_that_cannot_encode_leaves_the_old_file_and_no_temp(tmp_path: Path) -> None:
    dst = tmp_path / "result.json"
    dst.write_text('{"old": true}')
    with pytest.raises(TypeError):
        atomic_write_json(dst, {"x": object()})
    assert dst.read_text() == '{"old": true}'
    assert list(tmp_path.iterdir()) == [dst]


def test_an_explicit_mode_wins_over_the_existing_file_and_the_umask(tmp_path: Path) -> None:
    dst = tmp_path / "spec.json"
    dst.write_text("{}")
    os.chmod(dst, 0o644)
    atomic_write_json(dst, {"spec": 1}, mode=0o600)
    assert (dst.stat().st_mode & 0o777) == 0o600
    fresh = tmp_path / "new.txt"
    atomic_write_text(fresh, "x", mode=0o640)
    assert (fresh.stat().st_mode & 0o777) == 0o640
    with atomic_output(tmp_path / "copy.bin", mode_like=fresh, mode=0o604) as tmp:
        tmp.write_bytes(b"y")
    assert ((tmp_path / "copy.bin").stat().st_mode & 0o777) == 0o604


def test_a_sweep_removes_only_names_of_ppds_own_form(tmp_path: Path) -> None:
    """A black-box review (F14): every unlocked `.ppd-tmp-*` older than 10 s went, whoever made it (a
    user's `.ppd-tmp-todo.txt`); now only create_temp_at's form: the prefix, a 12-hex token, a suffix."""
    dir_fd = os.open(tmp_path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        made = []
        for suffix in ("", ".jpg", ".seal.key", ".db"):
            name, fd = create_temp_at(dir_fd, suffix)
            os.close(fd)  # its writer gone
            made.append(name)
        theirs = [f"{TEMP_PREFIX}{rest}" for rest in (
            "todo.txt", "my-notes.jpg", "0123456789ab.jpg.bak", "0123456789AB.jpg", "L0123456789abc.jpg",
        )]  # fmt: skip
        for name in [*made, *theirs]:
            (tmp_path / name).write_bytes(b"x")
            os.utime(tmp_path / name, (time.time() - 3600, time.time() - 3600))
        assert all(is_temp_name(n) for n in made) and not any(is_temp_name(n) for n in theirs)
        assert sorted(clear_stale_temps(dir_fd)) == sorted(made)
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(theirs)  # before: all gone
    finally:
        os.close(dir_fd)
