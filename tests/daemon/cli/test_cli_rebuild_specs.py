"""A dataset's spec across a lost store (an eighth black-box review, F4): a seal names only the spec's id,
so every spec that patches an original is kept in the vault (`vault/specs/<id>.json`) and `ppd store
rebuild` gives each dataset its exact spec back. A vault kept by a ppd before that holds no spec: the
rebuild exits 1 naming the dataset and what gives it back, and the dataset refuses new photos instead of
taking the config's spec in silence. Real CLI (typer), real store, vault and patched files."""

from __future__ import annotations

import hashlib
import shutil
import sqlite3
from pathlib import Path

from testkit.cli import said
from testkit.photos import make_image, make_shoot

FLAGS = ("--patch-size", "0.04", "--block-size", "0.005")  # not the default: the spec a creator chose


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _spec_id(data: Path, dataset: str) -> str | None:
    with sqlite3.connect(data / "ppd.sqlite3") as conn:
        row = conn.execute("SELECT spec_id FROM datasets WHERE name = ?", (dataset,)).fetchone()
    return row[0] if row else None


def _file_spec(data: Path, path: Path) -> str | None:
    with sqlite3.connect(data / "ppd.sqlite3") as conn:
        row = conn.execute("SELECT spec_id FROM files WHERE path = ?", (str(path),)).fetchone()
    return row[0] if row else None


def _lose_store(data: Path) -> None:
    for suffix in ("", "-wal", "-shm"):
        Path(f"{data / 'ppd.sqlite3'}{suffix}").unlink(missing_ok=True)


def test_every_spec_that_patches_is_kept_in_the_vault_and_a_rebuild_gives_it_back(
    ppd_env: dict[str, Path],
) -> None:
    data, castle = ppd_env["data"], make_shoot(ppd_env["outbox"] / "castle", 3)
    specs = data / "vault" / "specs"
    assert said("poison", str(castle), *FLAGS)[0] == 0
    chosen = _spec_id(data, "castle")
    assert chosen is not None and [p.name for p in specs.iterdir()] == [f"{chosen}.json"]  # before: none
    assert (specs / f"{chosen}.json").stat().st_mode & 0o777 == 0o600
    code, text = said("dataset", "set", "castle", *FLAGS, "--design", "roaming", "--reprotect")
    assert code == 0, text
    marked = _spec_id(data, "castle")
    assert marked != chosen and (specs / f"{marked}.json").is_file()  # the re-protect's spec kept too

    _lose_store(data)
    code, text = said("store", "rebuild")
    assert code == 0 and "not recovered" not in text, text
    assert _spec_id(data, "castle") == marked
    code, text = said("dataset", "show", "castle")
    assert code == 0 and f"castle at {castle} spec {marked}: random_blocks" in text, text
    make_image(castle / "late.png", 9)  # the next photo gets the dataset's very spec
    code, text = said("poison", str(castle))
    assert code == 0, text
    assert _file_spec(data, castle / "late.png") == marked


def test_a_spec_the_vault_never_kept_is_named_and_the_dataset_takes_no_other(
    ppd_env: dict[str, Path],
) -> None:
    data, castle = ppd_env["data"], make_shoot(ppd_env["outbox"] / "castle", 3)
    assert said("poison", str(castle), *FLAGS)[0] == 0
    chosen = _spec_id(data, "castle")
    assert chosen is not None
    shutil.rmtree(data / "vault" / "specs", ignore_errors=True)  # a vault kept by an earlier ppd: no spec
    _lose_store(data)

    code, text = said("store", "rebuild")
    assert code == 1, text  # before: 0, "1 spec(s) not recovered", naming no dataset
    assert "1 spec(s) not recovered: dataset(s) castle" in text, text
    lost = (
        f"castle: spec not recovered: its patched files carry spec {chosen}, which `ppd store rebuild` found "
        "nowhere, so its new photos are refused: `ppd dataset set castle` with the flags it was made with "
        "(--design, --patch-size, --position, ...) gives it back, or `ppd dataset set castle --reprotect` "
        "marks all its files again with the config's spec; then `ppd poison` of its folder patches those "
        "refused"
    )
    assert f"ppd: error: {lost}" in text, text
    code, text = said("dataset", "show", "castle")  # before: "spec None: None", then "no spec yet"
    assert code == 0 and f"castle at {castle} {lost[len('castle: ') :]}" in text, text
    code, text = said("status", "castle")
    assert f"spec {chosen}: not recovered" in text and lost in text, text
    assert "--reprotect` gives them its spec" not in text, text  # before: advised, over the creator's design

    late = make_image(castle / "late.png", 9)
    before = _sha(late)
    code, text = said("poison", str(castle), "--dry-run")
    assert code == 1 and "would patch 0, unchanged 3, skipped 0, failed 1" in text, text  # before: patch 1
    code, text = said("poison", str(castle))
    assert code == 1 and "patched 0, unchanged 3, skipped 0, failed 1" in text, text
    assert f"ppd: failed: {late}: dataset 'castle': spec not recovered" in text, text
    assert _sha(late) == before and _spec_id(data, "castle") is None  # before: patched with the default

    code, text = said("dataset", "set", "castle", "--patch-size", "0.05")  # not the flags it was made with
    assert code == 2 and "these flags make spec " in text and f"not {chosen}, the spec its patched" in text
    assert _spec_id(data, "castle") is None
    code, text = said("dataset", "set", "castle", *FLAGS)  # the very flags: the spec given back, free
    assert code == 0 and f"castle: spec {chosen} (" in text, text
    code, text = said("poison", str(castle))
    assert code == 0 and "patched 1, unchanged 3" in text, text
    assert _file_spec(data, late) == chosen


def test_a_spec_is_found_among_the_designs_in_any_corner_or_in_a_store_kept_aside(
    ppd_env: dict[str, Path],
) -> None:
    data, outbox = ppd_env["data"], ppd_env["outbox"]
    corner = make_shoot(outbox / "corner", 2)
    odd = make_shoot(outbox / "odd", 2)
    assert said("poison", str(corner), "--design", "watermark", "--position", "bottom-right")[0] == 0
    assert said("poison", str(odd), *FLAGS, "--seed", "7")[0] == 0
    ids = {name: _spec_id(data, name) for name in ("corner", "odd")}
    shutil.rmtree(data / "vault" / "specs", ignore_errors=True)
    aside = data / "ppd.sqlite3.before-rebuild-20260101T000000Z"  # as an earlier rebuild kept it
    shutil.copy(data / "ppd.sqlite3", aside)
    with sqlite3.connect(aside) as conn:
        conn.execute("DELETE FROM specs WHERE id = ?", (ids["corner"],))
    _lose_store(data)

    code, text = said("store", "rebuild")
    assert code == 0 and "not recovered" not in text, text  # before: 2 spec(s) not recovered
    assert {name: _spec_id(data, name) for name in ids} == ids
    assert {p.stem for p in (data / "vault" / "specs").iterdir()} == set(ids.values())  # kept for next time


def test_a_store_made_by_a_newer_ppd_is_said_so_and_not_rebuilt_unless_forced(
    ppd_env: dict[str, Path],
) -> None:
    data, castle = ppd_env["data"], make_shoot(ppd_env["outbox"] / "castle", 2)
    assert said("poison", str(castle))[0] == 0
    store = data / "ppd.sqlite3"
    with sqlite3.connect(store) as conn:
        conn.execute("UPDATE schema_version SET version = version + 1")
        newer = conn.execute("SELECT version FROM schema_version").fetchone()[0]
    kept = store.read_bytes()

    code, text = said("status")
    newer_said = (
        f"ppd: error: the store {store} was made by a newer ppd (schema version {newer}; this ppd "
        f"knows up to {newer - 1}): upgrade ppd to open it (`pipx upgrade patchpoison`"
    )
    assert code == 3 and text.startswith(newer_said), text
    code, text = said("store", "rebuild")
    assert code == 3 and "made by a newer ppd" in text and "leaves a newer store alone" in text, text
    assert "store rebuilt at" not in text and store.read_bytes() == kept  # before: "damaged", replaced
    code, text = said("store", "rebuild", "--force")
    assert code == 0 and "the newer store is kept at" in text, text


def test_a_dataset_whose_spec_was_lost_follows_its_moved_folder_and_stays_spec_less(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd dataset set NAME --root NEW` alone on such a dataset moved it, then exited 2 with "these flags
    make spec ..." (no flag was given): it set the config's spec (a diff review). --root moves it only."""
    data, castle = ppd_env["data"], make_shoot(ppd_env["outbox"] / "castle", 3)
    assert said("poison", str(castle), *FLAGS)[0] == 0
    shutil.rmtree(data / "vault" / "specs", ignore_errors=True)
    _lose_store(data)
    assert said("store", "rebuild")[0] == 1
    moved = castle.rename(tmp_path / "castle-2026")
    code, text = said("dataset", "set", "castle", "--root", str(moved))
    assert code == 0 and "castle: moved from" in text and "these flags" not in text, text
    assert "spec not recovered" in text and _spec_id(data, "castle") is None, text
