"""poison_many: a pool writes byte for byte what serial poisoning writes; failures stay per file."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
from PIL import Image

from poisoner.batch import BatchResult, default_workers, poison_many
from poisoner.formats import poison_in_place
from poisoner.ladder import default_spec
from poisoner.provenance import Marker


def make_folder(folder: Path) -> list[Path]:
    folder.mkdir()
    rng = np.random.default_rng(0)
    paths = []
    for i in range(5):
        pixels = rng.integers(0, 256, size=(180 + 8 * i, 260, 3), dtype=np.uint8)
        path = folder / f"IMG_{i:03d}.jpg"
        Image.fromarray(pixels).save(path, quality=85, subsampling=i % 3)
        paths.append(path)
    png = folder / "view.png"
    Image.fromarray(rng.integers(0, 256, size=(200, 200, 4), dtype=np.uint8)).save(png)
    bad = folder / "broken.jpg"
    bad.write_bytes(paths[0].read_bytes()[:300])
    return [*paths, png, bad]


def test_pool_writes_what_serial_writes(tmp_path: Path) -> None:
    spec = default_spec()  # moving: every file gets its own placement
    files = make_folder(tmp_path / "a")
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    originals = {p.name: p.read_bytes() for p in files}
    markers = {
        p: Marker.placeholder(bytes(32), "x" * 16, f"{i:064d}") for i, p in enumerate(files)
    }
    serial = poison_many([(p, p) for p in files], spec, workers=1, markers=markers)
    pool_files = [tmp_path / "b" / p.name for p in files]
    pool_markers = {tmp_path / "b" / p.name: m for p, m in markers.items()}
    seen: list[BatchResult] = []
    pooled = poison_many(
        [(p, p) for p in pool_files], spec, workers=2, markers=pool_markers, on_done=seen.append
    )
    assert [r.src.name for r in pooled] == [p.name for p in files]  # input order
    assert sorted(r.src.name for r in seen) == sorted(p.name for p in files)
    for s, p in zip(serial, pooled, strict=True):
        assert (s.error is None) == (p.error is None)
        assert s.src.read_bytes() == p.src.read_bytes(), s.src.name
        if s.report is not None:
            assert s.report == p.report
    failed = [r for r in pooled if r.error]
    assert [r.src.name for r in failed] == ["broken.jpg"] and "\n" not in failed[0].error
    assert (tmp_path / "b" / "broken.jpg").read_bytes() == originals["broken.jpg"]
    changed = [p for p in pool_files if p.read_bytes() != originals[p.name]]
    assert len(changed) == len(files) - 1
    # and what a plain poison_in_place writes
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    (fresh / "IMG_002.jpg").write_bytes(originals["IMG_002.jpg"])
    poison_in_place(fresh / "IMG_002.jpg", spec, marker=markers[files[2]])
    assert (fresh / "IMG_002.jpg").read_bytes() == (tmp_path / "b" / "IMG_002.jpg").read_bytes()


def test_pool_to_other_folder_leaves_sources(tmp_path: Path) -> None:
    files = make_folder(tmp_path / "src")
    out = tmp_path / "out"
    out.mkdir()
    before = {p: p.read_bytes() for p in files}
    results = poison_many([(p, out / p.name) for p in files[:3]], default_spec(), workers=2)
    assert all(r.error is None and r.dst.exists() for r in results)
    assert all(p.read_bytes() == b for p, b in before.items())


def test_default_workers_bounded() -> None:
    assert default_workers(1) == 1
    assert 1 <= default_workers(1000) <= 8


def _probe(i: int, weight: int, folder: str) -> int:
    """Runs in a pool worker: the total weight of the calls running beside this one (itself included)."""
    import time

    mark = Path(folder) / f"{i}-{weight}"
    mark.touch()
    time.sleep(0.4)
    total = sum(int(p.name.split("-")[1]) for p in Path(folder).iterdir())
    mark.unlink()
    return total


def test_bounded_map_never_runs_more_weight_than_its_budget(tmp_path: Path) -> None:
    """Issue 29: the pool admits files by their memory estimate, never more than the byte budget
    at once (one file alone over it still runs, to be refused from its header)."""
    from poisoner.batch import bounded_map

    weights = [600, 600, 300, 300, 2500, 100, 400]
    calls = [(i, w, str(tmp_path)) for i, w in enumerate(weights)]
    seen = bounded_map(_probe, calls, 4, lambda i: -1, weights=weights, budget=1000)
    assert -1 not in seen and seen[4] == 2500  # the heavy one ran alone
    assert all(total <= 1000 for i, total in enumerate(seen) if i != 4), seen
    free = bounded_map(_probe, calls, 4, lambda i: -1)  # no budget: they overlap
    assert max(t for i, t in enumerate(free) if i != 4) > 1000, free
