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
