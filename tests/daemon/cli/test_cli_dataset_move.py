"""`ppd dataset set NAME --root NEWFOLDER` moves a dataset whose folder the user moved (a black-box
review: the option was silently ignored, exit 0, and the status advice for a moved folder,
`ppd poison NEWFOLDER`, made a second dataset while the old one kept its name and the advice)."""

from __future__ import annotations

import hashlib
import json
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_image, make_shoot

runner = CliRunner()


def said(*args: str) -> str:
    result = runner.invoke(app, list(args))
    return " ".join(result.output.split())


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_moved_folder_is_adopted_by_dataset_set_root(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    sets = tmp_path / "sets"
    shoot = sets / "n2"
    originals = {i: _sha(make_image(shoot / f"v{i}.png", i)) for i in range(3)}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["dataset", "set", "n2", "--patch-size", "8%"]).exit_code == 2  # spec kept
    spec = json.loads(runner.invoke(app, ["dataset", "show", "n2", "--json"]).stdout)["spec_id"]
    moved = sets / "n2_new"
    shoot.rename(moved)
    advice = said("status")
    assert f"n2: folder gone; its patched files are in {moved} (moved?): " in advice, advice
    assert f"`ppd dataset set n2 --root {shlex.quote(str(moved))}` moves the dataset there" in advice, advice

    result = runner.invoke(app, ["dataset", "set", "n2", "--root", str(moved)])  # the advice, as given
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert f"n2: moved from {shoot} to {moved} (3 files' records moved with it)" in text, text
    info = json.loads(runner.invoke(app, ["dataset", "show", "n2", "--json"]).stdout)
    assert info["root"] == str(moved) and info["spec_id"] == spec, info
    text = said("status", "n2")
    assert "folder gone" not in text and "is gone" not in text, text
    assert "files 3: patched 3" in text, text
    assert "folder gone" not in said("status") and "n2_new" not in [
        d["name"] for d in json.loads(runner.invoke(app, ["status", "--json"]).stdout)["datasets"]
    ]
    assert "patched 0, unchanged 3" in said("poison", str(moved))  # its own folder now, nothing twice
    restored = runner.invoke(app, ["restore", "n2"])
    assert restored.exit_code == 0 and "restored 3" in restored.output, restored.output
    assert {i: _sha(moved / f"v{i}.png") for i in range(3)} == originals


def test_dataset_set_root_refuses_what_is_not_a_move(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    sets = tmp_path / "sets"
    for name in ("a", "b"):
        assert runner.invoke(app, ["poison", str(make_shoot(sets / name, 2))]).exit_code == 0
    (sets / "elsewhere").mkdir()

    def refused(*args: str) -> str:
        result = runner.invoke(app, ["dataset", "set", *args])
        assert result.exit_code == 2, result.output
        shown = json.loads(runner.invoke(app, ["dataset", "show", "a", "--json"]).stdout)
        assert shown["root"] == str(sets / "a")  # unchanged
        return " ".join(result.output.split())

    still = refused("a", "--root", str(sets / "elsewhere"))  # its folder still there: not a move
    assert f"the folder of dataset 'a', {sets / 'a'}, is still there" in still, still
    assert f"`ppd poison {shlex.quote(str(sets / 'elsewhere'))}` makes a new dataset" in still, still
    (sets / "a").rename(sets / "a_moved")
    assert f"--root {sets / 'nowhere'}: no such folder" in refused("a", "--root", str(sets / "nowhere"))
    assert "is the folder of dataset 'b'; a folder is one" in refused("a", "--root", str(sets / "b"))


def test_a_moved_folder_made_its_own_dataset_is_said_so(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The old advice followed: `ppd poison NEWFOLDER` made dataset n2_new; status repeated the advice."""
    sets = tmp_path / "sets"
    assert runner.invoke(app, ["poison", str(make_shoot(sets / "n2", 2))]).exit_code == 0
    (sets / "n2").rename(sets / "n2_new")
    assert runner.invoke(app, ["poison", str(sets / "n2_new")]).exit_code == 0
    text = said("status", "n2")
    assert f"its patched files are in {sets / 'n2_new'}, now dataset 'n2_new'" in text, text
    assert "moves the dataset there" not in said("status")
    # its files seen beside it, in a folder made a dataset by name (no run carried their rows)
    assert runner.invoke(app, ["poison", str(make_shoot(sets / "n4", 2))]).exit_code == 0
    (sets / "n4").rename(sets / "n4_new")
    assert runner.invoke(app, ["dataset", "set", "n4_new", "--root", str(sets / "n4_new")]).exit_code == 0
    text = said("status", "n4")
    assert f"its patched files are in {sets / 'n4_new'}, now dataset 'n4_new'" in text, text


def test_a_new_dataset_without_its_folder_is_refused_and_one_set_up_early_is_not_called_gone(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A fifth black-box review: `ppd dataset set gardn --design paper` (the dataset is 'garden') made
    a dataset of OUTBOX/gardn, a folder that never existed, exit 0, and `ppd status` then called its
    folder "gone, moved or deleted"; a name close to a dataset's was refused as a typo. A seventh (F4):
    any other new name still made one (`ppd dataset set studio` before the shoot was copied), and
    `ppd poison` of the real studio folder was then refused, its name taken. Every new dataset without
    its folder is refused now (one line, exit 2); its folder made first, or --root, sets it up."""
    shoot = tmp_path / "garden"
    make_shoot(shoot, 2)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    typo = runner.invoke(app, ["dataset", "set", "gardn", "--design", "paper"])
    assert typo.exit_code == 2 and "did you mean 'garden'?" in " ".join(typo.output.split()), typo.output
    new = runner.invoke(app, ["dataset", "set", "studio", "--design", "paper"])
    text = " ".join(new.output.split())
    folder = ppd_env["outbox"] / "studio"
    assert new.exit_code == 2 and f"no dataset 'studio'; a new dataset of that name needs its folder: make " \
        f"{folder} first, or give --root" in text, text  # fmt: skip
    nowhere = runner.invoke(app, ["dataset", "set", "studio", "--root", str(tmp_path / "nowhere")])
    assert nowhere.exit_code == 2 and "no such folder" in " ".join(nowhere.output.split()), nowhere.output
    assert [d["name"] for d in json.loads(runner.invoke(app, ["status", "--json"]).stdout)["datasets"]] == [
        "garden"
    ]
    studio = make_shoot(tmp_path / "studio", 2)  # the real shoot, under the name refused above
    assert runner.invoke(app, ["poison", str(studio)]).exit_code == 0
    (ppd_env["outbox"] / "gardn").mkdir()  # its folder made first: a new dataset is meant
    assert runner.invoke(app, ["dataset", "set", "gardn", "--design", "paper"]).exit_code == 0
    (ppd_env["outbox"] / "gardn").rmdir()  # and taken away before any file came
    status = said("status")
    assert "set up before their folder, which does not exist yet (gardn)" in status, status
    assert "gone, moved or deleted" not in status, status


def test_a_spec_set_before_the_first_file_keeps_the_configs_publish_folder(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd dataset set garden --design paper` on the outbox's garden folder before its first photo is
    patched (the flow F4's refusal leaves open): the row it made had no publish folder, so the config's
    `[datasets.garden] publish_dir` was lost and the patched photos stayed in the outbox (found with F4)."""
    pub = tmp_path / "site" / "garden"
    (ppd_env["config"] / "config.toml").write_text(f'[datasets.garden]\npublish_dir = "{pub}"\n')
    garden = make_shoot(ppd_env["outbox"] / "garden", 2)
    names = sorted(p.name for p in garden.iterdir())
    result = runner.invoke(app, ["dataset", "set", "garden", "--design", "paper"])
    assert result.exit_code == 0 and "garden: spec" in " ".join(result.output.split()), result.output
    assert f"publish folder: {pub}" in said("dataset", "show", "garden")
    assert runner.invoke(app, ["poison", str(garden)]).exit_code == 0
    assert sorted(p.name for p in pub.iterdir()) == names and not any(garden.iterdir())
    shown = json.loads(runner.invoke(app, ["dataset", "show", "garden", "--json"]).stdout)
    assert shown["spec"]["pattern"] == "checkerboard"


def test_a_folder_of_the_same_name_in_another_outbox_is_not_merged(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A fifth black-box review: a second `ppd watch` on the same data folder, watching outbox ob2, took
    ob2/castle into dataset 'castle', ob1/castle (the first outbox's): the dataset's folder moved to
    ob2/castle and ob1's patched photos were called "patched copies". The daemon's file now fails with
    the reason (nothing written, the dataset where it was), as `ppd poison` refused it already."""
    from daemon.context import AppContext
    from daemon.protect.one_file import protect_file

    ob1, ob2 = tmp_path / "ob1", tmp_path / "ob2"
    make_shoot(ob1 / "castle", 2)
    make_shoot(ob2 / "castle", 2)
    assert runner.invoke(app, ["poison", str(ob1 / "castle")], env={"PPD_OUTBOX": str(ob1)}).exit_code == 0
    monkeypatch.setenv("PPD_OUTBOX", str(ob2))
    photo = sorted((ob2 / "castle").iterdir())[0]
    before = _sha(photo)
    ctx = AppContext.open()
    try:
        outcome = protect_file(photo, ctx)  # what `ppd watch` on ob2 does with a new photo there
        assert outcome.state == "failed", outcome
        assert f"dataset 'castle' already belongs to {ob1 / 'castle'}" in outcome.reason, outcome.reason
        assert ctx.store.dataset("castle")["root"] == str(ob1 / "castle")
    finally:
        ctx.close()
    assert _sha(photo) == before
    refused = runner.invoke(app, ["poison", str(ob2 / "castle")])  # the CLI, as before
    assert refused.exit_code == 2 and "already belongs to" in refused.output, refused.output
