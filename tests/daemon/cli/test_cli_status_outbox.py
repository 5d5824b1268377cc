"""`ppd status` and its `--check` gate see what the outbox holds, not only the store's datasets (a
black-box review of the daemon, 2026-12-07): with the daemon stopped, a folder and a loose photo put in
the outbox were in no table, `ppd status ghost` said there was no such folder, and `--check && publish`
could pass over them. A dataset whose folder is gone, and quarantined files the user has deleted, no
longer keep `--check` failing for ever."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from daemon.protect.one_file import AppContext
from daemon.protect.quarantine import quarantine
from testkit.cli import said as _said
from testkit.photos import make_image

runner = CliRunner()


def test_photos_in_the_outbox_no_dataset_holds_are_said_and_fail_the_check(ppd_env: dict[str, Path]) -> None:
    outbox = ppd_env["outbox"]
    for i in range(2):
        make_image(outbox / "ghost" / f"v{i}.png", i)
    make_image(outbox / "loose.png", 5)
    (outbox / "notes.txt").write_text("not a photo")
    code, text = _said("status")
    assert code == 0 and "outbox: 3 photo(s) or video(s) no dataset holds yet, NOT protected" in text, text
    assert "ghost/v0.png" in text and "loose.png" in text and "notes.txt" not in text
    code, text = _said("status", "--check")
    assert code == 1 and "not ready to publish: outbox: 3 photo(s) or video(s) not patched yet" in text
    listed = json.loads(runner.invoke(app, ["status", "--json"]).output)["outbox_not_patched"]
    assert sorted(Path(p).name for p in listed) == ["loose.png", "v0.png", "v1.png"]
    code, text = _said("status", "ghost")
    assert code == 2 and "ghost: a folder of the outbox that ppd has not patched yet" in text, text
    # `ppd poison OUTBOX` files them as the daemon does: one dataset per folder, "default" for loose ones
    assert runner.invoke(app, ["poison", str(outbox)]).exit_code == 0
    datasets = {d["name"]: d for d in json.loads(runner.invoke(app, ["status", "--json"]).output)["datasets"]}
    assert set(datasets) == {"ghost", "default"} and datasets["ghost"]["patched"] == 2
    assert "no dataset holds" not in _said("status")[1]
    # a new photo of an outbox dataset's: not patched, so listed (a black-box review: [] read as clean)
    make_image(outbox / "fresh.png", 7)
    said = json.loads(runner.invoke(app, ["status", "--json"]).output)
    assert said["outbox_not_patched"] == [str(outbox / "fresh.png")], said["outbox_not_patched"]
    assert said["outbox_no_dataset"] == [] and said["ready_to_publish"] is False


def test_a_dataset_whose_folder_is_gone_does_not_hold_the_check(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "offline"
    make_image(shoot / "v0.png", 0)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    shutil.rmtree(shoot)
    code, text = _said("status", "--check")
    assert "not ready to publish: offline" not in text and "not shown: 1 dataset(s)" in text, text
    assert code == 1  # nothing at all is ready to publish: still not a pass


def test_a_quarantined_file_the_user_deleted_no_longer_counts(ppd_env: dict[str, Path]) -> None:
    kitchen = ppd_env["outbox"] / "kitchen"
    make_image(kitchen / "IMG_0.png", 0)
    notes = kitchen / "notes.jpg"
    notes.write_text("a text file with a photo's name")
    assert runner.invoke(app, ["poison", str(kitchen)]).exit_code == 1
    ctx = AppContext.open()
    try:
        moved = quarantine(ctx, notes, "kitchen", ctx.store.file(notes)["error"])
    finally:
        ctx.close()
    assert moved is not None and moved.exists()
    assert "1 quarantined" in _said("status", "kitchen", "--check")[1]
    moved.unlink()  # the user dealt with it
    counts = json.loads(runner.invoke(app, ["status", "kitchen", "--json"]).output)["datasets"][0]["counts"]
    assert counts["quarantined"] == 0 and counts["files"] == 1, counts
    assert "1 quarantined" not in _said("status", "kitchen", "--check")[1]


def test_a_symlinked_outbox_patched_through_its_real_path_is_not_said_unpatched(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The diff review: with PPD_OUTBOX=/x/link/outbox and `ppd poison /x/real/outbox/newds`, status
    said its photo was NOT protected and --check failed for good."""
    real = tmp_path / "real"
    (real / "outbox").mkdir(parents=True)
    (tmp_path / "link").symlink_to(real, target_is_directory=True)
    for name in ("data", "config"):
        monkeypatch.setenv(f"PPD_{name.upper()}_DIR", str(tmp_path / name))
    monkeypatch.setenv("PPD_OUTBOX", str(tmp_path / "link" / "outbox"))
    make_image(real / "outbox" / "newds" / "r_6.png", 6)
    assert "no dataset holds" in _said("status")[1]
    assert runner.invoke(app, ["poison", str(real / "outbox" / "newds")]).exit_code == 0
    assert "no dataset holds" not in _said("status")[1]
