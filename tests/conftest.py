"""Shared test fixtures. Keep this small: each area's fixtures live in its own test module."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

# Idle OpenMP threads sleep instead of spinning (see verifier/splat/__init__.py): libgomp reads this
# once when torch loads, so it must be set before any test module imports torch.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# PIL before pycolmap in any process that has both (pillow 13 + pycolmap 4.2.1 crash otherwise).
import PIL.Image  # noqa: F401
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"
# ppd finds the shared datasets only where it is told (verifier/shared_data.py): the checkout's.
os.environ.setdefault("PPD_SHARED_DATA", str(SHARED / "datasets"))

# The integration tests CI runs (`make test`, the default selection), one for each real part: pycolmap SfM
# on a synthetic scene; an unpoisoned copy called not protected, its two sides run at once; the paper's
# verdict (the patch breaks default COLMAP, hardened COLMAP resists); `ppd demo`, the real watchdog daemon
# end to end up to a printed verdict; a file the daemon cannot patch leaving the outbox (real daemon
# processes); a deleted store, no double poisoning, every original restored. The video path has no
# integration test: tests/test_video*.py run by default. The other integration tests run with `make
# test-all` or `pytest -m integration`. A node id without [parameters] takes every parameter;
# tests/test_selection.py checks that each names an integration test.
REPRESENTATIVE = (
    "tests/verifier/test_sfm.py::test_clean_sfm_recovers_synthetic_cameras",
    "tests/verifier/test_verification.py::test_patch_breaks_default_colmap_and_hardened_colmap_resists",
    "tests/verifier/test_verification.py::test_unpoisoned_copy_is_not_protected",
    "tests/daemon/cli/test_demo.py::test_demo_verifies_and_prints_the_verdict",
    "tests/daemon/protect/test_quarantine.py::test_a_file_ppd_cannot_patch_leaves_the_outbox",
    "tests/reliability/test_reliability_kill_loops.py::test_store_deleted_no_double_poisoning_and_every_original_restored",
)

# AF_UNIX socket paths are limited to 107 bytes by the kernel, and tests bind sockets (sd_notify
# receivers, systemd-analyze's runtime dir) under tmp_path. Under a long TMPDIR the tests' own
# folders go to a short private one; what ppd itself does with TMPDIR still sees the long path
# (tests/daemon/cli/test_cli_terminal.py runs `ppd` under a 150-character TMPDIR on purpose).
LONG_TMPDIR = 40
# The folders this run made for itself, removed when it ends (pytest's typed per-run store).
SHORT_BASETEMP = pytest.StashKey[str]()
TEST_HOME = pytest.StashKey[str]()


def pytest_configure(config: pytest.Config) -> None:
    if config.option.basetemp is None and len(tempfile.gettempdir()) > LONG_TMPDIR and os.path.isdir("/tmp"):
        config.option.basetemp = tempfile.mkdtemp(prefix="ppd-pytest-", dir="/tmp")
        config.stash[SHORT_BASETEMP] = config.option.basetemp
    # No test reads or writes the real user's ppd folders: a test that forgets ppd_env (or undoes
    # it) lands here, not in ~/.local/share/ppd, whose state would then decide the result.
    from verifier.lpips_weights import weights_dir

    installed_lpips = weights_dir()  # the set-up's converted LPIPS weights, read before the cache moves
    home = tempfile.mkdtemp(prefix="ppd-test-home-")
    config.stash[TEST_HOME] = home
    for var, name in (("PPD_DATA_DIR", "data"), ("PPD_CONFIG_DIR", "config"), ("PPD_OUTBOX", "outbox"),
                      ("PPD_CACHE_DIR", "cache")):  # fmt: skip
        os.environ.setdefault(var, os.path.join(home, name))
    # the isolated cache still sees the weights `make test` installed (read-only use: a link)
    test_lpips = weights_dir()
    if installed_lpips.is_dir() and test_lpips != installed_lpips and not test_lpips.exists():
        test_lpips.parent.mkdir(parents=True, exist_ok=True)
        test_lpips.symlink_to(installed_lpips, target_is_directory=True)


def pytest_unconfigure(config: pytest.Config) -> None:
    for folder in (config.stash.get(SHORT_BASETEMP, None), config.stash.get(TEST_HOME, None)):
        if folder:
            shutil.rmtree(folder, ignore_errors=True)


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


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects: the marker must be there to select by
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    wanted = set(REPRESENTATIVE)
    for item in items:
        if item.nodeid.split("[", 1)[0] in wanted:
            item.add_marker(pytest.mark.representative)
