"""A patched photo moved or copied into another dataset, whose spec is another one: one dataset, one spec
(docs/STORE.md). A black-box review: it kept the first dataset's mark; the daemon logged "unchanged ...
moved from", `ppd poison` said "patched 0, unchanged 2" (exit 0), and status blamed "a re-protect".
Now it is patched again from its vault original with the dataset's spec, by `ppd poison` and the daemon,
and said; an original not in the vault fails, named. `--dataset NAME` on files another dataset holds is
refused. Real shoots, a real store and vault, a real `ppd watch`."""

from __future__ import annotations

import hashlib
import sqlite3
from pathlib import Path

import pytest
from PIL import Image
from typer.testing import CliRunner

import daemon.protect.remark as remark
from daemon.cli import app
from daemon.store.vault import blob_path
from testkit.cli import said
from testkit.daemon_proc import start_daemon, stop_daemon, wait_for
from testkit.photos import make_image, make_shoot, rate_in_place, textured

runner = CliRunner()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _row(data: Path, path: Path) -> dict[str, object]:
    conn = sqlite3.connect(f"file:{data / 'ppd.sqlite3'}?mode=ro", uri=True)
    conn.row_factory = sqlite3.Row
    try:
        row = conn.execute("SELECT * FROM files WHERE path = ?", (str(path),)).fetchone()
        return dict(row) if row is not None else {}
    finally:
        conn.close()


def _spec_id(name: str) -> str:
    import json

    return str(json.loads(runner.invoke(app, ["dataset", "show", name, "--json"]).stdout)["spec_id"])


def _two_datasets(outbox: Path) -> tuple[Path, Path, dict[str, str]]:
    """shoot (the default spec) and papers (the paper design), both patched; shoot's originals' digests."""
    shoot = make_shoot(outbox / "shoot", 3)
    originals = {p.name: _sha(p) for p in shoot.iterdir()}
    papers = outbox / "papers"
    make_image(papers / "p0.png", 30)
    assert said("dataset", "set", "papers", "--design", "paper")[0] == 0
    for folder in (shoot, papers):
        assert runner.invoke(app, ["poison", str(folder)]).exit_code == 0
    return shoot, papers, originals


def test_a_photo_moved_or_copied_in_gets_the_datasets_spec(ppd_env: dict[str, Path]) -> None:
    data = ppd_env["data"]
    shoot, papers, originals = _two_datasets(ppd_env["outbox"])
    ours, theirs = _spec_id("papers"), _spec_id("shoot")
    assert ours != theirs
    (shoot / "v1.png").rename(papers / "moved.png")
    (papers / "copied.png").write_bytes((shoot / "v2.png").read_bytes())
    code, text = said("poison", str(papers), "--dry-run")
    assert code == 0 and "would patch 2" in text, text  # before: "unchanged 3"

    code, text = said("-v", "poison", str(papers))
    assert code == 0 and "patched 2, unchanged 1" in text, text  # before: "patched 0, unchanged 3", exit 0
    came = f"it came from dataset 'shoot' (moved from {shoot / 'v1.png'})"
    assert f"re-marked with this dataset's spec: {came}" in text, text
    assert f"it came from dataset 'shoot' (copied from {shoot / 'v2.png'})" in text, text
    # the summary says it without -v too (it was only a -v line: a diff review)
    assert "re-marked with this dataset's spec: 2 file(s) moved or copied in from another dataset " \
        "(copied.png, moved.png)" in text, text
    for name in ("moved.png", "copied.png"):
        row = _row(data, papers / name)
        assert row["dataset"] == "papers" and row["spec_id"] == ours and row["state"] == "patched", row
        assert row["poisoned_sha256"] == _sha(papers / name)
    assert _row(data, shoot / "v2.png")["spec_id"] == theirs  # the copy's source keeps its own
    code, text = said("status", "papers")
    assert code == 0 and "another spec" not in text, text  # before: "a re-protect did not finish?"
    assert said("poison", str(papers))[1].startswith("patched 0, unchanged 3"), "done once"

    assert said("restore", "papers")[0] == 0  # each one's own original, from the vault
    assert _sha(papers / "moved.png") == originals["v1.png"]
    assert _sha(papers / "copied.png") == originals["v2.png"]


def test_an_original_not_in_the_vault_fails_named(ppd_env: dict[str, Path]) -> None:
    data = ppd_env["data"]
    shoot, papers, originals = _two_datasets(ppd_env["outbox"])
    for name in ("v1.png", "v2.png"):  # lost from the vault
        blob_path(data / "vault", originals[name]).unlink()
    (shoot / "v1.png").rename(papers / "moved.png")
    (papers / "copied.png").write_bytes((shoot / "v2.png").read_bytes())
    marked = {name: _sha(papers / name) for name in ("moved.png", "copied.png")}
    result = runner.invoke(app, ["poison", str(papers)])
    text = " ".join(result.output.split())
    assert result.exit_code == 1 and "patched 0, unchanged 1, skipped 0, failed 2" in text, text
    assert "ppd: failed: " + str(papers / "moved.png") + ": the vault copy of moved.png is missing or " \
        "corrupt (it came from dataset 'shoot' (moved from " in text, text
    assert "it keeps that mark, not the one of dataset 'papers')" in text, text
    assert "copied.png carries ppd's mark with another spec than the one of dataset 'papers' (it came " \
        "from dataset 'shoot' (copied from" in text and "its original is not in the vault" in text, text
    assert {name: _sha(papers / name) for name in marked} == marked  # left as they were
    code, text = said("status", "papers")
    assert "1 patched with another spec than the dataset's (moved in from another " \
        "dataset" in text, text


def test_dataset_flag_on_files_another_dataset_holds_is_refused(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: "patched 0, unchanged 6 ... other7: nothing patched", exit 0, the paper design
    not applied, and the new dataset's folder "held 0 files" while its photos stayed top7's."""
    top = tmp_path / "p7" / "top7"
    make_shoot(top / "sub", 3)
    make_image(top / "a.png", 40)
    assert runner.invoke(app, ["poison", str(top)]).exit_code == 0
    before = {p: _sha(p) for p in top.rglob("*.png")}
    code, text = said("poison", str(top / "sub"), "--dataset", "other7", "--design", "paper")
    assert code == 2 and text.startswith("ppd: error: ") and text.count("ppd:") == 1, text
    assert "3 file(s) here belong to dataset 'top7', patched with its spec " \
        f"({top / 'sub' / 'v0.png'}, ...): --dataset other7 cannot take them" in text, text
    assert said("dataset", "show", "other7")[0] == 2  # not made
    assert {p: _sha(p) for p in top.rglob("*.png")} == before
    code, text = said("poison", str(top / "sub"))  # without --dataset: top7's, as before
    assert code == 0 and "unchanged 3" in text, text


def test_the_daemon_gives_a_photo_moved_in_the_datasets_spec(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The daemon's moved-file path: it logged "unchanged ... moved from .../shoot/v1.png"."""
    data = ppd_env["data"]
    shoot, papers, originals = _two_datasets(ppd_env["outbox"])
    ours = _spec_id("papers")
    daemon = start_daemon(tmp_path, "--no-verify")
    try:
        (shoot / "v1.png").rename(papers / "moved.png")
        wait_for(lambda: _row(data, papers / "moved.png").get("spec_id") == ours, 60, "re-marked")
    finally:
        stop_daemon(daemon)
    log = daemon.log.read_text()
    assert "re-marked with this dataset's spec: it came from dataset 'shoot'" in log, log
    row = _row(data, papers / "moved.png")
    assert row["state"] == "patched" and row["poisoned_sha256"] == _sha(papers / "moved.png"), row
    assert said("restore", str(papers / "moved.png"))[0] == 0
    assert _sha(papers / "moved.png") == originals["v1.png"]


def _jpeg_datasets(outbox: Path) -> tuple[Path, Path]:
    """shoot (smooth JPEGs: a rating keeps them ppd's output, as a camera's) and papers (paper design)."""
    shoot = outbox / "shoot"
    shoot.mkdir(parents=True)
    for i in range(2):
        Image.fromarray(textured(240, 320, seed=i)).save(shoot / f"v{i}.jpg", quality=95)
    papers = outbox / "papers"
    make_image(papers / "p0.png", 30)
    assert said("dataset", "set", "papers", "--design", "paper")[0] == 0
    for folder in (shoot, papers):
        assert runner.invoke(app, ["poison", str(folder)]).exit_code == 0
    return shoot, papers


def test_a_rated_photo_moved_in_keeps_its_bytes(ppd_env: dict[str, Path]) -> None:
    """A review (F3): a photo rated in place (its row 'saved again by another program') moved into papers
    was re-marked from its vault original: the rating gone, kept nowhere. Now it is left as it is, said
    and noted; the way the line gives (restore --force, poison --force) keeps the rated bytes."""
    data = ppd_env["data"]
    shoot, papers = _jpeg_datasets(ppd_env["outbox"])
    for name in ("v0.jpg", "v1.jpg"):
        rate_in_place(shoot / name)
    assert "its pixels unchanged" in said("-v", "poison", str(shoot))[1]  # recognised: its bytes are yours
    rated = (shoot / "v1.jpg").read_bytes()
    photo = (shoot / "v1.jpg").rename(papers / "rated.jpg")
    copied = papers / "copied.jpg"
    copied.write_bytes((shoot / "v0.jpg").read_bytes())
    copy = copied.read_bytes()
    code, text = said("poison", str(papers))
    assert code == 1 and "patched 0, unchanged 1, skipped 0, failed 2" in text, text
    assert f"ppd: failed: {photo}: rated.jpg was saved again by another program since ppd patched it (its " \
        "bytes are yours): not re-marked; `ppd restore FILE --force` keeps your version" in text, text
    assert "copied.jpg was saved again by another program" in text, text
    assert photo.read_bytes() == rated and copied.read_bytes() == copy  # before: re-marked, the rating gone
    assert _row(data, photo)["resaved"] == 1
    code, text = said("status", "papers", "--failed")
    assert "rated.jpg" in text and "saved again by another program" in text, text

    assert said("restore", str(photo), "--force")[0] == 0
    (kept,) = (p for p in (data / "displaced").rglob("*") if p.is_file())
    assert kept.read_bytes() == rated
    code, text = said("poison", str(photo), "--force")
    assert code == 0 and "patched 1" in text, text
    assert _row(data, photo)["spec_id"] == _spec_id("papers")


def _edit_while_made(monkeypatch: pytest.MonkeyPatch, photo: Path) -> list[bytes]:
    """The creator's editor saves photo in place (rotated) once its re-mark is made, before the re-mark
    is put there: the review's race.py, as a wrapper of the re-mark's poisoner. The edit's bytes."""
    real, saved = remark.poison_to, []

    def made_then_edited(*args: object, **kwargs: object) -> object:
        report = real(*args, **kwargs)  # type: ignore[arg-type]
        if not saved and Path(str(args[1])).name == photo.name:  # its vault original, under its name
            with Image.open(photo) as im:
                im.load()
                edited = im.rotate(90)
            edited.save(photo, "PNG")  # in place: the same inode, new bytes
            saved.append(photo.read_bytes())
        return report

    monkeypatch.setattr(remark, "poison_to", made_then_edited)
    return saved


def test_an_edit_saved_during_the_re_mark_is_not_written_over(
    ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A review (F2): the re-mark renamed its output over the path without a compare-and-swap: an edit
    saved meanwhile was gone, kept nowhere. Now nothing is written over it: the run starts over on it."""
    data = ppd_env["data"]
    shoot, papers, _ = _two_datasets(ppd_env["outbox"])
    photo = (shoot / "v1.png").rename(papers / "moved.png")
    saved = _edit_while_made(monkeypatch, photo)
    code, text = said("-v", "poison", "-j", "1", str(papers))  # one worker: this process, the wrapper's
    assert saved and code == 0, text
    assert "patched 1, unchanged 1" in text, text
    edit = hashlib.sha256(saved[0]).hexdigest()  # judged again: a new photo, patched, kept in the vault
    assert blob_path(data / "vault", edit).read_bytes() == saved[0], text  # before: kept nowhere
    row = _row(data, photo)
    assert row["original_sha256"] == edit and row["poisoned_sha256"] == _sha(photo), row
    assert row["spec_id"] == _spec_id("papers"), row


def test_reprotect_leaves_an_edit_saved_while_it_ran(
    ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`ppd dataset set NAME --reprotect`, the same race: the edit stays, one line says so, noted."""
    data = ppd_env["data"]
    shoot, _papers, _ = _two_datasets(ppd_env["outbox"])
    photo = shoot / "v1.png"
    saved = _edit_while_made(monkeypatch, photo)
    code, text = said("dataset", "set", "shoot", "--design", "paper", "--reprotect")
    assert saved and photo.read_bytes() == saved[0], text  # before: ppd's re-mark, the edit nowhere
    assert "v1.png was written to while being patched; left as it is now" in text, text
    assert "written to while being patched" in _row(data, photo)["error"]  # type: ignore[operator]


def test_a_re_mark_a_kill_stopped_is_finished_by_the_next_run(ppd_env: dict[str, Path]) -> None:
    """A kill after the moved file's row was carried (take_in's first step), before its re-mark: every
    later run said "unchanged (already patched)", exit 0, and the file kept the other dataset's mark (a
    diff review). The state is made by the very first step (recovery.carry_moved_row, real store)."""
    from daemon.context import AppContext
    from daemon.protect.recovery import carry_moved_row

    data = ppd_env["data"]
    shoot, papers, originals = _two_datasets(ppd_env["outbox"])
    ours = _spec_id("papers")
    moved = (shoot / "v1.png").rename(papers / "moved.png")
    ctx = AppContext.open()
    try:
        earlier = ctx.store.file(shoot / "v1.png")
        assert carry_moved_row(ctx, earlier, moved, "papers", papers)  # ... and here the run was killed
    finally:
        ctx.close()
    assert _row(data, moved)["spec_id"] != ours
    code, text = said("poison", str(papers), "--dry-run")
    assert code == 0 and "would patch 1" in text, text
    code, text = said("-v", "poison", str(papers))
    assert code == 0 and "patched 1, unchanged 1" in text, text  # before: "patched 0, unchanged 2"
    assert "re-marked with this dataset's spec: it carried an earlier spec of this dataset" in text, text
    # its summary line: it called every such file "moved or copied in from another dataset" (review 8, F4)
    assert "re-marked with this dataset's spec: 1 file(s) of its own that carried an earlier spec of it " \
        "(moved.png)" in text and "from another dataset" not in text, text
    assert _row(data, moved)["spec_id"] == ours and _row(data, moved)["poisoned_sha256"] == _sha(moved)
    assert said("restore", str(moved))[0] == 0 and _sha(moved) == originals["v1.png"]
