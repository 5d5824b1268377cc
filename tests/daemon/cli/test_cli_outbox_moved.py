"""`ppd status` and `ppd poison` after the outbox moved (PPD_OUTBOX set anew) with no `ppd watch` run
since. An eighth black-box review (F2): status listed every dataset as gone and every patched photo as
"no dataset holds yet, NOT protected", and its advice, `ppd poison OUTBOX`, exited 2 ("dataset 'kitchen'
already belongs to OLD"). Now status names the folders where the datasets' patched files are, with one
command, and `ppd poison` (of the outbox or one folder) moves each dataset there, said once; a dry run
changes nothing. And `ppd dataset forget` keeps the originals of photos an earlier ppd's restore deleted
as `--out` copies (F1): the vault holds their only copy."""

from __future__ import annotations

import hashlib
import json
import shlex
import shutil
from pathlib import Path

import pytest

from daemon.context import AppContext
from daemon.states import FileState
from testkit.cli import said
from testkit.photos import make_image, make_shoot


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _root(name: str) -> str:
    code, text = said("dataset", "show", name, "--json")
    assert code == 0, text
    return str(json.loads(text)["root"])


def test_status_and_poison_follow_an_outbox_moved_while_ppd_was_stopped(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    old, new = tmp_path / "Outbox 1", tmp_path / "disk 2" / "Outbox"
    monkeypatch.setenv("PPD_OUTBOX", str(old))
    for name in ("a", "b", "kitchen"):
        make_shoot(old / name, 2)
    make_image(old / "loose.png", 7)  # the outbox's own dataset, "default"
    originals = {p.name: _sha(p) for p in (old / "a").iterdir()}
    code, text = said("poison", str(old))
    assert code == 0, text
    _a_copy_takes_nothing(old, tmp_path / "copy" / "Outbox", monkeypatch)
    new.parent.mkdir()
    old.rename(new)
    old.mkdir()  # left behind empty: a `ppd watch` still running there makes it again
    monkeypatch.setenv("PPD_OUTBOX", str(new))
    make_image(new / "b" / "fresh.png", 9)  # a new photo: NOT protected, said so as before

    code, text = said("status")
    assert code == 0, text
    assert (f"4 datasets' folders are gone and their patched files are in the outbox {new} (a, b, default, "
            f"kitchen): the outbox moved? `ppd poison {shlex.quote(str(new))}` moves each dataset to its "
            "folder there") in text, text  # fmt: skip
    assert "no dataset holds yet, NOT protected (b/fresh.png)" in text, text  # the new one only
    assert "1 photo(s) or video(s)" in text and "not shown" not in text, text
    code, text = said("status", "kitchen")
    moved = shlex.quote(str(new / "kitchen"))
    assert (f"its patched files are in {new / 'kitchen'} (moved?): `ppd dataset set kitchen --root {moved}` "
            "moves the dataset there") in text, text  # fmt: skip

    code, text = said("poison", str(new), "--dry-run")
    assert code == 0 and "would patch 1, unchanged 7" in text, text
    assert _root("a") == str(old / "a") and "folder moved" not in text  # a dry run changes nothing

    code, text = said("poison", str(new / "kitchen"))  # one folder: its dataset follows it
    assert code == 0 and "patched 0, unchanged 2" in text, text
    assert f"dataset kitchen's folder moved: {old / 'kitchen'} -> {new / 'kitchen'}" in text, text
    code, text = said("poison", str(new))  # the advice, as given
    assert code == 0 and "patched 1, unchanged 7" in text, text
    assert text.count("folder moved") == 3 and "dataset kitchen's" not in text, text
    assert f"dataset default's folder moved: {old} -> {new}" in text, text
    assert _root("b") == str(new / "b")

    code, text = said("status")
    assert "gone" not in text and "NOT protected" not in text, text
    code, text = said("restore", "a")
    assert code == 0 and "restored 2, removed 0" in text, text
    assert {p.name: _sha(p) for p in (new / "a").iterdir()} == originals


def test_restore_by_name_follows_a_dataset_that_moved_with_the_outbox(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`ppd restore kitchen` right after the move (F1's expectation): it said "its folder ... is gone"
    (exit 2); it follows the folder where the outbox's rule puts it now, and restores there."""
    old, new = tmp_path / "Outbox 1", tmp_path / "disk 2" / "Outbox"
    monkeypatch.setenv("PPD_OUTBOX", str(old))
    originals = {p.name: _sha(p) for p in make_shoot(old / "kitchen", 2).iterdir()}
    assert said("poison", str(old / "kitchen"))[0] == 0
    new.parent.mkdir()
    old.rename(new)
    monkeypatch.setenv("PPD_OUTBOX", str(new))
    code, text = said("restore", "kitchen")
    assert code == 0 and "restored 2, removed 0" in text, text
    assert f"dataset kitchen's folder moved: {old / 'kitchen'} -> {new / 'kitchen'}" in text, text
    assert {p.name: _sha(p) for p in (new / "kitchen").iterdir()} == originals


def _a_copy_takes_nothing(old: Path, copy: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The outbox copied (`cp -a`), the old one still there: no dataset follows the copy, whose folders
    are refused as another outbox's, as before."""
    shutil.copytree(old, copy)  # times kept
    monkeypatch.setenv("PPD_OUTBOX", str(copy))
    code, text = said("poison", str(copy / "kitchen"))
    assert code == 2 and "already belongs to" in text and "folder moved" not in text, text
    assert _root("kitchen") == str(old / "kitchen")
    shutil.rmtree(copy)
    monkeypatch.setenv("PPD_OUTBOX", str(old))


def test_forget_keeps_the_originals_of_photos_an_earlier_restore_deleted_as_copies(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A store an earlier ppd left after F1: the photos of a dataset, in its folder, deleted by `ppd
    restore` as `--out` copies (recorded restored, no original put back); forget removed their only
    originals, no word. It refuses now, naming where they are (exit 2); --force forgets all the same."""
    shoot = make_shoot(tmp_path / "kitchen", 2)
    assert said("poison", str(shoot))[0] == 0
    ctx = AppContext.open()
    try:
        for row in ctx.store.files("kitchen"):  # what that restore did and recorded
            Path(row["path"]).unlink()
            detail = {"to": None, "sha256": row["original_sha256"],
                      "note": f"removed the patched copy {row['path']} from the output folder"}  # fmt: skip
            ctx.store.record_file(row["path"], "kitchen", FileState.RESTORED, event="restored", detail=detail)
        kept = [ctx.vault.path_for(r["original_sha256"]) for r in ctx.store.files("kitchen")]
    finally:
        ctx.close()
    code, text = said("dataset", "forget", "kitchen")
    assert code == 2, text
    removed = "kitchen': 2 of its photos were removed by `ppd restore` as --out copies, no original put back"
    assert f"{removed}: their originals are only in the vault ({kept[0]}, ...)" in text, text
    assert "copy them out first" in text, text
    assert all(p.is_file() for p in kept)
    code, text = said("dataset", "forget", "kitchen", "--force")
    assert code == 0 and not any(p.exists() for p in kept), text


def test_a_folder_still_holding_patched_photos_is_not_followed(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A diff review: "still there" was judged by the dataset's first three rows, so a folder moved in
    two batches, or a backup copy whose first photos were deleted from the outbox, took the whole
    dataset, and the photos left behind were "gone" to status and restore. A stored folder that holds any
    of its patched photos stays the dataset's."""
    outbox = ppd_env["outbox"]
    # a move done in batches: three of five photos moved first
    shoot = make_shoot(tmp_path / "elsewhere" / "shoot", 5)
    assert said("poison", str(shoot))[0] == 0
    part = outbox / "shoot"
    part.mkdir()
    for name in ("v0.png", "v1.png", "v2.png"):
        (shoot / name).rename(part / name)
    code, text = said("poison", str(part))
    assert "folder moved" not in text and _root("shoot") == str(shoot), text
    code, text = said("status", "shoot")
    assert "deleted or moved away since patched 3" in text, text  # the three moved, not the two left
    assert "deleted or moved away since patched 2" not in text, text
    # a backup copy, the outbox's first photos deleted since
    kitchen = make_shoot(outbox / "kitchen", 5)
    assert said("poison", str(kitchen))[0] == 0
    backup = tmp_path / "backup" / "kitchen"
    shutil.copytree(kitchen, backup, copy_function=shutil.copy2)
    for name in ("v0.png", "v1.png", "v2.png"):
        (kitchen / name).unlink()
    code, text = said("poison", str(backup), "--dataset", "kitchen")
    assert "folder moved" not in text and _root("kitchen") == str(kitchen), text
    code, text = said("poison", str(kitchen))
    assert code == 0 and "already belongs" not in text, text
