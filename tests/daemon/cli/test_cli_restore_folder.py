"""`ppd restore DATASET|FOLDER` restores what is in the folder and leaves what the user removed.

A black-box review: after a lost store a folder restore said "not a folder ppd patched", or "restored 0,
..., failed 0" with exit 0, while its files were still patched (F2); a dataset folder moved or renamed
could not be restored by its new path, and its old one gave a raw "[Errno 2]" line per file (F3); a
dataset restore made deleted photos again and duplicated renamed ones, saying only "restored N" (F4)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_image

runner = CliRunner()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _shoot(folder: Path, n: int = 3) -> dict[str, str]:
    originals = {f"v{i}.png": _sha(make_image(folder / f"v{i}.png", i)) for i in range(n)}
    assert runner.invoke(app, ["poison", str(folder)]).exit_code == 0
    return originals


def _lose_store(data: Path) -> None:
    for suffix in ("", "-wal", "-shm"):
        (data / f"ppd.sqlite3{suffix}").unlink(missing_ok=True)


def test_a_folder_restore_after_a_lost_store_restores_every_sealed_file(ppd_env: dict[str, Path],
                                                                        tmp_path: Path) -> None:  # fmt: skip
    a, b = tmp_path / "a", tmp_path / "b"
    originals = {**{f"a/{k}": v for k, v in _shoot(a).items()}, **{f"b/{k}": v for k, v in _shoot(b).items()}}
    _lose_store(ppd_env["data"])
    first = runner.invoke(app, ["restore", str(a)])  # before: "not a folder ppd patched", rc 2
    assert first.exit_code == 0 and "restored 3" in first.output, first.output
    assert runner.invoke(app, ["restore", str(b / "v0.png")]).exit_code == 0  # one file: a dataset b
    rest = runner.invoke(app, ["restore", str(b)])  # before: "restored 0, ..., failed 0", rc 0
    assert rest.exit_code == 0 and "restored 2" in rest.output, rest.output
    assert {f"{p.parent.name}/{p.name}": _sha(p) for p in [*a.iterdir(), *b.iterdir()]} == originals
    dry = runner.invoke(app, ["poison", str(a), "--dry-run"])  # recorded restored: not patched again
    assert "would patch 0" in " ".join(dry.output.split()), dry.output


def test_a_moved_dataset_folder_is_restored_by_its_new_path(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot, moved = tmp_path / "shoot", tmp_path / "moved"
    originals = _shoot(shoot)
    shoot.rename(moved)
    old = runner.invoke(app, ["restore", "shoot"])
    lines = [line for line in old.output.splitlines() if line.strip()]
    assert old.exit_code == 2 and len(lines) == 1 and "[Errno" not in old.output, old.output
    assert f"its folder {shoot} is gone" in lines[0] and lines[0].startswith("ppd: error: "), lines
    new = runner.invoke(app, ["restore", str(moved)])  # before: "not a folder ppd patched", rc 2
    assert new.exit_code == 0 and "restored 3" in new.output, new.output
    assert {p.name: _sha(p) for p in moved.iterdir()} == originals
    dry = runner.invoke(app, ["poison", str(moved), "--dry-run"])
    assert "would patch 0" in " ".join(dry.output.split()), dry.output


def test_a_dataset_restore_leaves_deleted_files_gone_and_restores_renamed_ones(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "shoot"
    originals = _shoot(shoot, n=4)
    (shoot / "v1.png").unlink()  # culled
    (shoot / "v0.png").rename(shoot / "hero.png")
    result = runner.invoke(app, ["restore", "shoot"])
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "restored 3" in text, text
    assert "1 gone since patched, not recreated: v1.png" in text, text
    assert sorted(p.name for p in shoot.iterdir()) == ["hero.png", "v2.png", "v3.png"]
    assert _sha(shoot / "hero.png") == originals["v0.png"]
    # asked for by its name, a deleted photo does come back
    again = runner.invoke(app, ["restore", str(shoot / "v1.png")])
    assert again.exit_code == 0 and _sha(shoot / "v1.png") == originals["v1.png"], again.output


def test_a_folder_restore_without_the_seal_key_restores_what_the_store_names(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A diff review (F6): with the key missing, `ppd restore shoot` restored two files, then stopped with
    exit 3 and only the key error: no summary, and the renamed file (found by the store's recorded output,
    which needs no key) left patched. Files only the seal names fail each with the reason."""
    shoot = tmp_path / "shoot"
    originals = _shoot(shoot)
    key = ppd_env["data"] / "seal.key"
    key.rename(tmp_path / "seal.key")
    (shoot / "v0.png").rename(shoot / "hero.png")
    result = runner.invoke(app, ["restore", "shoot"])
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "restored 3" in text, text
    assert _sha(shoot / "hero.png") == originals["v0.png"]
    assert all(_sha(shoot / k) == v for k, v in originals.items() if k != "v0.png")
    # a lost store too: only the seals name the originals, and the key is missing
    b = tmp_path / "b"
    (tmp_path / "seal.key").rename(key)
    _shoot(b, n=2)
    key.rename(tmp_path / "seal.key")
    _lose_store(ppd_env["data"])
    lost = runner.invoke(app, ["restore", str(b)])
    text = " ".join(lost.output.split())
    assert lost.exit_code == 1 and "failed 2" in text, text
    assert "the seal key that recognises it cannot be read" in text, text


def test_a_dataset_restore_leaves_a_nested_datasets_files(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A diff review (F1): `ppd restore castle` also restored a renamed file of castle/day2, a dataset of
    its own, and recorded it "restored by you" there."""
    castle, day2 = tmp_path / "castle", tmp_path / "castle" / "day2"
    inner = _shoot(day2)
    outer = _shoot(castle)
    (day2 / "v0.png").rename(day2 / "hero.png")
    patched = (day2 / "hero.png").read_bytes()
    result = runner.invoke(app, ["restore", "castle"])
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "restored 3" in text, text
    assert {k: _sha(castle / k) for k in outer} == outer
    assert (day2 / "hero.png").read_bytes() == patched  # day2's: left for `ppd restore day2`
    assert all(_sha(day2 / k) != v for k, v in inner.items() if k != "v0.png")
    inner_restore = runner.invoke(app, ["restore", "day2"])
    assert inner_restore.exit_code == 0 and "restored 3" in inner_restore.output, inner_restore.output
    assert _sha(day2 / "hero.png") == inner["v0.png"]


def test_a_home_folder_dataset_restore_scans_the_home_folder_alone(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A diff review (F1): `ppd poison ~/desk.png` makes a dataset rooted at the home folder, and
    `ppd restore` of it restored every row-less sealed file in the whole home tree: another dataset's
    renamed file, a copy in ~/Downloads."""
    home = tmp_path / "home"
    monkeypatch.setenv("HOME", str(home))
    _shoot(home / "shoot")
    (home / "Downloads").mkdir()
    (home / "Downloads" / "from-shoot.png").write_bytes((home / "shoot" / "v1.png").read_bytes())
    desk = make_image(home / "desk.png", 7)
    desk_original = _sha(desk)
    assert runner.invoke(app, ["poison", str(desk)]).exit_code == 0
    (home / "shoot" / "v0.png").rename(home / "shoot" / "hero.png")
    others = (home / "shoot" / "hero.png", home / "Downloads" / "from-shoot.png")
    untouched = {p: p.read_bytes() for p in others}
    result = runner.invoke(app, ["restore", "home"])
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "restored 1" in text, text
    assert _sha(desk) == desk_original
    assert all(p.read_bytes() == b for p, b in untouched.items())


def test_a_nested_dataset_restore_leaves_a_file_moved_in_from_the_outer_one(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """restore_file does not claim for the folder restored a file another dataset's row names, in that
    dataset's folder: castle's photo moved into castle/day2 is castle's output (F1's second half)."""
    castle, day2 = tmp_path / "castle", tmp_path / "castle" / "day2"
    _shoot(day2, n=1)
    outer = _shoot(castle, n=2)
    (castle / "v1.png").rename(day2 / "from-castle.png")
    patched = (day2 / "from-castle.png").read_bytes()
    result = runner.invoke(app, ["restore", "day2"])
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "restored 1" in text and "unchanged 1" in text, text
    assert (day2 / "from-castle.png").read_bytes() == patched
    one = runner.invoke(app, ["restore", str(day2 / "from-castle.png")])  # asked for by its path: restored
    assert one.exit_code == 0 and _sha(day2 / "from-castle.png") == outer["v1.png"], one.output


def test_a_dataset_folder_moved_under_the_same_name_moves_the_dataset(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A diff review (F3): after `mv a/shoot b/shoot`, `ppd restore b/shoot` recorded the restored files
    in dataset shoot, whose root stayed a/shoot: `ppd poison b/shoot` was then refused ("already belongs
    to a/shoot") and status did not count them. The dataset now moves with its folder."""
    old, new = tmp_path / "a" / "shoot", tmp_path / "b" / "shoot"
    originals = _shoot(old)
    new.parent.mkdir()
    old.rename(new)
    result = runner.invoke(app, ["restore", str(new)])
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "restored 3" in text, text
    assert {p.name: _sha(p) for p in new.iterdir()} == originals
    dry = runner.invoke(app, ["poison", str(new), "--dry-run"])
    text = " ".join(dry.output.split())
    assert dry.exit_code == 0 and "would patch 0" in text, text
    status = " ".join(runner.invoke(app, ["status"]).output.split())
    assert "3 restored by you" in status, status
    # another folder named shoot while the dataset's own is there: refused, as `ppd poison` does
    other = tmp_path / "c" / "shoot"
    other.mkdir(parents=True)
    (other / "v0.png").write_bytes((new / "v0.png").read_bytes())
    refused = runner.invoke(app, ["restore", str(other)])
    lines = [line for line in refused.output.splitlines() if line.strip()]
    assert refused.exit_code == 2 and len(lines) == 1, refused.output
    assert lines[0].startswith(f"ppd: error: dataset 'shoot' already belongs to {new}; name this one with "
                               "--dataset NAME"), lines  # fmt: skip


def test_a_restore_into_a_read_only_folder_is_refused_in_one_line_exit_3(ppd_env: dict[str, Path],
                                                                         tmp_path: Path) -> None:  # fmt: skip
    """A black-box review (S9): `ppd restore R` gave exit 1 and one "not restored ... folder not writable"
    line per file, while `ppd poison R` says it once with exit 3 ("cannot work here"), as --help says."""
    from testkit.disk_full import MountUnavailable, read_only_folder

    shoot = tmp_path / "shoot"
    originals = _shoot(shoot)
    patched = {name: _sha(shoot / name) for name in originals}
    try:
        with read_only_folder(shoot):
            whole = runner.invoke(app, ["restore", "shoot"])
            one = runner.invoke(app, ["restore", str(shoot / "v1.png")])
    except MountUnavailable as exc:
        pytest.skip(f"no read-only folder here: {exc}")
    for result in (whole, one):
        errors = [line for line in result.output.splitlines() if line.startswith("ppd:")]
        assert result.exit_code == 3, result.output
        assert errors == [f"ppd: error: folder not writable: {shoot}; nothing restored"], result.output
    assert {name: _sha(shoot / name) for name in originals} == patched  # nothing changed
    again = runner.invoke(app, ["restore", "shoot"])  # writable again: every original back
    assert again.exit_code == 0 and "restored 3" in again.output, again.output
    assert {name: _sha(shoot / name) for name in originals} == originals
