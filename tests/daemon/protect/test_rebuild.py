"""`ppd store rebuild` on real files: a store deleted, damaged or lost is rebuilt from the vault
and the provenance markers of really patched files; every original is restorable afterwards."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import pytest

from daemon.config import Config, DatasetOverride
from daemon.paths import AppPaths
from daemon.protect.rebuild import RebuildRefused, rebuild_store
from daemon.states import FileState
from daemon.store import Store, StoreError
from daemon.store.sealkey import load_key
from daemon.store.vault import Vault
from poisoner.atomic import atomic_output
from poisoner.provenance import read_seal
from poisoner.spec import PatchSpec
from testkit.reliability import sealed_patch, write_image

COMPARED = ("path", "dataset", "state", "original_sha256", "poisoned_sha256", "spec_id", "published_path")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass
class World:
    paths: AppPaths
    config: Config
    store: Store
    vault: Vault
    originals: dict[Path, bytes]  # row path -> the original's bytes
    extra: Path  # a `ppd poison` folder outside the outbox


def _paths(tmp: Path) -> AppPaths:
    data = tmp / "data"
    return AppPaths(
        data_dir=data, config_dir=tmp / "config", outbox=tmp / "outbox", vault_dir=data / "vault",
        db_path=data / "ppd.sqlite3", runs_dir=data / "runs", cache_dir=tmp / "cache",
    )  # fmt: skip


def _patch(
    world: World, path: Path, dataset: str, root: Path, spec: PatchSpec, publish: Path | None = None
) -> None:
    """What the core pipeline does: the original to the vault, the spec too, the patched file
    (with its marker) over the original, then publish, then the row."""
    original = path.read_bytes()
    sha = world.vault.keep(path, expected_sha256=hashlib.sha256(original).hexdigest())
    world.vault.keep_spec(spec)
    world.store.ensure_dataset(dataset, root, spec, publish)
    with atomic_output(path, mode_like=path) as tmp:
        sealed_patch(path, tmp, spec, sha, world.paths.data_dir)
    final = path
    if publish is not None:
        final = publish / path.relative_to(root)
        final.parent.mkdir(parents=True, exist_ok=True)
        os.replace(path, final)
    world.store.record_file(
        path, dataset, FileState.PATCHED, original_sha256=sha, poisoned_sha256=_sha(final),
        spec_id=spec.spec_id, tool_version="ppd test", event="patched",
        published_path=str(final) if final != path else None,
    )  # fmt: skip
    world.originals[path] = original


@pytest.fixture
def world(tmp_path: Path) -> World:
    paths = _paths(tmp_path)
    paths.ensure()
    publish = tmp_path / "pub" / "web"
    config = Config(datasets={"web": DatasetOverride(publish_dir=publish)})
    w = World(
        paths, config, Store(paths.db_path), Vault(paths.vault_dir), {}, tmp_path / "elsewhere" / "trip"
    )
    outbox, spec = paths.outbox, PatchSpec()
    shoot = outbox / "shoot"
    for i, name in enumerate(["a.png", "b.jpg", "sub/c.webp"]):
        _patch(w, write_image(shoot / name, seed=i, size=96), "shoot", shoot, spec)
    _patch(w, write_image(outbox / "top.png", seed=5, size=96), "default", outbox, spec)
    _patch(w, write_image(outbox / "web" / "d.png", seed=6, size=96), "web", outbox / "web", spec, publish)
    trip_spec = PatchSpec(seed=3)
    _patch(w, write_image(w.extra / "e.jpg", seed=7, size=96), "trip", w.extra, trip_spec)
    write_image(shoot / "new.png", seed=8, size=96)  # an original not patched yet
    return w


def _snapshot(store: Store) -> list[tuple]:
    rows = []
    for dataset in store.datasets():
        for row in store.files(dataset["name"]):
            rows.append(tuple(row[c] for c in COMPARED))
    return sorted(rows)


def _delete_store(paths: AppPaths) -> None:
    for suffix in ("", "-wal", "-shm"):
        Path(f"{paths.db_path}{suffix}").unlink(missing_ok=True)


def _assert_every_original_restorable(world: World, store: Store, where: Path) -> None:
    where.mkdir(exist_ok=True)
    for path, original in world.originals.items():
        row = store.file(path)
        assert row is not None and row["state"] == FileState.PATCHED, path
        back = where / hashlib.sha256(str(path).encode()).hexdigest()
        world.vault.restore(row["original_sha256"], back)
        assert back.read_bytes() == original, path
        patched = Path(row["published_path"] or row["path"])
        assert _sha(patched) == row["poisoned_sha256"]
        assert read_seal(patched, load_key(world.paths.data_dir)) is not None


def test_deleted_store_is_rebuilt_and_every_original_restorable(world: World, tmp_path: Path) -> None:
    before = _snapshot(world.store)
    specs_before = {d["name"]: d["spec_id"] for d in world.store.datasets()}
    assert len(before) == 6
    world.store.close()
    _delete_store(world.paths)

    report = rebuild_store(world.paths, config=world.config, folders=[world.extra])

    assert report.before == "missing" and report.kept_aside == []
    assert report.recorded == 6 and report.marked == 6 and report.without_original == []
    assert report.datasets == {"default": 1, "shoot": 3, "trip": 1, "web": 1}
    assert report.specs_missing == [] and set(report.specs.values()) == {"vault"}
    assert "\n" not in report.summary() and "6 patched file(s) in 4 dataset(s)" in report.summary()
    store = Store(world.paths.db_path)
    assert _snapshot(store) == before
    assert {d["name"]: d["spec_id"] for d in store.datasets()} == specs_before
    assert store.dataset("web")["publish_dir"] == str(tmp_path / "pub" / "web")
    assert Path(store.dataset("trip")["root"]) == world.extra
    assert store.get_spec(specs_before["trip"]) == PatchSpec(seed=3)
    assert store.file(world.paths.outbox / "shoot" / "new.png") is None  # an original: the daemon's to patch
    assert store.lost_note() is None
    _assert_every_original_restorable(world, store, tmp_path / "restored")
    store.close()


def test_symlinks_are_not_followed_and_orphans_are_counted(world: World, tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    marked_outside = write_image(outside / "x.png", seed=9, size=96)
    sha = world.vault.keep(marked_outside)
    with atomic_output(marked_outside) as tmp:
        sealed_patch(marked_outside, tmp, PatchSpec(), sha, world.paths.data_dir)
    (world.paths.outbox / "shoot" / "link.png").symlink_to(marked_outside)
    (world.paths.outbox / "linked-folder").symlink_to(outside, target_is_directory=True)
    unknown = world.paths.outbox / "shoot" / "lost-original.jpg"
    write_image(unknown, seed=10, size=96)
    with atomic_output(unknown) as tmp:
        sealed_patch(unknown, tmp, PatchSpec(), "f" * 64, world.paths.data_dir)
    world.store.close()
    _delete_store(world.paths)

    report = rebuild_store(world.paths, config=world.config)  # the `ppd poison` folder not given

    assert report.symlinks_skipped == 2
    assert report.without_original == [unknown]
    assert report.recorded == 5 and "trip" not in report.datasets
    assert report.unreferenced_originals == 2  # trip's e.jpg and the one behind the symlink
    # and the line says how to find them (a black-box review: "0 patched file(s)", nothing more)
    assert "2 vault original(s) no file names: give the folders patched outside the outbox, " \
        "`ppd store rebuild FOLDER ...`" in report.summary()
    store = Store(world.paths.db_path)
    assert store.file(world.paths.outbox / "shoot" / "link.png") is None
    assert not [r for r in store.files("linked-folder")]
    store.close()


def test_a_corrupt_vault_blob_is_not_recorded(world: World) -> None:
    victim = world.paths.outbox / "top.png"
    row = world.store.file(victim)
    world.vault.path_for(row["original_sha256"]).write_bytes(b"not the original any more")
    world.store.close()
    _delete_store(world.paths)
    report = rebuild_store(world.paths, config=world.config, folders=[world.extra])
    assert report.without_original == [victim] and report.recorded == 5


def test_a_damaged_store_is_kept_aside_and_replaced(world: World, tmp_path: Path) -> None:
    world.store.close()
    _delete_store(world.paths)
    garbage = os.urandom(20_000)
    world.paths.db_path.write_bytes(garbage)
    with pytest.raises(StoreError, match="ppd store rebuild"):
        Store(world.paths.db_path)

    report = rebuild_store(world.paths, config=world.config, folders=[world.extra])

    assert report.before == "damaged" and len(report.kept_aside) == 1
    aside = report.kept_aside[0]
    assert aside.parent == world.paths.db_path.parent and ".before-rebuild-" in aside.name
    assert aside.read_bytes() == garbage  # kept, byte for byte
    assert str(aside) in report.summary()
    store = Store(world.paths.db_path)
    assert store.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert len(_snapshot(store)) == 6
    _assert_every_original_restorable(world, store, tmp_path / "restored")
    store.close()
    assert not [p for p in world.paths.data_dir.iterdir() if ".rebuilding-" in p.name]


def test_a_sound_store_is_refused_unless_forced_and_its_datasets_are_reused(world: World) -> None:
    before = _snapshot(world.store)
    world.store.close()
    with pytest.raises(RebuildRefused, match="--force") as caught:
        rebuild_store(world.paths, config=world.config)
    assert "\n" not in str(caught.value)
    assert len(list(world.paths.data_dir.glob("ppd.sqlite3*before-rebuild*"))) == 0
    for spec_file in (world.paths.vault_dir / "specs").iterdir():
        spec_file.unlink()  # the specs are still in the old store

    report = rebuild_store(world.paths, config=world.config, force=True)  # trip found by its old root

    assert report.before == "sound" and report.kept_aside and report.old_datasets == 4
    assert report.recorded == 6 and set(report.specs.values()) == {"old store"}
    store = Store(world.paths.db_path)
    assert _snapshot(store) == before
    store.close()
    assert Vault(world.paths.vault_dir).load_spec(PatchSpec(seed=3).spec_id) == PatchSpec(
        seed=3
    )  # kept again


def test_specs_come_back_from_the_config_or_are_reported_missing(world: World) -> None:
    world.store.close()
    _delete_store(world.paths)
    for spec_file in (world.paths.vault_dir / "specs").iterdir():
        spec_file.unlink()
    report = rebuild_store(world.paths, config=world.config, folders=[world.extra])
    assert report.specs == {PatchSpec().spec_id: "defaults"}  # PatchSpec(), not the config default
    assert report.specs_missing == [PatchSpec(seed=3).spec_id]
    assert "1 spec(s) not recovered" in report.summary()
    store = Store(world.paths.db_path)
    assert (
        store.dataset("trip")["spec_id"] is None and store.dataset("shoot")["spec_id"] == PatchSpec().spec_id
    )
    assert store.file(world.extra / "e.jpg")["spec_id"] == PatchSpec(seed=3).spec_id
    store.close()


def test_a_lost_store_is_rebuilt_without_force_and_the_note_goes(world: World) -> None:
    world.store.close()
    _delete_store(world.paths)
    lost = Store.open_or_warn(world.paths.db_path, world.paths.vault_dir)
    assert lost.lost_warning is not None
    lost.close()
    report = rebuild_store(world.paths, config=world.config, folders=[world.extra])
    assert report.before == "lost" and report.recorded == 6
    store = Store.open_or_warn(world.paths.db_path, world.paths.vault_dir)
    assert store.lost_warning is None and not store.fresh
    store.close()


def test_a_file_reached_twice_is_recorded_once(world: World) -> None:
    world.store.close()
    _delete_store(world.paths)
    report = rebuild_store(
        world.paths, config=world.config, folders=[world.extra, world.paths.outbox / "shoot"]
    )  # shoot's files are reached from the outbox first
    assert report.recorded == 6 and report.conflicts == [] and report.datasets["shoot"] == 3
