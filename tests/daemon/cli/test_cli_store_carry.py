"""What `ppd store rebuild` carries over from the old store, and what it says it left out (a black-box
review: every restored file became "not patched yet", so `ppd poison` patched it again without
--force; the verification history was dropped; datasets whose files share originals with another's
vanished from the summary; `--force /no/such/dir` rebuilt anyway with exit 0). Real stores, real files."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from daemon.paths import AppPaths
from daemon.states import FileState
from daemon.store import Store
from testkit.photos import make_image, make_shoot

runner = CliRunner()


def _line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    return lines[0]


def _run(store: Store, dataset: str, verdict: str) -> None:
    now = time.time()
    store.add_verification_run(dataset, "default", verdict, {"n": 1}, now, now + 1, None, None)


def test_restored_files_stay_restored_and_the_verification_history_stays(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 4)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    store = Store(paths.db_path)
    _run(store, "shoot", "protected")  # then a restore: this verdict becomes history
    time.sleep(0.01)
    for name in ("v0.png", "v1.png"):
        assert runner.invoke(app, ["restore", str(shoot / name)]).exit_code == 0
    time.sleep(0.01)
    _run(store, "shoot", "weak")  # current
    before = [(r["verdict"], r["started_at"]) for r in store.current_verification_runs("shoot")]
    store.close()
    make_image(shoot / "v1.png", 9)  # a restored file replaced since: no longer the original

    rebuilt = runner.invoke(app, ["store", "rebuild", "--force"])
    assert rebuilt.exit_code == 0, rebuilt.output
    line = _line(rebuilt.stdout)
    assert "1 file(s) you restored kept as restored" in line and "2 verification run(s) carried over" in line
    assert "1 restored file(s) no longer hold their original" in line
    store = Store(paths.db_path)
    assert store.file(shoot / "v0.png")["state"] == FileState.RESTORED
    assert store.file(shoot / "v1.png") is None  # its bytes prove nothing: a new photo
    assert [r["verdict"] for r in store.verification_runs("shoot")] == ["weak", "protected"]
    assert [(r["verdict"], r["started_at"]) for r in store.current_verification_runs("shoot")] == before
    store.close()
    dry = runner.invoke(app, ["poison", str(shoot), "--dry-run"])
    assert "would patch 1," in dry.stdout, dry.output  # v1, replaced; v0 left as the user chose
    assert "left unprotected (restored by you): 1" in dry.stdout, dry.output


def test_a_folder_that_is_not_there_is_refused_before_anything_is_touched(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    paths = AppPaths.from_env()
    make_image(tmp_path / "shoot" / "v0.png", 0)
    assert runner.invoke(app, ["poison", str(tmp_path / "shoot")]).exit_code == 0
    listing = sorted(p.name for p in paths.data_dir.iterdir())
    stored = paths.db_path.read_bytes()
    for folder, said in ((tmp_path / "no" / "such", "no such folder"), (tmp_path / "shoot" / "v0.png",
                                                                        "not a folder")):  # fmt: skip
        refused = runner.invoke(app, ["store", "rebuild", "--force", str(folder)])
        assert refused.exit_code == 2, refused.output
        assert _line(refused.stderr) == f"ppd: error: {folder}: {said}"
    assert sorted(p.name for p in paths.data_dir.iterdir()) == listing  # nothing kept aside, nothing made
    assert paths.db_path.read_bytes() == stored


def test_a_dataset_whose_files_were_not_found_again_is_named(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Copies of the same photos as two datasets: the second's originals are the first's, so moving
    its folder away left no vault original unnamed and the summary said nothing of it."""
    shoot, copy = tmp_path / "shoot", tmp_path / "copy"
    make_shoot(shoot, 3)
    shutil.copytree(shoot, copy)
    for folder in (shoot, copy):
        assert runner.invoke(app, ["poison", str(folder)]).exit_code == 0
    copy.rename(tmp_path / "moved")
    rebuilt = runner.invoke(app, ["store", "rebuild", "--force"])
    assert rebuilt.exit_code == 0, rebuilt.output
    line = _line(rebuilt.stdout)
    assert "3 file(s) the old store listed as patched not found again, in dataset(s) copy (3)" in line
    assert "`ppd store rebuild --force FOLDER ...`" in line


def test_a_backup_copy_with_the_same_folder_name_is_its_own_dataset(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd store rebuild sh/castle bk/castle` merged the backup into dataset castle (8 files for 4),
    and `ppd restore castle` then deleted every backup file as an --out copy (a second black-box
    review). The backup is its own dataset; restoring castle leaves it alone."""
    import hashlib

    shoot, backup = tmp_path / "sh" / "castle", tmp_path / "bk" / "castle"
    make_shoot(shoot, 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    shutil.copytree(shoot, backup)
    kept = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in backup.iterdir()}
    AppPaths.from_env().db_path.unlink()
    rebuilt = runner.invoke(app, ["store", "rebuild", str(shoot), str(backup)])
    assert rebuilt.exit_code == 0, rebuilt.output
    store = Store(AppPaths.from_env().db_path)
    try:
        assert store.counts("castle")["files"] == 3 and store.dataset("castle-2")["root"] == str(backup)
    finally:
        store.close()
    restored = runner.invoke(app, ["restore", "castle"])
    assert restored.exit_code == 0 and "removed 0" in restored.output, restored.output
    assert {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in backup.iterdir()} == kept


def test_a_rebuild_after_a_new_key_keeps_the_rows_the_files_still_prove(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """After `ppd key new`, `ppd store rebuild --force A` replaced a sound store with an empty one:
    the seals no longer open, the walk found nothing, and the originals were out of ppd's reach
    (a third black-box review). A patched row whose file still holds exactly the bytes it records
    is kept; restore then gives every original back."""
    import hashlib

    shoot = tmp_path / "A"
    make_shoot(shoot, 3)
    originals = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in shoot.iterdir()}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    paths = AppPaths.from_env()
    (paths.data_dir / "seal.key").unlink()
    assert runner.invoke(app, ["key", "new"]).exit_code == 0
    rebuilt = runner.invoke(app, ["store", "rebuild", "--force", str(shoot)])
    said = " ".join(rebuilt.output.split())
    assert rebuilt.exit_code == 0 and "3 patched file(s) kept by their recorded bytes" in said, said
    store = Store(paths.db_path)
    try:
        assert store.counts("A")["patched"] == 3
    finally:
        store.close()
    assert runner.invoke(app, ["restore", "A"]).exit_code == 0
    assert {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in shoot.iterdir()} == originals


def test_a_rebuild_reminds_to_start_the_service_again(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A rebuild (or a key change) needs `ppd watch` stopped; a creator who stopped the service as told
    and forgot left the outbox unprotected (a third black-box review). With the unit installed, the
    command says how to start it again; without it, nothing."""
    shoot = tmp_path / "A"
    make_image(shoot / "v0.png", 0)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    quiet = runner.invoke(app, ["store", "rebuild", "--force", str(shoot)])
    assert quiet.exit_code == 0 and "systemctl" not in quiet.output, quiet.output
    unit = tmp_path / "xdg" / "systemd" / "user" / "ppd.service"
    unit.parent.mkdir(parents=True)
    unit.write_text("[Service]\n")
    said = runner.invoke(app, ["store", "rebuild", "--force", str(shoot)])
    words = " ".join(said.output.split())
    assert said.exit_code == 0 and "`systemctl --user start ppd`" in words, words


@pytest.mark.parametrize("undone_by", ["restore", "a new key"])
def test_the_summary_counts_what_the_table_lists(
    ppd_env: dict[str, Path], tmp_path: Path, undone_by: str
) -> None:
    """`ppd store rebuild -v` said "0 patched file(s) in 0 dataset(s)" above a table listing the dataset
    (a black-box review): a dataset whose files were all restored, or whose rows were kept by their
    bytes after `ppd key new`, was counted nowhere, and the table said 0 of the 3 kept patched."""
    shoot = tmp_path / "A"
    make_shoot(shoot, 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    if undone_by == "restore":
        assert runner.invoke(app, ["restore", "A"]).exit_code == 0
        patched = 0
    else:
        (AppPaths.from_env().data_dir / "seal.key").unlink()
        assert runner.invoke(app, ["key", "new"]).exit_code == 0
        patched = 3
    rebuilt = runner.invoke(app, ["store", "rebuild", "--force", "-v"])
    said = " ".join(rebuilt.output.split())
    assert rebuilt.exit_code == 0, said
    assert f"{patched} patched file(s) in 1 dataset(s)" in said, said
    assert f"│ A │ {patched} │" in said, said  # the table's row: dataset, patched files
