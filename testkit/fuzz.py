"""Fuzzing ppd's image readers: small seed files of each format, a byte mutator, and one reader run
that says 'ok' or 'refused' and lets any other exception through (tests/poisoner/test_properties.py's
hypothesis tests and bench/bench_faults.py's long fuzz runs)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import PIL.Image

from poisoner.formats import ImageFormatError, poison_file
from poisoner.spec import PatchSpec


def _seed_files() -> dict[str, bytes]:
    rng = np.random.default_rng(3)
    pixels = rng.integers(0, 256, (40, 56, 3), dtype=np.uint8)
    seeds = {}
    for fmt, suffix in (("PNG", ".png"), ("JPEG", ".jpg"), ("WEBP", ".webp"), ("TIFF", ".tif")):
        buf = io.BytesIO()
        PIL.Image.fromarray(pixels).save(buf, format=fmt)
        seeds[suffix] = buf.getvalue()
    return seeds


SEEDS = _seed_files()


def mutate(data: bytes, edits: list[tuple[int, int]], cut: int | None) -> bytes:
    """Overwrite bytes at (position mod length) with values, then optionally truncate."""
    out = bytearray(data)
    for pos, value in edits:
        out[pos % len(out)] = value
    return bytes(out[:cut] if cut is not None else out)


def fuzz_image_reader(folder: Path, suffix: str, data: bytes) -> str:
    """Feed bytes to poison_file; 'ok' or 'refused'. Any other exception propagates (a bug).

    A refusal writes nothing: no output file (not even an empty or partial one) and nothing else
    left in the folder."""
    src, dst = folder / f"fuzz{suffix}", folder / f"out{suffix}"
    src.write_bytes(data)
    dst.unlink(missing_ok=True)  # an earlier example's output (hypothesis reuses the folder)
    before = sorted(folder.iterdir())
    try:
        poison_file(src, dst, PatchSpec(patch_size=8, block_size=2))
    except ImageFormatError as exc:
        assert str(exc) and "\n" not in str(exc)
        assert not dst.exists(), f"refused, yet {dst.name} was written ({dst.stat().st_size} bytes)"
        assert sorted(folder.iterdir()) == before, "a refusal left files behind"
        return "refused"
    assert dst.stat().st_size > 0
    PIL.Image.open(dst).load()  # what it wrote is a complete image
    return "ok"
