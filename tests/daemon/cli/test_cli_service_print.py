"""`ppd service install --print` writes nothing (its help says so): a black-box review found it made
the outbox, the data folder, the vault, the store and the cache of a fresh account."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def test_service_install_print_makes_no_folder(tmp_path: Path) -> None:
    home = tmp_path / "home"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PPD_", "XDG_"))}
    env.update(HOME=str(home), PYTHONPATH=str(REPO))
    proc = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "service", "install", "--print"],
        env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "[Service]" in proc.stdout and f"PPD_OUTBOX={home}/PPD Outbox" in proc.stdout.replace('"', "")
    assert list(home.iterdir()) == []  # nothing made
