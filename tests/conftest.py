"""Shared test fixtures. Keep this small: each area's fixtures live in its own test module."""

from __future__ import annotations

import os
from pathlib import Path

# Idle OpenMP threads sleep instead of spinning (see verifier/splat/__init__.py): libgomp reads this
# once when torch loads, so it must be set before any test module imports torch.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# PIL before pycolmap in any process that has both (pillow 13 + pycolmap 4.2.1 crash otherwise).
import PIL.Image  # noqa: F401
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not (SHARED / "datasets").is_dir():
        pytest.skip(f"shared datasets not found at {SHARED}")
    return SHARED


@pytest.fixture
def ppd_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Path]:
    """Private data/config/outbox folders for one test, through ppd's environment overrides."""
    dirs = {name: tmp_path / name for name in ("data", "config", "outbox")}
    for p in dirs.values():
        p.mkdir()
    monkeypatch.setenv("PPD_DATA_DIR", str(dirs["data"]))
    monkeypatch.setenv("PPD_CONFIG_DIR", str(dirs["config"]))
    monkeypatch.setenv("PPD_OUTBOX", str(dirs["outbox"]))
    return dirs
