"""Small generated photos, a polling wait and a bursty writer: what daemon, CLI and bench scenarios drop."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import PIL.Image


def texture(seed: int, size: int = 256) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (rng.random((size, size, 3)) * 255).astype(np.uint8)


def write_image(path: Path, seed: int, size: int = 256) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = "JPEG" if path.suffix.lower() in (".jpg", ".jpeg") else "PNG"
    PIL.Image.fromarray(texture(seed, size)).save(path, format=fmt)
    return path


def wait_for(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def burst_writer(path: Path, data: bytes, bursts: int, gap_s: float) -> None:
    """open(path, 'ab'), write a part, close; pause; again: how some uploaders and sync tools write."""
    step = -(-len(data) // bursts)
    for i in range(bursts):
        with open(path, "ab") as f:
            f.write(data[i * step : (i + 1) * step])
        if i < bursts - 1:
            time.sleep(gap_s)
