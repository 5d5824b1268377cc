"""`ppd dataset forget NAME`: a finished or deleted shoot leaves ppd. The vault only grew (it holds a
private, unprotected copy of every photo ever patched) and a deleted shoot stayed in the store for good
(`ppd status`: "not shown: ... whose folder is gone" forever). Now its rows, verification runs and events
leave the store, then the originals no remaining row names leave the vault; a folder still holding its
patched files, or seen moved, is refused (exit 2) unless --force, and so is any other ppd using the store
(exit 3). Real shoots patched by the real commands, a real store and vault, a real `ppd watch`."""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import shutil
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.context import AppContext
from testkit.cli import said
from testkit.daemon_proc import start_daemon, stop_daemon, wait_for
from testkit.photos import make_image, make_shoot
from testkit.privilege import modes_bind
from testkit.reliability import REPO

runner = CliRunner()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _blobs(data: Path) -> set[str]:
    return {p.name for p in (data / "vault").glob("??/*") if len(p.name) == 64}


def _rows(data: Path, sql: str, *params: str) -> list[tuple[object, ...]]:
    conn = sqlite3.connect(f"file:{data / 'ppd.sqlite3'}?mode=ro", uri=True)
    try:
        return conn.execute(sql, params).fetchall()
    finally:
        conn.close()


def _of(data: Path, name: str) -> dict[str, int]:
    """The store's rows that belong to dataset name, per table."""
    tables = {"datasets": "name", "files": "dataset", "verification_runs": "dataset", "events": "dataset",
              "auto_decisions": "dataset"}  # fmt: skip
    return {t: len(_rows(data, f"SELECT 1 FROM {t} WHERE {col} = ?", name)) for t, col in tables.items()}


def _verdict(name: str) -> None:
    """A verification run of the dataset, as `ppd verify` records it (its COLMAP run is minutes)."""
    ctx = AppContext.open()
    try:
        now = time.time()
        ctx.store.add_verification_run(name, "default", "protected", {}, now, now + 1, None, None)
    finally:
        ctx.close()


def test_a_deleted_shoot_is_forgotten_and_its_name_starts_clean(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    data, shoot = ppd_env["data"], tmp_path / "sets" / "castle"
    originals = {_sha(p) for p in make_shoot(shoot, 3).iterdir()}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    _verdict("castle")
    runs = data / "runs" / "castle" / "20260101T000000-abcdef"  # a verification's run folder
    runs.mkdir(parents=True)
    (runs / "report.json").write_text("{}")
    assert originals <= _blobs(data)
    for path in shoot.iterdir():
        path.unlink()
    shoot.rmdir()
    code, text = said("status")
    assert "folder is gone" in text and "`ppd dataset forget NAME` forgets a deleted one" in text, text

    freed = sum((data / "vault" / sha[:2] / sha).stat().st_size for sha in originals)
    assert 1000 < freed < 1_000_000
    code, text = said("dataset", "forget", "castle")
    assert code == 0, text
    # the size in kB: "(0.0 MB)" said that nothing was freed (a black-box review, F8)
    assert f"forgot dataset castle: 3 file record(s); 3 original(s) ({freed / 1000:.0f} KB) removed " \
        "from the vault" in text and "kept" not in text, text
    assert "3 patched file(s) not found where they were patched (moved or deleted?): any copy of them " \
        "keeps the mark for good" in text, text  # a deleted shoot is not refused, and what it means is said
    assert _of(data, "castle") == dict.fromkeys(_of(data, "castle"), 0)
    assert not originals & _blobs(data) and not (data / "runs" / "castle").exists()
    assert not _rows(data, "SELECT key FROM store_notes")  # the vault step done: no note left
    code, text = said("status")
    assert "castle" not in text and "folder is gone" not in text, text
    assert said("dataset", "forget", "castle") == (2, "ppd: error: no dataset 'castle'")

    # a new shoot of the same name: no verdict, no run, no pixel-change date from the old one
    make_image(shoot / "n0.png", 7)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    info = json.loads(runner.invoke(app, ["status", "castle", "--json"]).stdout)["datasets"][0]
    assert info["last_verification"] is None and info["regression"] is None, info
    assert _of(data, "castle")["verification_runs"] == 0
    kinds = [k for (k,) in _rows(data, "SELECT kind FROM events WHERE dataset = ? ORDER BY id", "castle")]
    assert kinds[0] == "dataset_created" and kinds.count("patched") == 1, kinds


def test_an_original_another_dataset_uses_stays_and_restores(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    data, sets = ppd_env["data"], tmp_path / "sets"
    make_shoot(sets / "a", 3)
    b = {p.name: _sha(p) for p in make_shoot(sets / "b", 2).iterdir()}  # v0, v1: the same photos as a's
    for name in ("a", "b"):
        assert runner.invoke(app, ["poison", str(sets / name)]).exit_code == 0
    shutil.rmtree(sets / "a")  # a deleted shoot
    code, text = said("dataset", "forget", "a")
    assert code == 0, text
    assert "3 file record(s); 1 original(s) (" in text, text
    assert "removed from the vault; 2 original(s) kept: another dataset uses them" in text, text
    assert set(b.values()) <= _blobs(data) and len(_blobs(data)) == 2
    assert said("restore", "b")[0] == 0
    assert {p.name: _sha(p) for p in (sets / "b").iterdir()} == b


def test_the_originals_of_edited_photos_earlier_versions_go_too(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A photo edited and patched again under its name: its first original stays in the vault (a copy
    published before the edit restores from it) while the dataset lives, and goes when it is forgotten;
    unless another dataset's earlier version is the same photo (a diff review: they stayed for good)."""
    data, sets = ppd_env["data"], tmp_path / "sets"
    first = {p.name: _sha(p) for p in make_shoot(sets / "a", 3).iterdir()}
    make_shoot(sets / "b", 1)  # v0: the same photo as a's first v0
    for name in ("a", "b"):
        assert runner.invoke(app, ["poison", str(sets / name)]).exit_code == 0
    for name in ("a", "b"):  # both edit v0 and patch it again
        make_image(sets / name / "v0.png", 99 if name == "a" else 98)
        assert runner.invoke(app, ["poison", str(sets / name)]).exit_code == 0
    assert first["v0.png"] in _blobs(data)  # no row names it now; kept for what was published before
    assert len(_blobs(data)) == 3 + 2
    # a rebuilt store keeps them too (it was counted a vault original no file names, and left for good)
    code, text = said("store", "rebuild", "--force", str(sets))
    assert code == 0 and "no file names" not in text, text
    assert len(_rows(data, "SELECT 1 FROM earlier_originals")) == 2

    shutil.rmtree(sets / "a")
    code, text = said("dataset", "forget", "a")
    assert code == 2 and "saved over ppd's patched ones" in text, text  # the photo from before: said
    code, text = said("dataset", "forget", "a", "--force")
    assert code == 0, text
    assert "3 file record(s); 3 original(s) (" in text, text  # v1, v2 and a's edited v0
    assert "1 original(s) kept: another dataset uses them" in text, text  # the first v0: b's earlier one
    assert first["v0.png"] in _blobs(data) and len(_blobs(data)) == 2
    shutil.rmtree(sets / "b")
    code, text = said("dataset", "forget", "b", "--force")
    assert code == 0, text
    assert "1 file record(s); 2 original(s) (" in text and not _blobs(data), text
    assert not _rows(data, "SELECT 1 FROM earlier_originals")


def test_the_experiment_folder_of_its_originals_goes_too(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd experiment castle` stages the dataset's originals in DATA/experiments/castle (links to the
    vault's blobs): forget said "originals removed from the vault" and they stayed there for good (a
    black-box review). An experiment folder of another name stays."""
    from daemon.cli.experiment_cmd import resolve_dataset

    data, shoot = ppd_env["data"], tmp_path / "sets" / "castle"
    originals = {_sha(p) for p in make_shoot(shoot, 3).iterdir()}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    staged = resolve_dataset("castle", views=3)[0]  # what `ppd experiment castle` runs on
    assert {_sha(p) for p in staged.iterdir()} == originals and staged.is_relative_to(data / "experiments")
    (data / "experiments" / "lego40").mkdir()  # another experiment's folder
    assert said("restore", "castle")[0] == 0
    shutil.rmtree(shoot)
    code, text = said("dataset", "forget", "castle")
    assert code == 0 and "3 original(s) (" in text, text
    assert not (data / "experiments" / "castle").exists() and (data / "experiments" / "lego40").is_dir()
    kept = {_sha(p) for p in data.rglob("*") if p.is_file() and not p.is_symlink()}
    assert not originals & kept  # no copy of an original anywhere in the data folder


def test_patched_files_still_there_are_refused_unless_force(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    data, shoot = ppd_env["data"], tmp_path / "sets" / "castle"
    make_shoot(shoot, 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    blobs, before = _blobs(data), _of(data, "castle")
    code, text = said("dataset", "forget", "castle")
    assert code == 2 and text.startswith("ppd: error: ") and text.count("ppd:") == 1, text
    assert f"has 3 patched file(s) still there in {shoot}: their originals in the vault are the only" in text
    assert "`ppd restore castle` first, or --force" in text, text
    assert _blobs(data) == blobs and _of(data, "castle") == before  # nothing lost

    code, text = said("dataset", "forget", "castle", "--force")
    assert code == 0, text
    assert "forgot dataset castle: 3 file record(s); 3 original(s)" in text, text
    assert "its 3 patched file(s) still there keep the mark for good: ppd can no longer restore them" in text
    assert not _blobs(data) and _of(data, "castle")["files"] == 0
    assert len(list(shoot.iterdir())) == 3  # the photos themselves are the user's: untouched
    code, text = said("restore", str(shoot / "v0.png"))  # a diff review: "is not in the vault" read as damage
    assert code == 1 and "its original " in text, text
    assert "is not in the vault " in text and " (forgotten by `ppd dataset forget`, or lost)" in text, text


def test_restored_shoot_forgets_and_displaced_files_stay(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    data, shoot = ppd_env["data"], tmp_path / "castle"
    make_shoot(shoot, 2)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    with Image.open(shoot / "v0.png") as im:
        edited = im.copy()
    edited.putpixel((3, 3), (255, 0, 0))  # an edit: restore --force sets it aside
    edited.save(shoot / "v0.png")
    assert said("restore", "castle", "--force")[0] == 0
    aside = sorted(p for p in (data / "displaced").rglob("*") if p.is_file())
    assert len(aside) == 1
    code, text = said("dataset", "forget", "castle")  # restored: nothing patched there
    assert code == 0, text
    assert "forgot dataset castle: 2 file record(s); 2 original(s)" in text, text
    assert f"stay in {aside[0].parent}: they are yours" in text, text
    assert sorted(p for p in (data / "displaced").rglob("*") if p.is_file()) == aside


def test_a_restored_folder_in_the_outbox_is_refused_until_moved_out(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: `ppd restore castle` then `ppd dataset forget castle` (the README's flow for a
    finished shoot) of a folder in the outbox: forgotten, exit 0, and the next `ppd watch` start patched
    every restored original again (no row said restored any more), unsaid. Refused now (exit 2, one line,
    nothing lost) until the folder leaves the outbox; with --force it is said, and it is what happens."""
    data, outbox = ppd_env["data"], ppd_env["outbox"]
    shoot = make_shoot(outbox / "castle", 3)
    originals = {p.name: _sha(p) for p in shoot.iterdir()}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert said("restore", "castle")[0] == 0
    blobs, before = _blobs(data), _of(data, "castle")
    code, text = said("dataset", "forget", "castle")
    assert code == 2 and text.startswith("ppd: error: ") and text.count("ppd:") == 1, text
    assert f"the folder of dataset 'castle', {shoot}, is in the outbox: `ppd watch` would patch its " \
        "3 file(s) again once it is forgotten" in text, text
    assert "move the folder out of the outbox first, or --force" in text, text
    assert _blobs(data) == blobs and _of(data, "castle") == before  # nothing lost
    done = tmp_path / "done"
    done.mkdir()
    shoot.rename(done / "castle")  # out of the outbox: forgotten
    code, text = said("dataset", "forget", "castle")
    assert code == 0 and "forgot dataset castle: 3 file record(s); 3 original(s)" in text, text
    assert {p.name: _sha(p) for p in (done / "castle").iterdir()} == originals

    garden = make_shoot(outbox / "garden", 2)
    originals = {p.name: _sha(p) for p in garden.iterdir()}
    assert runner.invoke(app, ["poison", str(garden)]).exit_code == 0
    assert said("restore", "garden")[0] == 0
    code, text = said("dataset", "forget", "garden", "--force")
    assert code == 0 and "forgot dataset garden: 2 file record(s)" in text, text
    assert f"its 2 file(s) in the outbox ({garden}) are no dataset's now: `ppd watch` patches them again" \
        in text, text
    daemon = start_daemon(tmp_path, "--no-verify")  # what was said
    try:
        wait_for(lambda: all(_sha(garden / n) != sha for n, sha in originals.items()), 60, "patched again")
    finally:
        stop_daemon(daemon)


def test_a_moved_folder_and_an_unknown_name_are_refused(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    data, sets = ppd_env["data"], tmp_path / "sets"
    assert runner.invoke(app, ["poison", str(make_shoot(sets / "n2", 2))]).exit_code == 0
    (sets / "n2").rename(sets / "n2_new")
    blobs = _blobs(data)
    code, text = said("dataset", "forget", "n2")
    assert code == 2 and text.count("ppd: error:") == 1, text
    assert f"its patched files are in {sets / 'n2_new'} (moved?)" in text, text
    new = shlex.quote(str(sets / "n2_new"))
    assert f"`ppd dataset set n2 --root {new}` moves the dataset there" in text, text
    assert _blobs(data) == blobs and _of(data, "n2")["files"] == 2
    assert said("dataset", "forget", "nope") == (2, "ppd: error: no dataset 'nope'")
    assert said("dataset", "forget", "n2", "--force")[0] == 0
    assert not _blobs(data)


def test_a_moved_folder_made_a_dataset_by_name_keeps_its_originals(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The moved folder made its own dataset by `ppd dataset set NEW --root NEW`: no row of that one names
    the originals yet, so forgetting the old one would have taken the only way back of files still
    marked; a run there records them in it, and then the old one forgets freely."""
    data, sets = ppd_env["data"], tmp_path / "sets"
    moved = {make_image(sets / "n4" / f"a{i}.png", 10 + i).name: 0 for i in range(2)}
    originals = {name: _sha(sets / "n4" / name) for name in moved}
    assert runner.invoke(app, ["poison", str(sets / "n4")]).exit_code == 0
    (sets / "n4").rename(sets / "n4_new")
    assert runner.invoke(app, ["dataset", "set", "n4_new", "--root", str(sets / "n4_new")]).exit_code == 0
    code, text = said("dataset", "forget", "n4")
    new = shlex.quote(str(sets / "n4_new"))
    assert code == 2 and f"`ppd poison {new}` records them in dataset 'n4_new'" in text, text
    assert set(originals.values()) == _blobs(data)
    assert runner.invoke(app, ["poison", str(sets / "n4_new")]).exit_code == 0
    code, text = said("dataset", "forget", "n4")
    assert code == 0 and "0 original(s) (0 bytes) removed from the vault; 2 original(s) kept" in text, text
    assert said("restore", "n4_new")[0] == 0
    assert {name: _sha(sets / "n4_new" / name) for name in moved} == originals


def test_a_crash_before_the_vault_step_is_finished_by_the_next_forget(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    data, sets = ppd_env["data"], tmp_path / "sets"
    make_shoot(sets / "a", 2)
    make_image(sets / "b" / "w.png", 9)
    for name in ("a", "b"):
        assert runner.invoke(app, ["poison", str(sets / name)]).exit_code == 0
    for folder in ("a", "b"):
        shutil.rmtree(sets / folder)  # deleted shoots
    (data / "runs" / "a" / "20260101T000000-abcdef").mkdir(parents=True)  # a's verification run
    ctx = AppContext.open()
    try:
        assert ctx.store.forget_dataset("a") == 2  # the rows' step alone: a kill before the vault's
    finally:
        ctx.close()
    assert len(_blobs(data)) == 3  # unreferenced originals, never a row without its original
    code, text = said("dataset", "forget", "b")
    assert code == 0 and "1 file record(s); 3 original(s)" in text, text
    assert not _blobs(data) and not _rows(data, "SELECT key FROM store_notes")
    assert not (data / "runs" / "a").exists()  # before: left for good (only the forgotten name's went)

    # the same name again finishes it too (its records gone, its note left)
    make_image(sets / "c" / "w.png", 11)
    assert runner.invoke(app, ["poison", str(sets / "c")]).exit_code == 0
    shutil.rmtree(sets / "c")
    ctx = AppContext.open()
    try:
        ctx.store.forget_dataset("c")
    finally:
        ctx.close()
    code, text = said("dataset", "forget", "c")
    assert code == 0 and "forgot dataset c: 0 file record(s); 1 original(s)" in text, text
    assert not _blobs(data) and said("dataset", "forget", "c") == (2, "ppd: error: no dataset 'c'")


def test_patched_files_moved_out_of_the_folder_keep_their_originals(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A diff review: a patched photo moved out of its folder (to an album) has no row of its new place;
    forget deleted its original silently, exit 0, right after `ppd restore` had said `ppd restore FILE`
    brings one back, and the copy in the album kept the mark for good. While the folder is there, a
    patched file missing from it is refused (exit 2), named; with --force, or a deleted shoot, said."""
    data, shoot, album = ppd_env["data"], tmp_path / "sets" / "castle", tmp_path / "album"
    originals = {p.name: _sha(p) for p in make_shoot(shoot, 3).iterdir()}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    album.mkdir()
    (shoot / "v0.png").rename(album / "v0.png")
    (shoot / "v2.png").unlink()
    code, text = said("restore", "castle")
    assert code == 0 and "`ppd restore FILE` brings one back" in text, text
    blobs, before = _blobs(data), _of(data, "castle")
    code, text = said("dataset", "forget", "castle")
    assert code == 2 and text.startswith("ppd: error: ") and text.count("ppd:") == 1, text
    assert "has 2 patched file(s) not found where they were patched (moved or deleted?): v0.png, v2.png;" \
        in text, text  # before: "forgot dataset castle: 3 file record(s); 3 original(s) ... removed", exit 0
    assert "`ppd restore FILE` on a moved one first, or --force" in text, text
    assert _blobs(data) == blobs and _of(data, "castle") == before  # nothing lost

    assert said("restore", str(album / "v0.png"))[0] == 0  # the way back, still there
    assert _sha(album / "v0.png") == originals["v0.png"]
    code, text = said("dataset", "forget", "castle")  # v2.png: deleted, or moved where ppd cannot see
    assert code == 2 and "has 1 patched file(s) not found where they were patched" in text, text
    assert ": v2.png; " in text, text
    code, text = said("dataset", "forget", "castle", "--force")
    assert code == 0 and "forgot dataset castle: 3 file record(s); 3 original(s)" in text, text
    assert "1 patched file(s) not found where they were patched (moved or deleted?): any copy of them " \
        "keeps the mark for good" in text, text
    assert "still there" not in text and not _blobs(data), text


def test_a_new_dataset_of_a_crashed_forgets_name_keeps_the_first_note(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A diff review: a crash between forget's two steps, then a new dataset of the same name forgotten
    later: its note replaced the first one, whose originals stayed in the vault with no note to finish."""
    data, sets = ppd_env["data"], tmp_path / "sets"
    make_image(sets / "k" / "w.png", 21)
    assert runner.invoke(app, ["poison", str(sets / "k")]).exit_code == 0
    assert said("restore", "k")[0] == 0
    ctx = AppContext.open()
    try:
        ctx.store.forget_dataset("k")  # the rows' step alone: a kill before the vault's
    finally:
        ctx.close()
    make_image(sets / "other" / "x.png", 22)
    assert runner.invoke(app, ["poison", "--dataset", "k", str(sets / "other")]).exit_code == 0
    assert said("restore", "k")[0] == 0
    assert len(_blobs(data)) == 2
    code, text = said("dataset", "forget", "k")
    assert code == 0 and "forgot dataset k: 1 file record(s); 2 original(s)" in text, text
    assert not _blobs(data) and not _rows(data, "SELECT key FROM store_notes")  # before: the first one left


def test_runs_that_cannot_be_removed_are_said_and_the_next_forget_removes_them(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A diff review: the run folders were removed after the note went, their errors ignored: a failed
    removal (or a crash) left ppd's reconstructions of the forgotten photos for good, exit 0, unsaid."""
    data, shoot = ppd_env["data"], tmp_path / "sets" / "castle"
    assert runner.invoke(app, ["poison", str(make_shoot(shoot, 2))]).exit_code == 0
    shutil.rmtree(shoot)
    run = data / "runs" / "castle" / "20260101T000000-abcdef"
    run.mkdir(parents=True)
    (run / "report.json").write_text("{}")
    run.chmod(0o500)  # its file cannot be removed
    forget = [sys.executable, "-m", "daemon.cli", "dataset", "forget", "castle"]
    forget = [*modes_bind(), *forget]  # root: without the capabilities that override modes
    env = {**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "200"}
    try:
        done = subprocess.run(forget, cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    finally:
        run.chmod(0o700)
    assert done.returncode == 3 and done.stderr.count("ppd: error:") == 1, done.stdout + done.stderr
    assert "the records of dataset 'castle' are forgotten, but its verification runs or experiment folder " \
        "could not all be removed " \
        f"(Permission denied: {run / 'report.json'}); `ppd dataset forget castle` again finishes it" \
        in " ".join(done.stderr.split()), done.stderr
    assert not _blobs(data) and _of(data, "castle")["files"] == 0
    assert [k for (k,) in _rows(data, "SELECT key FROM store_notes")] == ["forgetting:castle"]  # kept
    code, text = said("dataset", "forget", "castle")
    assert code == 0 and "forgot dataset castle: 0 file record(s); 0 original(s)" in text, text
    assert not (data / "runs" / "castle").exists() and not _rows(data, "SELECT key FROM store_notes")


def _ppd(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", *args], cwd=REPO, capture_output=True, text=True, check=False,
        env={**os.environ, **env, "PYTHONPATH": str(REPO), "COLUMNS": "200"},
    )  # fmt: skip


def test_refused_while_ppd_watch_runs_or_a_command_holds_the_store(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tmp_path / "root"
    for name in ("data", "config", "outbox", "cache"):
        (root / name).mkdir(parents=True)
    env = {f"PPD_{name.upper()}_DIR": str(root / name) for name in ("data", "config", "cache")}
    env["PPD_OUTBOX"] = str(root / "outbox")
    env["XDG_CONFIG_HOME"] = str(root / "xdg")  # no ppd.service installed there (yet)
    shoot = make_shoot(tmp_path / "castle", 2)
    assert _ppd(env, "poison", str(shoot)).returncode == 0
    shutil.rmtree(shoot)  # a deleted shoot
    blobs = _blobs(root / "data")
    daemon = start_daemon(root, "--no-verify")
    try:
        refused = _ppd(env, "dataset", "forget", "castle")
        unit = root / "xdg" / "systemd" / "user" / "ppd.service"
        unit.parent.mkdir(parents=True)
        unit.write_text("[Service]\n")
        with_unit = _ppd(env, "dataset", "forget", "castle")
    finally:
        stop_daemon(daemon)
    assert refused.returncode == 3 and refused.stderr.count("ppd: error:") == 1, refused.stderr
    # a `ppd watch` run in a terminal, no unit installed: stopped by its pid, not by systemctl (review 8, F8)
    assert f"ppd watch (pid {daemon.pid}) is running on this data folder; stop pid {daemon.pid} first " \
        f"(Ctrl-C in its terminal, or `kill {daemon.pid}`), then forget the dataset" in refused.stderr
    assert "systemctl" not in refused.stderr
    assert with_unit.returncode == 3 and "stop it first (`systemctl --user stop ppd`; run in a terminal: " \
        f"Ctrl-C in its terminal, or `kill {daemon.pid}`)" in with_unit.stderr, with_unit.stderr
    assert _blobs(root / "data") == blobs

    for key, value in env.items():
        monkeypatch.setenv(key, value)
    ctx = AppContext.open()  # this process's command, holding the store as a long `ppd poison` does
    try:
        refused = _ppd(env, "dataset", "forget", "castle")
    finally:
        ctx.close()
    assert refused.returncode == 3 and "another ppd command is running" in refused.stderr, refused.stderr
    assert _blobs(root / "data") == blobs
    done = _ppd(env, "dataset", "forget", "castle")
    assert done.returncode == 0 and "forgot dataset castle: 2 file record(s)" in done.stdout, done.stderr
    assert not _blobs(root / "data")


def test_a_name_whose_safe_form_is_anothers_forgets_its_own_experiment_only(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`my shoot` and `my_shoot` had one experiment folder (DATA/experiments/my_shoot): forgetting the
    first removed the second's experiment (a diff review)."""
    from daemon.paths import AppPaths

    paths = AppPaths.from_env()
    for name in ("my shoot", "my_shoot"):
        make_shoot(tmp_path / "sets" / name, 1)
        assert runner.invoke(app, ["poison", str(tmp_path / "sets" / name)]).exit_code == 0
        (paths.experiment_dir(name) / "results.csv").parent.mkdir(parents=True)
        (paths.experiment_dir(name) / "results.csv").write_text(name)
    assert paths.experiment_dir("my shoot") != paths.experiment_dir("my_shoot")
    shutil.rmtree(tmp_path / "sets" / "my shoot")
    code, text = said("dataset", "forget", "my shoot")
    assert code == 0, text
    assert not paths.experiment_dir("my shoot").exists()
    assert (paths.experiment_dir("my_shoot") / "results.csv").read_text() == "my_shoot"


def test_forget_removes_the_report_and_the_previews_that_show_its_originals(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A privacy review: after `ppd dataset forget`, the dataset's report page and its cached previews
    (each showing an original beside the patched photo) were still in ppd's folders. Another dataset's
    stay."""
    import os

    shoots = {name: make_shoot(tmp_path / "sets" / name, 2) for name in ("castle", "garden")}
    for name, shoot in shoots.items():
        assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
        assert runner.invoke(app, ["preview", str(shoot / "v0.png"), "--no-visibility"]).exit_code == 0
        assert runner.invoke(app, ["report", name]).exit_code == 0
    data, cache = ppd_env["data"], Path(os.environ["PPD_CACHE_DIR"])
    previews = sorted(p.parent.name for p in (cache / "previews").rglob("*.ppd-preview.png"))
    assert len(previews) == 2 and (data / "reports" / "castle" / "latest.html").is_file(), previews
    assert runner.invoke(app, ["restore", "castle"]).exit_code == 0
    shutil.rmtree(shoots["castle"])
    result = runner.invoke(app, ["dataset", "forget", "castle"])
    assert result.exit_code == 0, result.output
    assert not (data / "reports" / "castle").exists()
    left = sorted(p.parent.name for p in (cache / "previews").rglob("*.ppd-preview.png"))
    assert [n.split("-")[0] for n in left] == ["garden"], left
    assert (data / "reports" / "garden" / "latest.html").is_file()
