"""Photos under names ppd does not patch (hidden files, files in hidden folders, `.bak`, `~`, `.part`):
the daemon leaves them, but a sync publishes them, so `ppd status` counts and names them, `--check`
fails on them and `ppd poison` says what they are (a black-box review, F4: five full-size JPEGs sat
unmarked in the outbox, status never counted them and poison called three of them "not a supported
image or video"). A photo named `#name` is patched by all three (the daemon left it, the others did not).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from daemon.watch.outbox import is_candidate
from poisoner.media import MEDIA_SUFFIXES
from testkit.photos import make_image, make_shoot

runner = CliRunner()

# names the daemon never patches, each a whole JPEG
HIDDEN = [".IMG_0017.jpg", "IMG_0019.jpg.bak", "IMG_0023.jpg~", "IMG_0024.part"]
LINE = ("4 photo(s) or video(s) under names ppd does not patch (hidden, backup or partial), NOT protected: "
        ".IMG_0017.jpg, IMG_0019.jpg.bak, IMG_0023.jpg~, IMG_0024.part")  # fmt: skip


def _said(*args: str) -> tuple[int, str]:
    result = runner.invoke(app, list(args), env={"COLUMNS": "300"})
    return result.exit_code, " ".join(result.output.split())


def _jpeg(path: Path, seed: int) -> Path:
    """A whole JPEG under any name (make_image's format follows the suffix)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as src:
        shutil.copyfile(make_image(Path(src) / "s.jpg", seed), path)
    return path


def _nest(outbox: Path) -> Path:
    """A dataset of the outbox, patched, then photos put in under names ppd does not patch."""
    nest = make_shoot(outbox / "nest", 2)
    assert runner.invoke(app, ["poison", str(nest)]).exit_code == 0
    for i, name in enumerate(HIDDEN):
        _jpeg(nest / name, 10 + i)
    (nest / "notes.txt.bak").write_text("a note, not a photo")  # no photo: never counted
    (nest / "._v0.jpg").write_bytes(b"\x00\x05\x16\x07" + b"\x00" * 60)  # macOS's resource fork: no photo
    (nest / ".ppd-tmp-L0123456789ab.jpg").write_bytes((nest / HIDDEN[0]).read_bytes())  # ppd's temporary
    return nest


def test_status_counts_and_names_photos_under_names_ppd_does_not_patch(ppd_env: dict[str, Path]) -> None:
    nest = _nest(ppd_env["outbox"])
    code, text = _said("status", "nest")
    assert code == 0, text
    assert f"nest: {LINE}" in text, text
    assert "rename them or move them out of the outbox" in text, text
    named = text.split("names ppd does not patch")[1].split("nest:")[0]
    assert "notes.txt.bak" not in named and "._v0.jpg" not in named and "ppd-tmp" not in named, text
    code, text = _said("status", "--check")
    assert code == 1 and "4 under names ppd does not patch" in text, text  # before: only "not verified"
    data = json.loads(runner.invoke(app, ["status", "nest", "--json"]).output)["datasets"][0]
    assert sorted(Path(p).name for p in data["unpatched_names"]) == sorted(HIDDEN)
    assert data["counts"]["unpatched_names"] == 4 and data["counts"]["files"] == 2
    for i, name in enumerate(HIDDEN):  # renamed to real names: the line goes (they are "not patched yet")
        (nest / name).rename(nest / f"renamed-{i}.jpg")
    assert "names ppd does not patch" not in _said("status", "nest")[1]


def test_a_hidden_folder_in_the_outbox_is_counted(ppd_env: dict[str, Path]) -> None:
    """`.album/x.jpg` right in the outbox: in no dataset, never named by status (the review's repro)."""
    outbox = ppd_env["outbox"]
    _jpeg(outbox / ".album" / "x.jpg", 3)
    make_image(outbox / ".album" / "deeper" / "y.png", 4)
    (outbox / ".album" / "x.xmp").write_text("<x/>")
    code, text = _said("status")
    assert "outbox: 2 photo(s) or video(s) under names ppd does not patch" in text, text
    assert "x.jpg" in text and "y.png" in text and "x.xmp" not in text, text
    code, text = _said("status", "--check")
    assert code == 1 and "outbox: 2 photo(s) or video(s) under names ppd does not patch" in text, text
    listed = json.loads(runner.invoke(app, ["status", "--json"]).output)
    assert sorted(Path(p).name for p in listed["outbox_unpatched_names"]) == ["x.jpg", "y.png"]
    assert listed["ready_to_publish"] is False


def test_poison_names_them_instead_of_calling_them_unsupported(ppd_env: dict[str, Path]) -> None:
    nest = _nest(ppd_env["outbox"])
    result = runner.invoke(app, ["-v", "poison", str(nest)], env={"COLUMNS": "300"})
    text = " ".join(result.output.split())
    assert "notes.txt.bak (not a supported image or video)" in text, text  # a note: as before
    assert "not a supported image or video" not in text.replace("notes.txt.bak (not a", ""), text
    assert "IMG_0024.part (a name ppd does not patch: partial/temporary file (.part), a photo by its " \
           "content)" in text, text  # fmt: skip
    assert LINE in text, text
    assert result.exit_code == 1, text  # in place: not protected, as a photo of a format ppd cannot patch
    assert all((nest / n).read_bytes()[:2] == b"\xff\xd8" for n in HIDDEN)  # untouched
    # named on the command line, alone: skipped in silence, exit 0 (a diff review)
    alone = runner.invoke(app, ["poison", str(nest / ".IMG_0017.jpg")], env={"COLUMNS": "300"})
    text = " ".join(alone.output.split())
    assert alone.exit_code == 1 and "1 photo(s) or video(s) under names ppd does not patch" in text, text


def test_a_photo_named_with_a_hash_is_patched_by_the_daemon_too(ppd_env: dict[str, Path]) -> None:
    """The daemon left `#IMG_0022.jpg` as an editor's file while status counted it "not patched yet" and
    `ppd poison` patched it; Emacs's `#name#` stays an editor's file for all three."""
    outbox = ppd_env["outbox"]
    assert is_candidate(outbox, outbox / "nest" / "#IMG_0022.jpg", MEDIA_SUFFIXES)  # before: False
    assert not is_candidate(outbox, outbox / "nest" / "#IMG_0022.jpg#", MEDIA_SUFFIXES)
    nest = make_shoot(outbox / "nest", 1)
    _jpeg(nest / "#IMG_0022.jpg", 5)
    _jpeg(nest / "#IMG_0023.jpg#", 6)
    assert runner.invoke(app, ["poison", str(nest)]).exit_code == 1  # the `#...#` one is named, not patched
    code, text = _said("status", "nest")
    assert "files 2: patched 2" in text, text
    assert "1 photo(s) or video(s) under names ppd does not patch" in text and "#IMG_0023.jpg#" in text


def test_the_walk_of_hidden_folders_stops_at_its_budget(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A `.git` or a cache of hundreds of thousands of files was walked whole on every `ppd status`
    (a diff review: 0.6 s warm, 2.3 s cold for 400 000). Past HIDDEN_WALK_BUDGET entries no hidden folder
    is entered (what was found is a lower bound); ordinary folders are still walked."""
    from daemon.datasets import unpatched_names

    monkeypatch.setattr(unpatched_names, "HIDDEN_WALK_BUDGET", 50)
    shoot = tmp_path / "shoot"
    first = _jpeg(shoot / ".album" / "x.jpg", 1)  # walked first (sorted): found
    for i in range(120):
        (shoot / ".git" / "objects" / f"{i:03d}").parent.mkdir(parents=True, exist_ok=True)
        (shoot / ".git" / "objects" / f"{i:03d}").write_bytes(b"blob")
    late = _jpeg(shoot / ".git" / "zz" / "late.jpg", 2)  # past the budget: not looked at
    ordinary = _jpeg(shoot / "day2" / ".y.jpg", 3)  # a hidden name in an ordinary folder, after it
    found = unpatched_names.unpatched_media(shoot)
    assert first in found and ordinary in found and late not in found, found
    monkeypatch.setattr(unpatched_names, "HIDDEN_WALK_BUDGET", 10_000)
    assert late in unpatched_names.unpatched_media(shoot)  # within the budget it is found
