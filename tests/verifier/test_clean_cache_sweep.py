"""What a feature child killed mid-build leaves in a clean cache (its temporary database and SQLite's
-wal and -shm) is removed by the next verification of those originals, and never while a living
child still writes it (the clean cache is shared by verifications of the same originals)."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from poisoner.atomic import TEMP_PREFIX
from verifier.shared_sfm import clean_cache_for, sweep_killed_databases


def _build(folder: Path, token: str) -> list[Path]:
    base = folder / f"{TEMP_PREFIX}L{token}.db"
    files = [base, base.with_name(base.name + "-wal"), base.with_name(base.name + "-shm")]
    for f in files:
        f.write_bytes(b"x" * 64)
    return files


def test_a_killed_childs_database_goes_with_its_sidecars_a_living_ones_stays(tmp_path: Path) -> None:
    here = clean_cache_for(tmp_path / "cache", "key", keep=3)
    dead = _build(here, "0123456789ab")
    alive = _build(here, "ba9876543210")
    fd = os.open(alive[0], os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)  # its writer, as poisoner.atomic's temporaries hold it
    try:
        removed = sweep_killed_databases(here)
        assert sorted(removed) == sorted(p.name for p in dead)
        assert all(p.exists() for p in alive) and not any(p.exists() for p in dead)
    finally:
        os.close(fd)
    clean_cache_for(tmp_path / "cache", "key", keep=3)  # the next verification of these originals
    assert not any(p.exists() for p in alive)
    (here / "clean-original-abc.db").write_bytes(b"kept")  # a finished build is never touched
    assert sweep_killed_databases(here) == [] and (here / "clean-original-abc.db").exists()
