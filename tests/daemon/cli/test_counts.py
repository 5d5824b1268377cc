"""One count per thing everywhere, and every message names its file (issue 28): a quarantined
upload counted once in `status`, `status --failed` and `--json`; an `--out` dataset's copies shown
by `status` and counted as removed by `restore`; a text file named `.jpg` is "not an image"; the
corner's warning names its file, unpadded, and `-v` says the corner once."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from daemon.protect.one_file import AppContext
from daemon.protect.quarantine import quarantine
from testkit.photos import make_image

runner = CliRunner()


def test_a_quarantined_upload_is_counted_once_everywhere(ppd_env: dict[str, Path]) -> None:
    kitchen = ppd_env["outbox"] / "kitchen"
    for i in range(2):
        make_image(kitchen / f"IMG_{i}.png", i)
    notes = kitchen / "notes.jpg"
    notes.write_text("a text file with a photo's name")
    result = runner.invoke(app, ["poison", str(kitchen)])
    assert result.exit_code == 1  # the text file failed
    ctx = AppContext.open()
    row = ctx.store.file(notes)
    assert "not a recognised image" in row["error"] and "incomplete" not in row["error"]
    assert quarantine(ctx, notes, "kitchen", row["error"]) is not None  # what the daemon does with it
    ctx.close()

    (d,) = json.loads(runner.invoke(app, ["status", "kitchen", "--json"]).output)["datasets"]
    assert d["counts"]["quarantined"] == 1 and d["counts"]["failed"] == 0
    assert d["counts"]["files"] == 3 and d["patched"] == 2 and d["not_patched_yet"] == 0
    failed = runner.invoke(app, ["status", "kitchen", "--failed"]).output.splitlines()
    assert failed[0] == "kitchen: 0 failed, 1 quarantined"
    assert len(failed) == 2 and str(notes) in failed[1] and "quarantined" in failed[1]
    text = " ".join(runner.invoke(app, ["status", "kitchen"]).output.split())
    assert "files 3: patched 2, quarantined 1" in text
    assert "kitchen: 2 of 3 patched, 1 quarantined (`ppd status kitchen --failed`)" in text


def test_an_out_dataset_says_where_its_copies_are_and_restore_says_it_removed_them(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot, out = tmp_path / "castle", tmp_path / "pub"
    for i in range(3):
        make_image(shoot / f"view{i}.png", i)
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(out)]).exit_code == 0
    status = " ".join(runner.invoke(app, ["status", "castle"]).output.split())
    assert f"patched copies in {out / 'castle'}" in status

    restored = runner.invoke(app, ["restore", "castle"])
    assert restored.exit_code == 0, restored.output
    lines = restored.output.splitlines()
    assert lines[0] == "restored 0, removed 3, unchanged 0, failed 0"
    said = f"removed 3 patched copies from {out / 'castle'} (--out copies: no original goes there)"
    assert lines[1] == said
    assert not list((out / "castle").glob("*.png")) and len(list(shoot.glob("*.png"))) == 3


def test_warnings_name_their_file_unpadded_and_v_says_the_corner_once(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "garden"
    for i in range(3):
        make_image(shoot / f"view{i}.jpg", i)
    (shoot / "broken.jpg").write_text("not a photo at all")
    # a corner design: its corner is chosen once per dataset (the default is placed per photo)
    result = runner.invoke(app, ["-v", "poison", str(shoot), "--design", "watermark"])
    warnings = [x for x in result.output.splitlines() if "corner choice" in x]
    assert warnings, result.output
    assert all(x.startswith("ppd: warning: broken.jpg: unreadable") for x in warnings), result.output
    assert all(x == x.rstrip() for x in warnings)  # not padded to the terminal's width
    assert sum("garden: mark in the" in x for x in result.output.splitlines()) == 1, result.output
