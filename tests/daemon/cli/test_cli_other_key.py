"""ppd's output sealed with another key (a second black-box review): after a lost store and `ppd key
new` (what the missing-key error offers), or `ppd key import --force` of another key, `ppd poison`
marked every patched file a second time and vaulted its once-marked bytes as the "original"; `ppd
restore` then said "restored" and wrote marked bytes back. A file carrying a token this key does not
open is refused, saying which key to import; `--force` marks it anyway."""

from __future__ import annotations

import hashlib
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from daemon.paths import AppPaths
from testkit.photos import make_shoot

runner = CliRunner()


def _shas(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def test_output_sealed_with_another_key_is_not_marked_again(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    patched = _shas(shoot)
    paths.db_path.unlink()  # the store lost, and the key with it: a new one made knowingly
    (paths.data_dir / "seal.key").unlink()
    assert runner.invoke(app, ["key", "new"]).exit_code == 0
    vaulted = sorted(p.name for p in paths.vault_dir.glob("??/*"))

    refused = runner.invoke(app, ["poison", str(shoot)])
    said = " ".join(refused.output.split())
    assert refused.exit_code == 1 and "failed 3" in said and "sealed with another key" in said, said
    assert "`ppd key import`" in said
    # not "already ppd's output": a new photo whose metadata was copied from one is sealed so too (F5)
    assert "already ppd's output" not in said and "metadata was copied" in said and "`--force`" in said, said
    assert _shas(shoot) == patched and sorted(p.name for p in paths.vault_dir.glob("??/*")) == vaulted

    forced = runner.invoke(app, ["poison", str(shoot), "--force"])  # asked for: not refused for the key
    assert "sealed with another key" not in forced.output and "patched" in forced.output, forced.output


def test_replacing_the_key_says_how_much_it_sealed(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd key import --force` said nothing of the files the old key sealed (a second black-box
    review): the refusal and the replacement count the vault's originals."""
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    other = tmp_path / "other.key"
    other.write_text("ab" * 32 + "\n")
    refused = runner.invoke(app, ["key", "import", str(other)])
    assert refused.exit_code == 2 and "3 original(s)" in " ".join(refused.output.split()), refused.output
    replaced = runner.invoke(app, ["key", "import", str(other), "--force"])
    said = " ".join(replaced.output.split())
    assert replaced.exit_code == 0 and "sealed the patched files of 3 original(s)" in said, said


def test_restore_after_a_refused_poison_says_which_key(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """After `ppd poison` refused files sealed with another key (their rows now "failed"), `ppd restore`
    said "restored 0 ... failed 0", exit 0, and "unchanged" read as "your original" (a third black-box
    review): it says again which key to import."""
    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 2)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    paths.db_path.unlink()
    (paths.data_dir / "seal.key").unlink()
    assert runner.invoke(app, ["key", "new"]).exit_code == 0
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 1  # refused: another key's output
    restored = runner.invoke(app, ["restore", str(shoot / "v0.png")])
    said = " ".join(restored.output.split())
    assert restored.exit_code == 1 and "sealed with another key" in said and "`ppd key import`" in said, said


# `ppd poison` SIGKILLed mid-file: the third file's original is in the vault, its row 'pending', the
# file itself never replaced
KILLED_ON_THE_THIRD_FILE = """
import os, signal, sys
from daemon.protect import stages
real, calls = stages.provenance_marker, []
def marker(*args, **kw):
    calls.append(1)
    if len(calls) == 3:
        os.kill(os.getpid(), signal.SIGKILL)
    return real(*args, **kw)
stages.provenance_marker = marker
from daemon.cli import app
sys.argv = ['ppd', *sys.argv[1:]]
app()
"""


def test_replacing_the_key_counts_only_what_it_sealed(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """After a killed `ppd poison`, `ppd key import` said it "sealed the patched files of 19 original(s)"
    where 17 were (a third black-box review, S5): the originals of the files in flight, never replaced,
    were counted. Counted now from the store; what it cannot tell is said as "up to"."""
    import os
    import signal
    import subprocess
    import sys

    from daemon.states import FileState
    from daemon.store import Store
    from testkit.kill_loops import REPO

    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 4)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-c", KILLED_ON_THE_THIRD_FILE, "poison", str(shoot), "--workers", "1"]
    killed = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    store = Store(paths.db_path)
    states = sorted(r["state"] for r in store.files("shoot"))
    store.close()
    assert states == [FileState.PATCHED, FileState.PATCHED, FileState.PENDING], states
    assert len(list(paths.vault_dir.glob("??/*"))) == 3  # the one in flight kept too
    other = tmp_path / "other.key"
    other.write_text("ab" * 32 + "\n")
    refused = runner.invoke(app, ["key", "import", str(other)])
    said = " ".join(refused.output.split())
    assert refused.exit_code == 2 and "sealed the patched files of 2 original(s)" in said, said  # before: 3
    kept = paths.db_path.with_name("kept.sqlite3")
    paths.db_path.rename(kept)  # a store lost: nothing says which originals had their file sealed
    unsure = runner.invoke(app, ["key", "import", str(other)])
    said = " ".join(unsure.output.split())
    assert unsure.exit_code == 2 and "sealed the patched files of up to 3 original(s)" in said, said
    for side in ("-wal", "-shm"):
        paths.db_path.with_name(paths.db_path.name + side).unlink(missing_ok=True)
    kept.rename(paths.db_path)
    replaced = runner.invoke(app, ["key", "import", str(other), "--force"])
    said = " ".join(replaced.output.split())
    assert replaced.exit_code == 0 and "sealed the patched files of 2 original(s)" in said, said


def test_restoring_a_folder_of_another_keys_output_names_each_file(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A fifth black-box review: a shoot patched with a mistyped PPD_DATA_DIR (a new folder: its own
    vault and key), then `ppd poison` with the right one (refused: sealed with another key) and `ppd
    restore FOLDER`: "restored 0, removed 0, unchanged 0, failed 0", exit 0, as if nothing were left
    to do. Each file is named with what to do, exit 1."""
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 2)
    typo = {"PPD_DATA_DIR": str(tmp_path / "ppd-dta")}
    assert runner.invoke(app, ["poison", str(shoot)], env=typo).exit_code == 0
    patched = _shas(shoot)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 1  # refused: another key's seal
    restored = runner.invoke(app, ["restore", str(shoot)])
    said = " ".join(restored.output.split())
    assert restored.exit_code == 1 and "failed 2" in said, said
    assert said.count("sealed with another key") == 2 and "`ppd key import`" in said, said
    assert _shas(shoot) == patched
