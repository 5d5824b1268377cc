"""`ppd restore FILE` on ppd's output that the user moved out of its dataset's folder: the file is
found by its seal and its original comes back there, every time. A black-box review: the first such
restore made a dataset of the new folder rooted in the outbox, and the second took the next moved
photo for an --out copy and deleted it. A copy of an --out copy still gets no original."""

from __future__ import annotations

import hashlib
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_image

runner = CliRunner()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_photos_moved_out_of_their_folder_get_their_originals_back(ppd_env: dict[str, Path],
                                                                 tmp_path: Path) -> None:  # fmt: skip
    shoot, desk = tmp_path / "shoot", tmp_path / "desk"
    originals = {i: _sha(make_image(shoot / f"v{i}.png", i)) for i in range(3)}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    make_image(desk / "unrelated.png", 9)  # a photo of the user's own in the folder they moved to
    for i in (1, 2):
        (shoot / f"v{i}.png").rename(desk / f"moved{i}.png")
    for i in (1, 2):
        result = runner.invoke(app, ["restore", str(desk / f"moved{i}.png")])
        assert result.exit_code == 0 and "restored 1" in result.output, result.output
        assert _sha(desk / f"moved{i}.png") == originals[i]  # there, and the original's bytes
    # no dataset was made of desk (its own photo was listed "not patched yet": a diff review)
    assert "desk" not in runner.invoke(app, ["status"]).output


def test_a_copy_of_an_out_copy_gets_no_original(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot, pub, desk = tmp_path / "shoot", tmp_path / "pub", tmp_path / "desk"
    make_image(shoot / "v0.png", 0)
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(pub)]).exit_code == 0
    (copy,) = pub.rglob("v0.png")
    desk.mkdir()
    moved = desk / "v0.png"
    moved.write_bytes(copy.read_bytes())
    result = runner.invoke(app, ["restore", str(moved)])
    text = " ".join(result.output.split())
    assert result.exit_code == 1 and "gets no original" in text, text
    assert "removes the dataset's copies" in text, text
    assert moved.read_bytes() == copy.read_bytes()  # left as it was, not deleted


def test_a_restore_killed_midway_is_finished_by_the_next_one(ppd_env: dict[str, Path],
                                                            tmp_path: Path) -> None:  # fmt: skip
    """What `kill -9` of `ppd restore` leaves (a black-box review, strace-injected): before the rename,
    a hidden copy of the original beside the photos, which the next restore left there (only
    `ppd poison` swept it); after the rename, the original in place with its row still 'patched',
    which the next restore refused as 'changed since ppd patched it'."""
    shoot = tmp_path / "shoot"
    originals = {i: make_image(shoot / f"v{i}.png", i).read_bytes() for i in range(2)}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    leftover = shoot / ".ppd-tmp-L0123456789ab.png"  # a temporary born locked, its writer gone
    leftover.write_bytes(originals[0])
    (shoot / "v1.png").write_bytes(originals[1])  # renamed into place, the store not told
    result = runner.invoke(app, ["restore", str(shoot)])
    assert result.exit_code == 0 and "restored 2" in result.output, result.output
    assert sorted(p.name for p in shoot.iterdir()) == ["v0.png", "v1.png"]
    assert all((shoot / f"v{i}.png").read_bytes() == originals[i] for i in range(2))


def test_a_patched_photo_copied_into_another_dataset_is_one_of_its_patched_files(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: status said "1 not patched yet: run `ppd poison`", and ppd poison said
    "unchanged (already ppd output)", round and round. The copy is now recorded in the folder's
    dataset (its original the same vault copy), so the two agree, and restore gives its original."""
    import json

    a, b = tmp_path / "a", tmp_path / "b"
    original = make_image(a / "v0.png", 0).read_bytes()
    make_image(b / "w0.png", 1)
    assert runner.invoke(app, ["poison", str(a)]).exit_code == 0
    assert runner.invoke(app, ["poison", str(b)]).exit_code == 0
    (b / "copied.png").write_bytes((a / "v0.png").read_bytes())
    again = runner.invoke(app, ["poison", str(b)])
    assert again.exit_code == 0 and "unchanged 2" in " ".join(again.output.split()), again.output
    (d,) = json.loads(runner.invoke(app, ["status", "b", "--json"]).output)["datasets"]
    assert d["not_patched_yet"] == 0 and d["patched"] == 2, d["counts"]
    assert runner.invoke(app, ["restore", str(b / "copied.png")]).exit_code == 0
    assert (b / "copied.png").read_bytes() == original


def test_a_photo_renamed_in_its_folder_and_restored_is_left_unpatched(ppd_env: dict[str, Path],
                                                                      tmp_path: Path) -> None:  # fmt: skip
    """A black-box review (F5a): after `mv A/0000.jpg A/r.jpg; ppd restore A/r.jpg`, `ppd poison A`
    patched r.jpg again (the restore by seal recorded nothing), and the store still listed 0000.jpg as
    patched, so `ppd restore A` brought it back beside r.jpg. The restore is now recorded under the new
    name and the old name's row as moved away."""
    shoot = tmp_path / "shoot"
    originals = {i: _sha(make_image(shoot / f"v{i}.png", i)) for i in range(3)}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    (shoot / "v0.png").rename(shoot / "r.png")
    result = runner.invoke(app, ["restore", str(shoot / "r.png")])
    assert result.exit_code == 0 and "restored 1" in result.output, result.output
    assert _sha(shoot / "r.png") == originals[0]
    dry = runner.invoke(app, ["poison", str(shoot), "--dry-run"])
    text = " ".join(dry.output.split())
    assert "would patch 0" in text and "left unprotected (restored by you): 1" in text, text
    assert runner.invoke(app, ["restore", str(shoot)]).exit_code == 0
    assert sorted(p.name for p in shoot.iterdir()) == ["r.png", "v1.png", "v2.png"]  # v0.png not made again


def test_a_rename_takes_its_own_row_when_another_shoot_holds_the_same_photo(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: the same photos in two shoots patch to the same bytes. With the first shoot's
    folder moved, a rename in the second was recorded as the first shoot's file moved over; its own row
    stayed "gone since patched", and `ppd restore` offered `ppd restore FILE` to bring back a duplicate."""
    first, second = tmp_path / "first", tmp_path / "second"
    for i in range(3):
        make_image(first / f"v{i}.png", i)
        make_image(second / f"v{i}.png", i)
    assert runner.invoke(app, ["poison", str(first)]).exit_code == 0  # its rows come first
    assert runner.invoke(app, ["poison", str(second)]).exit_code == 0
    assert _sha(first / "v1.png") == _sha(second / "v1.png")  # the case: one output, two rows
    first.rename(tmp_path / "first moved")
    (second / "v1.png").rename(second / "hero.png")
    recorded = runner.invoke(app, ["-v", "poison", str(second)])
    said = " ".join(recorded.output.split())
    assert f"moved from {second / 'v1.png'}" in said, said  # before: moved from .../first/v1.png
    restored = runner.invoke(app, ["restore", "second"])
    said = " ".join(restored.output.split())
    assert restored.exit_code == 0 and "restored 3" in said and "gone since patched" not in said, said
    assert sorted(p.name for p in second.iterdir()) == ["hero.png", "v0.png", "v2.png"]


def test_a_dataset_renamed_into_another_says_where_its_files_are(ppd_env: dict[str, Path],
                                                                 tmp_path: Path) -> None:  # fmt: skip
    """`ppd restore mv1` after its folder was renamed mv1-renamed and taken as that dataset said "restored
    0, ..., failed 0", exit 0, its files still patched (a black-box review, F11): status's words, exit 2."""
    old, new = tmp_path / "mv1", tmp_path / "mv1-renamed"
    for i in range(3):
        make_image(old / f"v{i}.png", i)
    assert runner.invoke(app, ["poison", str(old)]).exit_code == 0
    old.rename(new)
    assert runner.invoke(app, ["poison", str(new)]).exit_code == 0  # its rows carried to mv1-renamed
    result = runner.invoke(app, ["restore", "mv1"])
    lines = result.output.splitlines()
    assert result.exit_code == 2 and len(lines) == 1, result.output
    said = f"its folder {old} is gone; its patched files are in {new}, now dataset 'mv1-renamed'"
    assert lines[0] == f"ppd: error: dataset 'mv1': {said}: `ppd restore mv1-renamed` restores them", lines
    assert runner.invoke(app, ["restore", "mv1-renamed"]).output.startswith("restored 3,")


def test_the_moved_note_goes_once_the_files_are_restored(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A black-box review (F15): after the renamed folder's files were restored, status still said of the
    old dataset "its patched files are in ..., now dataset ...". It is said while one of them is patched
    there, and goes once they are all restored: by the new dataset's name, or by the folder (found by
    their seals, no rows carried)."""
    old, new = tmp_path / "mv2", tmp_path / "mv2-renamed"
    for i in range(3):
        make_image(old / f"v{i}.png", i)
    assert runner.invoke(app, ["poison", str(old)]).exit_code == 0
    old.rename(new)
    assert runner.invoke(app, ["poison", str(new)]).exit_code == 0  # its rows carried to mv2-renamed
    note = f"its patched files are in {new}, now dataset 'mv2-renamed'"
    assert note in " ".join(runner.invoke(app, ["status", "mv2"]).output.split())
    assert runner.invoke(app, ["restore", str(new / "v0.png")]).exit_code == 0  # one of them: still so
    assert note in " ".join(runner.invoke(app, ["status"]).output.split())

    assert runner.invoke(app, ["restore", "mv2-renamed"]).exit_code == 0
    for args in (["status"], ["status", "mv2"]):
        said = " ".join(runner.invoke(app, args).output.split())
        assert "its patched files are in" not in said and "folder gone;" not in said, said  # before: the note
    result = runner.invoke(app, ["restore", "mv2"])  # before: exit 2, "`ppd restore mv2-renamed` ..."
    assert result.exit_code == 0 and result.output.startswith("restored 0,"), result.output

    third, moved = tmp_path / "mv3", tmp_path / "mv3-renamed"  # no run in the new folder: rows not carried
    for i in range(2):
        make_image(third / f"v{i}.png", 10 + i)
    assert runner.invoke(app, ["poison", str(third)]).exit_code == 0
    third.rename(moved)
    said = " ".join(runner.invoke(app, ["status"]).output.split())
    assert f"its patched files are in {moved} (moved?)" in said, said
    assert runner.invoke(app, ["restore", str(moved)]).exit_code == 0  # found by their seals
    said = " ".join(runner.invoke(app, ["status", "mv3"]).output.split())
    assert "its patched files are in" not in said, said
