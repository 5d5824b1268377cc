"""Issue 25: a dataset remembers its subject masks, and a change to its pixels turns its verdict back
into "patched, not verified" (the old verdict stays in the history). Real CLI, real SQLite store."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.cli.status_queries import dataset_status, protection_line
from daemon.context import AppContext

runner = CliRunner()


def busy(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (h // 4, w // 4, 3), dtype=np.uint8)
    return np.repeat(np.repeat(small, 4, axis=0), 4, axis=1)


@pytest.fixture
def masked_set(ppd_env: dict[str, Path], tmp_path: Path) -> tuple[Path, Path]:
    """Three photos whose top half is plain, the plain top being the SUBJECT (a white product on a
    busy table): without the masks the mark would go onto it."""
    images, masks = tmp_path / "shoot" / "image", tmp_path / "shoot_masks"
    images.mkdir(parents=True)
    masks.mkdir()
    for i in range(3):
        pixels = busy(240, 320, i)
        pixels[:120] = 235
        Image.fromarray(pixels).save(images / f"{i:06d}.png")
        mask = np.zeros((240, 320), dtype=np.uint8)
        mask[:125] = 255
        Image.fromarray(mask).save(masks / f"{i:03d}.png")
    return images, masks


def changed(a: Path, b: bytes | Path) -> np.ndarray:
    import io

    pa = np.asarray(Image.open(a).convert("RGB")).astype(int)
    pb = np.asarray(Image.open(io.BytesIO(b) if isinstance(b, bytes) else b).convert("RGB")).astype(int)
    return np.abs(pa - pb).max(axis=2) > 0


def test_masks_are_remembered_for_a_later_force_run(masked_set: tuple[Path, Path]) -> None:
    images, masks = masked_set
    originals = {p.name: p.read_bytes() for p in images.iterdir()}
    first = runner.invoke(app, ["poison", str(images), "--subject-masks", str(masks), "-j", "1"])
    assert first.exit_code == 0, first.output
    ctx = AppContext.open()
    try:
        assert ctx.store.dataset_masks("image") == masks.absolute()
        assert dataset_status(ctx, "image")["subject_masks"] == str(masks.absolute())
    finally:
        ctx.close()
    assert runner.invoke(app, ["restore", "image"]).exit_code == 0
    assert {p.name: p.read_bytes() for p in images.iterdir()} == originals
    again = runner.invoke(app, ["poison", str(images), "--force", "-j", "1"])  # no --subject-masks
    assert again.exit_code == 0, again.output
    assert "patched 3" in again.output
    for name, original in originals.items():
        diff = changed(images / name, original)
        assert diff.any() and not diff[:125].any()  # marked, never on the remembered subject


def test_a_pixel_change_makes_the_verdict_history(masked_set: tuple[Path, Path]) -> None:
    images, masks = masked_set
    first = runner.invoke(app, ["poison", str(images), "--subject-masks", str(masks), "-j", "1"])
    assert first.exit_code == 0, first.output
    ctx = AppContext.open()
    try:
        now = time.time()
        for profile in ("default", "hardened", "published"):
            ctx.store.add_verification_run("image", profile, "protected", {}, now, now + 1, None, None)
        assert protection_line(ctx, "image").startswith("image: protected under default, hardened, published")
        assert dataset_status(ctx, "image")["protection"]["state"] == "protected"
    finally:
        ctx.close()
    time.sleep(0.01)
    Image.fromarray(busy(240, 320, 9)).save(images / "000009.png")  # a new photo joins the set
    assert runner.invoke(app, ["poison", str(images), "-j", "1"]).exit_code == 0
    ctx = AppContext.open()
    try:
        assert protection_line(ctx, "image") == "image: patched, not verified: run `ppd verify image`"
        assert dataset_status(ctx, "image")["protection"]["state"] == "patched, not verified"
        assert len(ctx.store.verification_runs("image")) == 3  # the old verdict stays in the history
        assert ctx.store.current_verification_runs("image") == []
        later = time.time()
        ctx.store.add_verification_run("image", "default", "protected", {}, later, later + 1, None, None)
        assert [r["profile"] for r in ctx.store.current_verification_runs("image")] == ["default"]
    finally:
        ctx.close()
    time.sleep(0.01)
    restored = runner.invoke(app, ["restore", "image"])  # a restore changes the pixels too
    assert restored.exit_code == 0, restored.output
    ctx = AppContext.open()
    try:
        assert ctx.store.current_verification_runs("image") == []
    finally:
        ctx.close()
