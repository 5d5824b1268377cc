"""`ppd status` says what is true of a dataset's files (black-box reviews, F8, S3, N8, N9, N11, N12):
a re-protect's failures stay listed, a moved folder or a renamed file is not called deleted or
unpatched, a headline leads with its failures, and identical advice is one line."""

from __future__ import annotations

import json
import os
import shlex
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_shoot

runner = CliRunner()


def said(*args: str) -> str:
    """The command's output, its lines joined as one (the terminal's wrapping undone)."""
    return " ".join(runner.invoke(app, list(args)).output.split())


def status_json(name: str) -> dict:
    result = runner.invoke(app, ["status", name, "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)["datasets"][0]


def test_a_reprotect_failure_stays_listed_until_fixed(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """F8/S3: `dataset set --reprotect` printed each failure and exited 1, then `status --failed` said
    "0 failed": nothing kept it. A file that still carries the earlier spec's mark is not called failed."""
    from daemon.context import AppContext

    shoot = make_shoot(tmp_path / "A", 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    old_spec = status_json("A")["spec_id"]
    edited = shoot / "v0.png"
    Image.open(edited).crop((0, 0, 150, 110)).save(edited)  # edited since patched: refused
    ctx = AppContext.open()
    try:  # v1's vault copy damaged: refused, v1 untouched, still ppd's output under the old spec
        blob = ctx.vault.path_for(ctx.store.file(shoot / "v1.png")["original_sha256"])
    finally:
        ctx.close()
    os.chmod(blob, 0o644)
    blob.write_bytes(b"not the original")
    result = runner.invoke(app, ["dataset", "set", "A", "--patch-size", "8%", "--reprotect"])
    assert result.exit_code == 1, result.output
    failed = said("status", "A", "--failed")
    assert "A: 0 failed, 0 quarantined, 2 not re-protected" in failed, failed
    assert (f"{edited}: changed since ppd patched it, maybe NOT protected; not re-protected to spec "
            in failed and "changed since ppd protected it" in failed), failed  # fmt: skip
    kept = f"{shoot / 'v1.png'}: still carries the earlier spec's mark (spec {old_spec}); not re-protected to"
    assert kept in failed and "vault copy of v1.png is missing or corrupt" in failed, failed
    assert "v2.png" not in failed
    assert "A: 2 not re-protected (`ppd status A --failed`)" in said("status", "A")
    assert status_json("A")["not_reprotected"] == 2
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0  # patches the edited file again
    again = said("status", "A", "--failed")
    assert "1 not re-protected" in again and "v0.png" not in again and "v1.png" in again, again


def test_a_moved_folder_is_not_said_to_hold_no_file(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """N8: a deleted folder and a renamed one were both "whose folder is gone and that hold no file
    now", and --json could not tell them apart; the renamed one's patched files sat beside it."""
    sets = tmp_path / "sets"
    for name in ("set 5", "set 6", "set 7"):
        assert runner.invoke(app, ["poison", str(make_shoot(sets / name, 2))]).exit_code == 0
    for f in (sets / "set 5").iterdir():
        f.unlink()
    (sets / "set 5").rmdir()
    moved = sets / "set 6 moved"
    (sets / "set 6").rename(moved)
    text = said("status")
    assert "hold no file" not in text, text
    assert "not shown: 2 dataset(s) whose folder is gone, moved or deleted (set 5, set 6)" in text, text
    assert (f"set 6: folder gone; its patched files are in {moved} (moved?): `ppd dataset set 'set 6' --root "
            f"'{moved}'` moves the dataset there") in text, text  # fmt: skip
    assert "set 5: folder gone" not in text
    report = json.loads(runner.invoke(app, ["status", "--json"]).stdout)["datasets"]
    folders = {d["name"]: d["folder"] for d in report}
    assert folders["set 6"]["exists"] is False and folders["set 6"]["moved_to"] == str(moved)
    assert folders["set 5"]["exists"] is False and folders["set 5"]["moved_to"] is None
    assert folders["set 7"]["moved_to"] is None
    assert ("moved or deleted? `ppd dataset set 'set 5' --root NEWFOLDER` follows it to where you moved it; "
            "`ppd dataset forget 'set 5'` forgets a deleted one") in said("status", "set 5")  # fmt: skip
    # the promised command: the dataset moves there, its files recognised, not patched twice
    assert runner.invoke(app, ["dataset", "set", "set 6", "--root", str(moved)]).exit_code == 0
    adopted = said("poison", str(moved))
    assert "patched 0, unchanged 2" in adopted and "set 6 moved" not in said("status"), adopted


def test_a_renamed_patched_file_is_patched_and_the_parts_add_up(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """N9: a patched photo renamed was "1 not patched yet: run `ppd poison`", and poison then found
    nothing to do; after a deletion too, "files 3: deleted or moved away since patched 1, removed 1,
    restored 3" added up to 5."""
    shoot = make_shoot(tmp_path / "A", 4)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    (shoot / "v0.png").rename(shoot / "hero.png")
    text = said("status", "A")
    assert "not patched yet" not in text and "files 4: patched 4 (1 renamed since)" in text, text
    command = f"ppd poison {shlex.quote(str(shoot))}"
    assert f"A: 1 patched file(s) renamed since, still carrying the mark: `{command}`" in text
    counts = status_json("A")["counts"]
    assert counts["patched"] == 4 and counts["renamed"] == 1 and counts["untracked"] == 0, counts
    assert status_json("A")["resume"] is None
    (shoot / "v1.png").unlink()
    text = said("status", "A")
    assert "files 3: patched 3 (1 renamed since); not counted: deleted or moved away since patched 1" in text
    assert "patched 0, unchanged 3" in said("poison", str(shoot))  # as status said: nothing to patch
    assert "renamed since" not in said("status", "A")  # the new name recorded
    assert runner.invoke(app, ["restore", str(shoot)]).exit_code == 0
    text = said("status", "A")
    assert ("files 3: restored 3; not counted: deleted or moved away earlier 1, deleted or moved away "
            "since patched 1") in text, text  # fmt: skip


def test_a_headline_leads_with_the_failures(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """N11: 4 of 5 files failed, and the headline was "B: patched, not verified: run `ppd verify B`"
    (the failures a line further down, in ppd status after the verify advice)."""
    shoot = make_shoot(tmp_path / "B", 1)
    for i in range(4):
        (shoot / f"bad{i}.png").write_text("not a photo")
    poisoned = runner.invoke(app, ["poison", str(shoot)])
    assert poisoned.exit_code == 1
    lines = [line for line in poisoned.stdout.splitlines() if line.startswith("B: ") and "placed" not in line]
    headline = "B: 1 of 5 patched, 4 failed (`ppd status B --failed`); not verified: run `ppd verify B`"
    assert lines == [headline], poisoned.stdout
    assert "failed files and reasons" not in poisoned.stdout  # the headline says where
    text = said("status")
    assert "B: 1 of 5 patched, 4 failed (`ppd status B --failed`) B: run `ppd verify B`" in text, text
    nothing = tmp_path / "C"
    nothing.mkdir()
    (nothing / "a.png").write_text("not a photo")
    none = runner.invoke(app, ["poison", str(nothing)])
    assert "C: 0 of 1 patched, 1 failed (`ppd status C --failed`)\n" in none.stdout, none.stdout


def test_shared_advice_is_one_line_after_what_matters(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """N12: with 23 datasets, 23 lines "set N: run `ppd verify 'set N'`" buried "NOT protected" and
    "changed since patched". More than 3 datasets with the same advice share one line, after those."""
    import time

    from daemon.context import AppContext

    for i in range(1, 7):  # set 6 of 2 photos: one changed leaves it patched
        shoot = make_shoot(tmp_path / f"set {i}", 1 + i // 6)
        assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    (tmp_path / "set 6" / "v0.png").write_bytes((tmp_path / "set 6" / "v0.png").read_bytes() + b"!")
    ctx = AppContext.open()
    try:  # set 5 measured NOT protected
        now = time.time() + 1
        ctx.store.add_verification_run("set 5", "default", "not_protected", {}, now, now + 1, None, None)
    finally:
        ctx.close()
    text = said("status")  # one line of words: the terminal's width wraps each line anywhere
    order = [
        "set 5: find a design that holds: `ppd auto 'set 5'`",
        "set 6: 1 changed since ppd patched them",
        "run `ppd verify NAME` for 5 datasets: set 1, set 2, set 3, set 4, set 6",
    ]
    at = [text.find(step) for step in order]
    assert -1 not in at and at == sorted(at), (at, text)
    assert text.count("run `ppd verify") == 1, text  # the shared advice once, no line of it per dataset
    one = said("status", "set 1")  # one dataset: its own line, as before
    assert "set 1: run `ppd verify 'set 1'`" in one, one


def test_the_table_says_how_many_are_patched_when_some_are_not(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The protection cell said "patched, not verified" of a dataset with 5 of 25 patched (a black-box
    review, F15; a narrow terminal drops the counts' columns and keeps only that cell)."""
    shoot = make_shoot(tmp_path / "kp", 2)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    text = said("status")
    assert "patched, not verified" in text and "2 of 2 patched" not in text, text  # all patched: as before
    make_shoot(tmp_path / "more", 4)
    for photo in (tmp_path / "more").iterdir():
        photo.rename(shoot / f"n{photo.name}")
    text = said("status")  # the cell may wrap inside the table at a narrow width: its first words
    assert "2 of 6 patched" in text.split("kp: patched 2 of 6")[0], text


def test_a_reprotect_says_which_files_it_did_not_reach(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd dataset set NAME ... --reprotect` said only "patched again A: patched 2" of a dataset with a
    photo added since and one restored: the user took the whole dataset for one carrying the new spec (a
    black-box review). One line says how many it did not reach, why, and what patches them; and that
    command does patch them with the new spec."""
    import shlex

    from daemon.paths import AppPaths
    from daemon.store import Store
    from testkit.photos import make_image

    shoot = make_shoot(tmp_path / "A", 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["restore", str(shoot / "v0.png")]).exit_code == 0
    make_image(shoot / "late.png", 7)  # put in since: no row
    text = said("dataset", "set", "A", "--patch-size", "8%", "--reprotect")
    command = shlex.join(["ppd", "poison", str(shoot)])
    assert "patched again A: patched 2" in text, text
    assert ("A: 2 of its files not re-protected, as they carry no mark of ppd's: 1 not patched yet "
            f"(`{command}` patches them with the new spec); 1 restored by you (`{command} --force` "
            "patches them with the new spec)") in text, text  # fmt: skip
    new_spec = status_json("A")["spec_id"]
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["poison", str(shoot), "--force"]).exit_code == 0
    store = Store(AppPaths.from_env().db_path)
    try:
        for photo in ("late.png", "v0.png"):
            row = store.file(shoot / photo)
            assert row["state"] == "patched" and row["spec_id"] == new_spec, row
    finally:
        store.close()
    again = said("dataset", "set", "A", "--patch-size", "7%", "--reprotect")
    assert "patched again A: patched 4" in again and "not re-protected" not in again, again


def test_a_reprotect_no_file_took_names_the_spec_kept(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A re-protect on which every file failed keeps the dataset's earlier spec, but its last line
    named the new spec's id as the dataset's (a helper's review)."""
    shoot = make_shoot(tmp_path / "A", 2)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    before = status_json("A")["spec_id"]
    for photo in shoot.iterdir():  # each changed since ppd wrote it: refused, its earlier mark kept
        photo.write_bytes(photo.read_bytes() + b"edited")
    result = runner.invoke(app, ["dataset", "set", "A", "--patch-size", "8%", "--reprotect"])
    text = " ".join(result.output.split())
    assert result.exit_code == 1 and status_json("A")["spec_id"] == before, text
    assert f"A: spec still {before} (" in text and "no file took the new spec" in text, text
    assert f"A: spec {before}" not in text, text
    assert "v0.png changed since ppd protected it; not re-protecting it" in text, text


def test_a_reprotect_records_a_deleted_photo_gone(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A patched photo deleted before a re-protect (no daemon running to see it go) failed the
    re-protect, every time, and status then held the dataset "patched with another spec" for it, its
    advice a re-protect that failed again (a black-box review). It is recorded gone, as the daemon
    records it; a renamed photo is not taken for a deleted one."""
    shoot = make_shoot(tmp_path / "A", 4)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    (shoot / "v3.png").unlink()
    (shoot / "v2.png").rename(shoot / "renamed.png")  # still ppd's output, under the earlier spec
    result = runner.invoke(app, ["dataset", "set", "A", "--patch-size", "8%", "--reprotect"])
    text = " ".join(result.output.split())
    assert "patched again A: failed 1, patched 2" in text, text
    gone = "A: 1 deleted or moved away since ppd patched them: recorded so, nothing to re-protect"
    assert gone in text, text
    assert "v3.png" not in text and "v2.png was renamed renamed.png since ppd patched it" in text, text
    assert f"`{shlex.join(['ppd', 'poison', str(shoot)])}` records the new name" in text, text
    assert result.exit_code == 1, text
    state = status_json("A")
    assert state["other_spec"] == 1 and state["not_reprotected"] == 1, state  # the renamed one only
    (shoot / "renamed.png").unlink()
    again = runner.invoke(app, ["dataset", "set", "A", "--patch-size", "7%", "--reprotect"])
    text = " ".join(again.output.split())
    assert again.exit_code == 0 and "patched again A: patched 2" in text, text
    state = status_json("A")
    assert state["other_spec"] == 0 and state["not_reprotected"] == 0, state
    check = runner.invoke(app, ["status", "A", "--check"])
    assert "another spec" not in " ".join(check.output.split()), check.output


def test_a_reprotect_with_the_out_copies_drive_gone_records_nothing_gone(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`--out` copies on a drive unplugged during a re-protect are not deleted photos: they failed, as
    before, their rows kept, and the dataset keeps the spec they carry (a diff review)."""
    shoot, out = make_shoot(tmp_path / "A", 2), tmp_path / "usb"
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(out)]).exit_code == 0
    before = status_json("A")["spec_id"]
    (out / "A").rename(tmp_path / "away")  # the drive unplugged
    result = runner.invoke(app, ["dataset", "set", "A", "--patch-size", "8%", "--reprotect"])
    text = " ".join(result.output.split())
    assert result.exit_code == 1 and "deleted or moved away since ppd patched them" not in text, text
    assert status_json("A")["spec_id"] == before, text
    (tmp_path / "away").rename(out / "A")  # back: still its patched copies
    assert status_json("A")["counts"]["patched"] == 2
