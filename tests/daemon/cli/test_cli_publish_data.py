"""ppd's data folder (the vault of originals, the seal key, restore's kept copies) is never where files
get published (a second black-box review): `ppd dataset set --publish-dir` took a folder holding it,
and data/displaced itself, and `ppd poison` patched a folder holding it in place."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_image, make_shoot

runner = CliRunner()


def test_a_publish_folder_never_holds_or_sits_in_the_data_folder(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 2)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    for folder in (tmp_path, ppd_env["data"] / "displaced"):
        result = runner.invoke(app, ["dataset", "set", "shoot", "--publish-dir", str(folder)])
        assert result.exit_code == 2 and "data folder" in result.output, result.output
    shown = runner.invoke(app, ["dataset", "show", "shoot", "--json"]).stdout
    assert '"publish_dir": null' in shown
    fine = runner.invoke(app, ["dataset", "set", "shoot", "--publish-dir", str(tmp_path / "pub")])
    assert fine.exit_code == 0, fine.output


def test_poison_refuses_a_folder_that_holds_the_data_folder(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    make_image(tmp_path / "v0.png", 0)  # tmp_path holds data/: patched in place, published with it
    before = (tmp_path / "v0.png").read_bytes()
    result = runner.invoke(app, ["poison", str(tmp_path)])
    assert result.exit_code == 3 and "vault of originals" in result.output, result.output
    assert (tmp_path / "v0.png").read_bytes() == before
    out = runner.invoke(app, ["poison", str(tmp_path), "--out", str(tmp_path.parent / "copies")])
    assert out.exit_code == 0, out.output  # copies elsewhere publish nothing of ppd's


def test_a_publish_folder_inside_the_outbox_is_refused(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A black-box review (s5 F6): a publish folder inside the outbox was taken; the daemon then took the
    files it published there in as a new dataset ('public') that `ppd status` called not patched yet.
    Refused as `--out` inside a dataset is, before anything is written (the refusal made the dataset)."""
    outbox = ppd_env["outbox"]
    (outbox / "castle").mkdir(parents=True)
    (tmp_path / "link").symlink_to(outbox / "castle")
    for folder in (outbox / "public", outbox, tmp_path / "link" / "pub"):
        result = runner.invoke(app, ["dataset", "set", "castle", "--publish-dir", str(folder)])
        said = " ".join(result.output.split())
        assert result.exit_code == 2 and f"is inside the outbox {outbox}" in said, result.output
        assert said.startswith(f"ppd: error: --publish-dir {folder}")
        assert said.endswith("choose another folder")
    assert "castle" not in runner.invoke(app, ["status"]).output
    fine = runner.invoke(app, ["dataset", "set", "castle", "--publish-dir", str(tmp_path / "pub")])
    assert fine.exit_code == 0, fine.output


@pytest.mark.parametrize("table", ["", "[datasets.castle]\n"])
def test_a_configured_publish_folder_inside_the_outbox_stops_every_command(
    ppd_env: dict[str, Path], table: str
) -> None:
    """config.toml's publish_dir (or a dataset's) inside the outbox: one line naming the key, exit 2,
    `ppd watch` included (a real process), before it watches anything."""
    import subprocess
    import sys

    from testkit.reliability import REPO

    config, outbox = ppd_env["config"] / "config.toml", ppd_env["outbox"]
    config.write_text(f'{table}publish_dir = "{outbox / "public"}"\n')
    key = "datasets.castle.publish_dir" if table else "publish_dir"
    status = runner.invoke(app, ["status"])
    assert status.exit_code == 2, status.output
    assert " ".join(status.output.split()) == (
        f"ppd: error: {config}: {key}: {outbox / 'public'} is inside the outbox {outbox}, whose new files "
        "ppd patches as a dataset; choose a folder outside it"
    )
    watch = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "watch", "--no-verify"], cwd=REPO, capture_output=True,
        text=True, timeout=60,
    )  # fmt: skip
    assert watch.returncode == 2 and f"{key}: " in watch.stderr and len(watch.stderr.splitlines()) == 1


def test_a_publish_folder_in_or_holding_a_dataset_folder_or_the_outbox_is_refused(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A diff review (F3): `dataset set castle --root castle --publish-dir castle/public` was taken, and
    `ppd restore` then wrote the originals into castle/public; a folder holding the outbox was taken too.
    Refused with one line, exit 2, before anything is written (castle is no dataset after)."""
    photos = tmp_path / "photos"
    castle, garden = make_shoot(photos / "castle", 2), make_shoot(tmp_path / "garden", 1)
    assert runner.invoke(app, ["poison", str(garden)]).exit_code == 0
    monkeypatch.setenv("PPD_OUTBOX", str(tmp_path / "box" / "outbox"))  # a folder holding it, not data/
    refused = {
        castle / "public": "is inside the folder of dataset 'castle',",
        castle: "is inside the folder of dataset 'castle',",
        garden / "pub": "is inside the folder of dataset 'garden',",
        photos: "holds the folder of dataset 'castle',",
        tmp_path / "box": f"holds the outbox {tmp_path / 'box' / 'outbox'}",
    }
    for folder, why in refused.items():
        args = ["dataset", "set", "castle", "--root", str(castle), "--publish-dir", str(folder)]
        result = runner.invoke(app, args)
        said = " ".join(result.output.split())
        assert result.exit_code == 2 and why in said, result.output
        assert said.startswith(f"ppd: error: --publish-dir {folder}") and len(result.output.splitlines()) <= 3
    assert "castle" not in runner.invoke(app, ["status"]).output
    fine = runner.invoke(app, ["dataset", "set", "castle", "--root", str(castle), "--publish-dir",
                               str(tmp_path / "pub")])  # fmt: skip
    assert fine.exit_code == 0, fine.output


def test_a_publish_folder_stored_inside_the_dataset_never_gets_the_originals(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A store from before the refusal: castle's publish folder is castle/public. A second `ppd poison
    castle` leaves the published copies as they are (it carried their rows over as 'moved' there), and
    `ppd restore castle` puts the originals back where they were patched, none into castle/public."""
    from daemon.context import AppContext

    castle = make_shoot(tmp_path / "castle", 2)
    originals = {p.name: p.read_bytes() for p in castle.iterdir()}
    assert runner.invoke(app, ["dataset", "set", "castle", "--root", str(castle)]).exit_code == 0
    ctx = AppContext.open()
    try:
        ctx.store.set_dataset_publish_dir("castle", castle / "public")  # as `dataset set` took it before
    finally:
        ctx.close()
    first = runner.invoke(app, ["poison", str(castle)])
    assert first.exit_code == 0 and sorted(p.name for p in (castle / "public").iterdir()) == sorted(originals)
    again = runner.invoke(app, ["poison", str(castle)])
    assert again.exit_code == 0, again.output
    assert f"left 2 file(s) in {castle / 'public'}" in " ".join(again.output.split()), again.output
    assert "moved from" not in again.output
    restored = runner.invoke(app, ["restore", "castle"])
    assert restored.exit_code == 0, restored.output
    for name, data in originals.items():
        assert (castle / name).read_bytes() == data
        assert not (castle / "public" / name).exists() or (castle / "public" / name).read_bytes() != data


def test_a_configured_publish_folder_in_a_dataset_folder_is_refused(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """config.toml's publish_dir inside a dataset's folder: a new dataset there is refused before it is
    made (exit 2); a stored one stops every command with one line naming the key, as the outbox does."""
    castle = make_shoot(tmp_path / "castle", 1)
    config = ppd_env["config"] / "config.toml"
    config.write_text(f'publish_dir = "{castle / "public"}"\n')
    new = runner.invoke(app, ["poison", str(castle)])
    said = " ".join(new.output.split())
    why = f"{config}: publish_dir: {castle / 'public'} is inside the folder of dataset 'castle',"
    assert new.exit_code == 2 and why in said, new.output
    assert "castle" not in runner.invoke(app, ["status"]).output  # refused before the dataset was made
    unpatched = make_shoot(tmp_path / "again", 1) / "v0.png"
    assert (castle / "v0.png").read_bytes() == unpatched.read_bytes()
    config.write_text("")
    assert runner.invoke(app, ["poison", str(castle)]).exit_code == 0
    config.write_text(f'publish_dir = "{castle / "public"}"\n')
    status = runner.invoke(app, ["status"])
    assert status.exit_code == 2 and " ".join(status.output.split()).startswith(
        f"ppd: error: {config}: publish_dir: {castle / 'public'} is inside the folder of dataset 'castle',"
    ), status.output


def test_a_failed_publish_says_where_the_file_was_left(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A diff review (F9): a move that fails said 'left in the outbox' for a dataset patched in place
    outside it; it says the file's folder."""
    castle = make_shoot(tmp_path / "castle", 1)
    (tmp_path / "blocker").write_text("a file where the publish folder's parent should be")
    pub = tmp_path / "blocker" / "pub"
    assert runner.invoke(app, ["dataset", "set", "castle", "--root", str(castle), "--publish-dir",
                               str(pub)]).exit_code == 0  # fmt: skip
    result = runner.invoke(app, ["poison", str(castle)])
    said = " ".join(result.output.split())
    assert result.exit_code == 1 and f"not moved to {pub}" in said, result.output
    assert f"left in {castle}, moved at the next run" in said and "outbox" not in said, result.output


def test_a_dataset_of_the_home_folder_leaves_its_subfolders_free_to_publish_to(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A dataset whose folder is the home folder holds the files right in it only (as `ppd poison`
    attributes them): ~/www stays a publish folder, for config.toml and for `dataset set`."""
    home = tmp_path / "home"
    monkeypatch.setenv("HOME", str(home))
    make_image(home / "v0.png", 0)
    assert runner.invoke(app, ["poison", str(home), "--dataset", "athome"]).exit_code == 0
    (ppd_env["config"] / "config.toml").write_text(f'publish_dir = "{home / "www"}"\n')
    assert runner.invoke(app, ["status"]).exit_code == 0
    castle = make_shoot(tmp_path / "castle", 1)
    fine = runner.invoke(app, ["dataset", "set", "castle", "--root", str(castle), "--publish-dir",
                               str(home / "www" / "castle")])  # fmt: skip
    assert fine.exit_code == 0, fine.output
