"""Issue 29: a file is one file until its writer is done. Real writers reopen the file and append
in bursts, with pauses longer than the debounce, against a real `ppd watch`: each file ends up
patched once, whole; its original in the vault is the whole file; nothing is quarantined and no
fragment enters the vault."""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path

import pytest

from daemon.states import FileState
from daemon.store import Store
from testkit.daemon_proc import stop_daemon
from testkit.photos import burst_writer
from testkit.reliability import app_paths, start_daemon, wait_for, write_image

pytestmark = pytest.mark.integration


def vault_blobs(vault: Path) -> set[str]:
    return {p.name for p in vault.glob("??/*") if p.is_file()}


def test_burst_appending_writers_are_one_file_each(tmp_path: Path) -> None:
    root = tmp_path / "ppd"
    (root / "config").mkdir(parents=True)
    (root / "config" / "config.toml").write_text(
        "[daemon]\nmax_debounce_seconds = 4.0\nincomplete_wait_seconds = 30.0\n"
    )
    (root / "outbox" / "shoot").mkdir(parents=True)
    sources = {
        name: write_image(tmp_path / "src" / name, seed=i, size=640).read_bytes()
        for i, name in enumerate(("a.jpg", "b.png", "c.jpg"))
    }
    paths = app_paths(root)
    daemon = start_daemon(root, "--no-verify", "--debounce", "0.3", "-j", "2")
    try:
        writers = [
            threading.Thread(target=burst_writer, args=(root / "outbox" / "shoot" / name, data, 4, gap))
            for (name, data), gap in zip(sources.items(), (1.0, 1.5, 2.5), strict=True)
        ]
        for w in writers:
            w.start()
        for w in writers:
            w.join()
        targets = [root / "outbox" / "shoot" / name for name in sources]

        def all_patched() -> bool:
            store = Store(paths.db_path)
            try:
                return all((store.file(p) or {}).get("state") == FileState.PATCHED for p in targets)
            finally:
                store.close()

        wait_for(all_patched, 120, "every burst-written file patched")
    finally:
        stop_daemon(daemon)
    store = Store(paths.db_path)
    try:
        for name, data in sources.items():
            row = store.file(root / "outbox" / "shoot" / name)
            assert row["original_sha256"] == hashlib.sha256(data).hexdigest(), name  # the whole file
    finally:
        store.close()
    # one file per writer, nothing split off: no quarantine, no fragment among the originals
    assert sorted(p.name for p in (root / "outbox" / "shoot").iterdir()) == sorted(sources)
    quarantine = root / "ppd-quarantine"
    assert not quarantine.exists() or not [p for p in quarantine.rglob("*") if p.is_file()]
    assert vault_blobs(paths.vault_dir) == {hashlib.sha256(d).hexdigest() for d in sources.values()}
