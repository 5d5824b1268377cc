"""ppd's data folder holds the vault of originals: it is refused (one line, exit 3, nothing made or
changed) where they would be published or mixed with photos. A black-box review: PPD_DATA_DIR inside
the outbox put the originals there; set to a dataset's folder it made that folder 0700; set to a
photo, it made the photo 0700 and then failed."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.paths import AppPaths
from poisoner.errors import PpdError

runner = CliRunner()


def _paths(tmp_path: Path, data: Path) -> AppPaths:
    env = {"PPD_DATA_DIR": str(data), "PPD_CONFIG_DIR": str(tmp_path / "config"),
           "PPD_OUTBOX": str(tmp_path / "outbox"), "PPD_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    return AppPaths.from_env(env)


def _shoot(tmp_path: Path) -> Path:
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    Image.new("RGB", (64, 48), (90, 90, 90)).save(shoot / "a.jpg")
    return shoot


@pytest.mark.parametrize("where", ["outbox", "photos", "photo", "day folders", "raw files"])
def test_a_data_folder_where_originals_would_be_published_is_refused(tmp_path: Path, where: str) -> None:
    shoot = _shoot(tmp_path)
    photo = shoot / "a.jpg"
    if where == "day folders":  # a shoot whose photos are in subfolders only (a diff review)
        (shoot / "day1").mkdir()
        photo = photo.rename(shoot / "day1" / "a.jpg")
    if where == "raw files":  # formats ppd cannot protect are photos all the same
        photo = photo.rename(shoot / "a.dng")
    data = {"outbox": tmp_path / "outbox" / "data", "photo": photo}.get(where, shoot)
    before = {p: os.stat(p).st_mode for p in (shoot, photo)}
    paths = _paths(tmp_path, data)
    with pytest.raises(PpdError, match="cannot hold the vault of originals"):
        paths.ensure()
    assert {p: os.stat(p).st_mode for p in before} == before  # nothing made private
    assert not (tmp_path / "outbox" / "data").exists() and not (shoot / "vault").exists()


def test_the_command_says_it_in_one_line_with_exit_3(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    shoot = _shoot(tmp_path)
    places = {"PPD_DATA_DIR": shoot, "PPD_CONFIG_DIR": tmp_path / "config", "PPD_OUTBOX": tmp_path / "outbox",
              "PPD_CACHE_DIR": tmp_path / "cache"}  # fmt: skip
    for var, value in places.items():
        monkeypatch.setenv(var, str(value))
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 3, result.output
    assert "holds photos or videos (a.jpg)" in " ".join(result.output.split())
    assert stat.S_IMODE(os.stat(shoot).st_mode) != 0o700


def test_a_data_folder_of_ppds_own_is_kept(tmp_path: Path) -> None:
    paths = _paths(tmp_path, tmp_path / "data")
    paths.ensure()
    (tmp_path / "data" / "ppd.sqlite3").write_bytes(b"")
    paths.ensure()  # its own files are no photos
    assert paths.vault_dir.is_dir()


def test_a_data_folder_inside_a_publish_folder_is_refused(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The config names the folders ppd publishes to; the vault of originals is never inside one (a
    diff review: only the outbox was checked, before the config was read)."""
    from daemon.context import AppContext

    www = tmp_path / "www"
    (ppd_env["config"] / "config.toml").write_text(f'publish_dir = "{www}"\n')
    monkeypatch.setenv("PPD_DATA_DIR", str(www / "ppd-data"))
    with pytest.raises(PpdError, match="inside the publish folder"):
        AppContext.open()
    assert not (www / "ppd-data").exists()  # nothing made there
