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


def test_watch_and_service_install_warn_about_a_synced_outbox(tmp_path: Path) -> None:
    """Only `ppd status` warned that a synced outbox uploads originals before ppd patches them; the
    daemon, which is what leaks them, said nothing (a black-box review)."""
    dropbox = tmp_path / "Dropbox"
    (dropbox / ".dropbox").mkdir(parents=True)
    outbox = dropbox / "PPD"
    outbox.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("PPD_")}
    env.update(PYTHONPATH=str(REPO), PPD_OUTBOX=str(outbox), PPD_DATA_DIR=str(tmp_path / "data"),
               PPD_CONFIG_DIR=str(tmp_path / "config"), PPD_CACHE_DIR=str(tmp_path / "cache"))  # fmt: skip
    printed = subprocess.run([sys.executable, "-m", "daemon.cli", "service", "install", "--print"], env=env,
                             capture_output=True, text=True, timeout=60)  # fmt: skip
    assert printed.returncode == 0 and "inside a Dropbox folder" in printed.stderr, printed.stderr
    proc = subprocess.Popen([sys.executable, "-m", "daemon.cli", "watch", "--no-verify"], env=env,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        first = proc.stderr.readline() if proc.stderr else ""
    finally:
        proc.terminate()
        proc.wait(60)
    assert "inside a Dropbox folder" in first, first  # said before it watches
