"""The non-daemon CLI through typer's CliRunner against the real `ppd` app."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.protect import AppContext
from daemon.states import FileState
from poisoner.ladder import default_spec
from poisoner.spec import PatchSpec

runner = CliRunner()


def make_image(path: Path, seed: int, size: tuple[int, int] = (160, 120)) -> Path:
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)).save(path)
    return path


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def shoot(ppd_env: dict[str, Path], tmp_path: Path) -> Path:
    folder = tmp_path / "photos" / "castle"
    for i in range(4):
        make_image(folder / f"view{i}.png", i)
    make_image(folder / "inner" / "view9.png", 9)
    return folder


def test_poison_folder_then_rerun_is_a_noop(shoot: Path) -> None:
    before = snapshot(shoot)
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    after = snapshot(shoot)
    assert after.keys() == before.keys()
    assert all(after[k] != before[k] for k in before)
    ctx = AppContext.open()
    rows = ctx.store.files("castle")
    assert len(rows) == 5 and {r["state"] for r in rows} == {FileState.PATCHED.value}
    assert ctx.store.dataset("castle")["root"] == str(shoot)
    ctx.close()
    again = runner.invoke(app, ["poison", str(shoot)])
    assert again.exit_code == 0, again.output
    assert snapshot(shoot) == after
    assert "unchanged" in again.output


def test_poison_out_leaves_inputs(shoot: Path, tmp_path: Path) -> None:
    before = snapshot(shoot)
    out = tmp_path / "published"
    result = runner.invoke(app, ["poison", str(shoot), "--out", str(out), "--patch-size", "48"])
    assert result.exit_code == 0, result.output
    assert snapshot(shoot) == before
    produced = snapshot(out / "castle")
    assert produced.keys() == before.keys()
    assert all(produced[k] != before[k] for k in before)
    patch = np.asarray(Image.open(out / "castle" / "view0.png"))[:48, :48]
    clean = np.asarray(Image.open(shoot / "view0.png"))[:48, :48]
    assert not np.array_equal(patch, clean)
    rerun = runner.invoke(app, ["poison", str(shoot), "--out", str(out), "--patch-size", "48"])
    assert rerun.exit_code == 0 and snapshot(out / "castle") == produced


def test_dry_run_changes_nothing(shoot: Path, ppd_env: dict[str, Path]) -> None:
    before = snapshot(shoot)
    result = runner.invoke(app, ["poison", str(shoot), "--dry-run", "--alpha", "0.5"])
    assert result.exit_code == 0, result.output
    assert "would patch" in result.output
    assert snapshot(shoot) == before
    ctx = AppContext.open()
    assert ctx.store.files("castle") == [] and ctx.store.dataset("castle") is None
    assert not list(ctx.paths.vault_dir.glob("??/*"))
    ctx.close()


def test_failures_give_nonzero_exit_and_lose_nothing(shoot: Path) -> None:
    (shoot / "broken.png").write_bytes(b"\x89PNG but truncated")
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 1
    assert "broken.png" in result.output
    assert (shoot / "broken.png").read_bytes() == b"\x89PNG but truncated"


def test_restore_dataset_is_byte_exact(shoot: Path) -> None:
    before = snapshot(shoot)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    result = runner.invoke(app, ["restore", "castle"])
    assert result.exit_code == 0, result.output
    assert snapshot(shoot) == before
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert snapshot(shoot) == before  # restored files are not re-poisoned without --force
    assert runner.invoke(app, ["poison", str(shoot), "--force"]).exit_code == 0
    assert snapshot(shoot) != before
    one = shoot / "view1.png"
    assert runner.invoke(app, ["restore", str(one)]).exit_code == 0
    assert one.read_bytes() == before["view1.png"]
    assert runner.invoke(app, ["restore", "nosuchthing"]).exit_code == 2


def test_status_json_and_regression_warning(shoot: Path, tmp_path: Path) -> None:
    (shoot / "broken.png").write_bytes(b"junk")
    runner.invoke(app, ["poison", str(shoot)])
    result = runner.invoke(app, ["status", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    (castle,) = data["datasets"]
    assert (
        castle["name"] == "castle" and castle["patched"] == 5 and castle["counts"]["failed"] == 1
    )
    assert castle["spec_id"] == default_spec().spec_id and castle["last_verification"] is None
    assert castle["regression"] is None
    ctx = AppContext.open()
    now = time.time()
    ctx.store.add_verification_run("castle", "default", "protected", {}, now - 100, now - 90, None, None)
    ctx.store.add_verification_run("castle", "default", "not_protected", {}, now - 10, now - 5, None, None)
    ctx.close()
    table = runner.invoke(app, ["status"])
    assert table.exit_code == 0
    assert "REGRESSION" in table.output and "castle" in table.output
    data = json.loads(runner.invoke(app, ["status", "castle", "--json"]).stdout)
    assert data["datasets"][0]["last_verification"]["verdict"] == "not_protected"
    assert data["datasets"][0]["regression"]["profile"] == "default"


def test_status_warns_about_sync_folders(ppd_env: dict[str, Path]) -> None:
    (ppd_env["outbox"].parent / ".stfolder").mkdir()
    result = runner.invoke(app, ["status"])
    assert result.exit_code == 0
    assert "Syncthing" in result.output
    assert json.loads(runner.invoke(app, ["status", "--json"]).stdout)["sync_folder"]["client"] == "Syncthing"


def test_dataset_set_show_and_reprotect(shoot: Path) -> None:
    set_first = runner.invoke(app, ["dataset", "set", "castle", "--root", str(shoot), "--patch-size", "6%"])
    assert set_first.exit_code == 0, set_first.output
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    protected = snapshot(shoot)
    locked = runner.invoke(app, ["dataset", "set", "castle", "--position", "bottom-right"])
    assert locked.exit_code == 2 and "--reprotect" in locked.output
    assert snapshot(shoot) == protected
    changed = runner.invoke(app, ["dataset", "set", "castle", "--position", "bottom-right", "--reprotect"])
    assert changed.exit_code == 0, changed.output
    assert all(snapshot(shoot)[k] != protected[k] for k in protected)
    shown = json.loads(runner.invoke(app, ["dataset", "show", "castle", "--json"]).stdout)
    assert shown["spec"]["position"] == "bottom-right" and shown["spec"]["patch_size"] == 0.06
    # poisoning with different flags now is refused, not silently mixed
    mixed = runner.invoke(app, ["poison", str(shoot), "--patch-size", "30"])
    assert mixed.exit_code == 2 and "--reprotect" in mixed.output


def test_same_dataset_name_for_another_folder_is_refused(shoot: Path, tmp_path: Path) -> None:
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    other = tmp_path / "elsewhere" / "castle"
    make_image(other / "x.png", 1)
    before = snapshot(other)
    result = runner.invoke(app, ["poison", str(other)])
    assert result.exit_code == 2 and "--dataset" in result.output
    assert snapshot(other) == before
    assert runner.invoke(app, ["poison", str(other), "--dataset", "castle2"]).exit_code == 0


def test_preview_writes_a_png(shoot: Path, tmp_path: Path) -> None:
    out = tmp_path / "preview.png"
    result = runner.invoke(
        app, ["preview", str(shoot / "view0.png"), "--out", str(out), "--patch-size", "0.2"]
    )
    assert result.exit_code == 0, result.output
    with Image.open(out) as im:
        assert im.format == "PNG" and im.width >= 2 * 160
    # The opaque patch (20% of the width) is plainly visible, and the preview says so and where.
    line = " ".join(result.output.split())
    p999 = float(line.split("FLIP p99.9 ")[1].split()[0])
    visible = float(line.split("; ")[1].split("%")[0])
    assert "visibility at 160 px wide" in line and p999 > 0.5 and visible > 1.0, line
    runner.invoke(app, ["poison", str(shoot)])
    protected_preview = tmp_path / "p2.png"
    assert (
        runner.invoke(app, ["preview", str(shoot / "view0.png"), "--out", str(protected_preview)]).exit_code
        == 0
    )
    assert protected_preview.is_file()


def test_config_show_and_path(ppd_env: dict[str, Path]) -> None:
    (ppd_env["config"] / "config.toml").write_text("workers = 5\n")
    shown = runner.invoke(app, ["config", "show"])
    assert shown.exit_code == 0 and "workers = 5" in shown.output and "[patch]" in shown.output
    where = runner.invoke(app, ["config", "path"])
    assert str(ppd_env["config"] / "config.toml") in where.output and str(ppd_env["outbox"]) in where.output
    (ppd_env["config"] / "config.toml").write_text("workers = [\n")
    bad = runner.invoke(app, ["config", "show"])
    assert bad.exit_code == 2


def test_file_hash_of_vault_matches(shoot: Path) -> None:
    original = (shoot / "view2.png").read_bytes()
    runner.invoke(app, ["poison", str(shoot / "view2.png")])
    ctx = AppContext.open()
    row = ctx.store.file(shoot / "view2.png")
    assert row["dataset"] == "castle"
    assert row["original_sha256"] == hashlib.sha256(original).hexdigest()
    assert ctx.vault.path_for(row["original_sha256"]).read_bytes() == original
    ctx.close()


def test_spec_summary_names_offset_and_motion() -> None:
    from daemon.cli.status_queries import spec_summary

    assert spec_summary(PatchSpec()) == "checkerboard 6% block 0.5% α1 Δc255 top-left"
    moving = spec_summary(default_spec())
    assert moving.startswith("random_blocks 6%") and "+(15%, 15%)" in moving and "drift 0.75%/image" in moving


def test_workers_write_the_bytes_of_a_serial_run(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`--workers 2` (a pool of processes) and `--workers 1` (in this process) write the same files
    and rows; the summary counts every file once and says the dataset is not verified yet."""
    serial, pooled = tmp_path / "a" / "shoot", tmp_path / "b" / "shoot"
    for i in range(5):
        make_image(serial / f"v{i}.png", i)
        make_image(pooled / f"v{i}.png", i)
    one = runner.invoke(app, ["poison", str(serial), "--dataset", "serial", "--workers", "1"])
    two = runner.invoke(app, ["poison", str(pooled), "--dataset", "pooled", "-j", "2"])
    assert one.exit_code == 0 and two.exit_code == 0, one.output + two.output
    assert snapshot(serial) == snapshot(pooled) != {}
    assert "patched 5, unchanged 0, skipped 0, failed 0" in two.output
    assert "pooled: patched, not verified" in two.output and "ppd verify pooled" in two.output
    ctx = AppContext.open()
    try:
        assert [r["poisoned_sha256"] for r in ctx.store.files("serial")] == [
            r["poisoned_sha256"] for r in ctx.store.files("pooled")
        ]
    finally:
        ctx.close()


def test_a_known_dataset_name_keeps_its_folder(shoot: Path, tmp_path: Path) -> None:
    """--dataset NAME of a known dataset: files inside its folder join it; a folder elsewhere is
    refused in one line before anything is written (daemon.dataset.attribute)."""
    assert runner.invoke(app, ["poison", str(shoot / "view0.png"), "--dataset", "castle"]).exit_code == 0
    inner = runner.invoke(app, ["poison", str(shoot / "inner"), "--dataset", "castle"])
    assert inner.exit_code == 0, inner.output
    ctx = AppContext.open()
    try:
        assert ctx.store.dataset("castle")["root"] == str(shoot)
        assert len(ctx.store.files("castle")) == 2
    finally:
        ctx.close()
    other = tmp_path / "elsewhere"
    make_image(other / "x.png", 3)
    before = snapshot(other)
    refused = runner.invoke(app, ["poison", str(other), "--dataset", "castle"])
    assert refused.exit_code == 2 and "already belongs to" in refused.output
    assert snapshot(other) == before
