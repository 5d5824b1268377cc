"""`ppd status` counts only a dataset's own files (defect 4): a file another dataset owns (its row,
or its folder nested inside this one's; in the outbox, a first-level subfolder) is never "not
patched yet" here, so the resume line never names a `ppd poison` that does nothing. And a dataset
whose files changed after its verification says so, never "verified: never" (defect 7, issue 25).
Real `ppd` commands (CliRunner), the real store, real files."""

from __future__ import annotations

import json
import time
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from daemon.context import AppContext
from daemon.datasets.folder_count import count_folder, owned_elsewhere
from testkit.photos import make_image

runner = CliRunner()


def ppd(*args: str) -> str:
    result = runner.invoke(app, list(args))
    assert result.exit_code == 0, result.output
    return result.output


def status_of(name: str) -> dict:
    (d,) = json.loads(ppd("status", name, "--json"))["datasets"]
    return d


def flat(text: str) -> str:
    return " ".join(text.split())


def test_a_nested_datasets_files_are_not_the_parents(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    nest = tmp_path / "photos" / "nest"  # not in ppd_env's data folder: no photos there
    make_image(nest / "a.png", 5)
    make_image(nest / "inner" / "r_6.png", 6)
    make_image(nest / "inner" / "r_2.png", 2)
    ppd("poison", str(nest / "inner"))
    ppd("poison", str(nest / "a.png"))

    d = status_of("nest")
    assert d["counts"]["files"] == 1 and d["patched"] == 1, d["counts"]
    assert d["not_patched_yet"] == 0 and d["resume"] is None and d["folder"]["on_disk"] == 1
    text = flat(ppd("status", "nest", "-l"))
    assert "not patched yet" not in text and "ppd poison" not in text, text
    assert "files 1: patched 1" in text
    # the command status would have named does nothing: every file is already patched
    dry = flat(ppd("poison", str(nest), "--dry-run"))
    assert "would patch 0" in dry, dry

    # an interrupted run of the inner dataset is the inner dataset's to finish, not nest's
    make_image(nest / "inner" / "r_9.png", 9)
    inner = status_of("inner")
    assert inner["not_patched_yet"] == 1 and inner["resume"] is not None
    assert str(nest / "inner") in inner["resume"]
    d = status_of("nest")
    assert d["not_patched_yet"] == 0 and d["resume"] is None, d["counts"]


def test_a_file_another_datasets_row_names_is_not_counted(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    nest = tmp_path / "nest"
    make_image(nest / "a.png", 1)
    make_image(nest / "b.png", 2)
    ppd("poison", str(nest / "a.png"))
    ppd("poison", str(nest / "b.png"), "--dataset", "other")  # same folder, another dataset's row
    d = status_of("nest")
    assert d["counts"]["files"] == 1 and d["not_patched_yet"] == 0 and d["resume"] is None, d["counts"]
    assert status_of("other")["counts"]["files"] == 1


def test_the_outbox_default_leaves_out_its_subfolders_datasets(ppd_env: dict[str, Path]) -> None:
    outbox = ppd_env["outbox"]
    make_image(outbox / "loose.png", 1)
    for i in range(2):
        make_image(outbox / "shoot1" / f"view{i}.png", 10 + i)
    ppd("poison", str(outbox / "shoot1"))
    ppd("poison", str(outbox / "loose.png"))
    ppd("restore", str(outbox / "shoot1" / "view0.png"))  # restored on purpose: still shoot1's
    make_image(outbox / "shoot2" / "new.png", 20)  # a subfolder the daemon has not reached yet

    d = status_of("default")
    assert d["counts"]["files"] == 1 and d["patched"] == 1, d["counts"]
    assert d["not_patched_yet"] == 0 and d["resume"] is None
    assert "not patched yet" not in flat(ppd("status", "default", "-l"))


def test_count_folder_leaves_out_what_others_own(tmp_path: Path) -> None:
    folder = tmp_path / "set"
    for name in ("a.png", "b.png", "inner/c.png", "inner/d.png", "masks/m.png"):
        make_image(folder / name, len(name))
    rows = [{"path": str(folder / "a.png"), "state": "protected"}]
    roots = [folder, folder / "inner", tmp_path]  # itself, one nested, one holding it: only the nested
    skip, foreign = owned_elsewhere(folder, roots, [str(folder / "b.png")])
    assert skip == [folder / "inner"] and foreign == {str(folder / "b.png")}
    count = count_folder(folder, rows, skip=[*skip, folder / "masks"], foreign=foreign)
    assert count.on_disk == 1 and count.untracked == []
    assert count_folder(folder, rows, skip=[folder / "masks"]).on_disk == 4  # without: all of them
    # the outbox's loose files: each first-level subfolder is a dataset of its own; a folder above skips it
    assert owned_elsewhere(folder, [], [], outbox=folder)[0] == [folder / "inner", folder / "masks"]
    assert owned_elsewhere(tmp_path, [], [], outbox=folder)[0] == [folder]


def test_status_after_the_files_changed_says_when_it_was_verified(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    lego = tmp_path / "lego8"
    for i in range(3):
        make_image(lego / f"r_{i}.png", i)
    ppd("poison", str(lego))
    assert "verified: never" in ppd("status", "lego8", "-l")
    ctx = AppContext.open()
    try:
        now = time.time()
        ctx.store.add_verification_run("lego8", "default", "inconclusive", {}, now, now + 1, None, None)
    finally:
        ctx.close()
    shown = flat(ppd("status", "lego8", "-l"))
    assert "default: could not be verified" in shown and "never" not in shown, shown

    time.sleep(0.01)
    (lego / "r_2.png").unlink()
    ppd("restore", str(lego / "r_2.png"))
    d = status_of("lego8")
    assert d["verdicts"] == {} and d["last_verification"]["verdict"] == "inconclusive"
    text = flat(ppd("status", "lego8", "-l"))
    assert "never" not in text, text
    assert "not verified since the files changed (last verification:" in text, text
    assert "default: could not be verified" in text, text
