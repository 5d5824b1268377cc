"""protect_many (daemon.protect.pool): worker processes write byte for byte what serial protect_file
writes, and record the same rows; real files, a real SQLite store, a real vault."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from daemon.context import AppContext
from daemon.datasets.dataset import attribute
from daemon.protect.job import ProtectOutcome
from daemon.protect.pool import protect_many

VOLATILE = {"id", "path", "dataset", "updated_at", "created_at", "mtime_ns"}  # when and where, not what


@pytest.fixture
def ctx(ppd_env: dict[str, Path]) -> AppContext:
    context = AppContext.open()
    yield context
    context.close()


def make_shoot(folder: Path) -> list[Path]:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(3)
    files = []
    for i in range(5):
        pixels = rng.integers(0, 256, size=(150 + 8 * i, 200, 3), dtype=np.uint8)
        path = folder / (f"IMG_{i:03d}.jpg" if i % 2 else f"view_{i:03d}.png")
        Image.fromarray(pixels).save(path, **({"quality": 90} if path.suffix == ".jpg" else {}))
        files.append(path)
    broken = folder / "broken.jpg"
    broken.write_bytes(files[1].read_bytes()[:300])
    return [*files, broken]


def jobs_for(ctx: AppContext, folder: Path, files: list[Path]) -> list[tuple[Path, str, Path, None]]:
    name, root = attribute(ctx, folder)
    return [(f, name, root, None) for f in files]


def rows(ctx: AppContext, dataset: str) -> dict[str, dict]:
    found = ctx.store.files(dataset)
    return {Path(r["path"]).name: {k: v for k, v in r.items() if k not in VOLATILE} for r in found}


def test_workers_write_what_serial_writes(ctx: AppContext, tmp_path: Path) -> None:
    serial_files = make_shoot(tmp_path / "a" / "castle-a")
    pool_dir = tmp_path / "b" / "castle-b"
    shutil.copytree(serial_files[0].parent, pool_dir)
    pool_files = [pool_dir / f.name for f in serial_files]
    originals = {f.name: f.read_bytes() for f in serial_files}

    serial = protect_many(ctx, jobs_for(ctx, serial_files[0].parent, serial_files), workers=1)
    seen: list[ProtectOutcome] = []
    pooled = protect_many(ctx, jobs_for(ctx, pool_dir, pool_files), workers=2, on_outcome=seen.append)

    assert [o.path for o in pooled] == [p.absolute() for p in pool_files]  # input order
    assert sorted(o.path.name for o in seen) == sorted(f.name for f in serial_files)
    assert [o.state for o in pooled] == [o.state for o in serial]
    assert [o.state for o in pooled].count("patched") == len(serial_files) - 1
    assert pooled[-1].state == "failed" and pooled[-1].reason and "\n" not in pooled[-1].reason
    for s, p in zip(serial_files, pool_files, strict=True):
        assert s.read_bytes() == p.read_bytes(), s.name
    assert sum(originals[f.name] != f.read_bytes() for f in pool_files) == len(pool_files) - 1
    assert rows(ctx, "castle-a") == rows(ctx, "castle-b")  # the same rows, whichever process wrote them
    for o in pooled[:-1]:
        assert ctx.vault.has(o.original_sha256)


def test_workers_write_copies_with_out_and_leave_inputs(ctx: AppContext, tmp_path: Path) -> None:
    files = make_shoot(tmp_path / "shoot")
    before = {f: f.read_bytes() for f in files}
    name, root = attribute(ctx, files[0].parent)
    out = tmp_path / "pub"
    jobs = [(f, name, root, out / name / f.name) for f in files]
    outcomes = protect_many(ctx, jobs, workers=2)
    assert {f: f.read_bytes() for f in files} == before
    patched = [o for o in outcomes if o.state == "patched"]
    assert len(patched) == len(files) - 1
    assert all((out / name / o.path.name).read_bytes() != before[o.path] for o in patched)
    again = protect_many(ctx, jobs, workers=2)  # up to date: nothing rewritten
    assert [o.state for o in again if o.path.name != "broken.jpg"] == ["unchanged"] * (len(files) - 1)


def test_dry_run_in_workers_changes_nothing(ctx: AppContext, tmp_path: Path) -> None:
    files = make_shoot(tmp_path / "dry")
    before = {f: f.read_bytes() for f in files}
    outcomes = protect_many(ctx, jobs_for(ctx, files[0].parent, files), workers=2, dry_run=True)
    assert [o.state for o in outcomes[:-1]] == ["patched"] * (len(files) - 1)
    assert all(o.dry_run and o.reason == "would patch" for o in outcomes[:-1])
    assert {f: f.read_bytes() for f in files} == before
    assert ctx.store.files("dry") == []


def test_the_daemons_workers_use_the_configs_subject_masks(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd watch`'s worker processes (ProtectWorkers): a new outbox dataset with a corner mark in the
    config gets its corner from the config's masks once, and every file keeps its mark off the subject."""
    from daemon.protect.pool import ProtectWorkers
    from testkit.photos import assert_in_corner_off_subject, changed_pixels, masked_shoot

    masks = tmp_path / "masks"
    files = masked_shoot(ppd_env["outbox"] / "shoot", masks, n=4)
    originals = {f.name: f.read_bytes() for f in files}
    (ppd_env["config"] / "config.toml").write_text(
        '[patch]\ndesign = "watermark"\n'
        f'[datasets.shoot]\nsubject_masks = "{masks}"\n'
    )
    ctx = AppContext.open()
    workers = ProtectWorkers(ctx, slots=2, idle_s=60)
    try:
        outcomes = [workers.protect(f) for f in files]
        assert [o.state for o in outcomes] == ["patched"] * len(files), [o.reason for o in outcomes]
        assert ctx.store.dataset_spec("shoot").position == "bottom-right"
        chosen = [e["detail"] for e in ctx.store.events("shoot") if e["kind"] == "corner_chosen"]
        assert len(chosen) == 1 and chosen[0]["source"] == "masks"
        assert chosen[0]["subject_masks"] == str(masks)
    finally:
        workers.close()
        ctx.close()
    for f in files:
        mask = masks / f"{f.stem[-3:]}.png"
        assert_in_corner_off_subject(changed_pixels(originals[f.name], f), mask, "bottom-right")
