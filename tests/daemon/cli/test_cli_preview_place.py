"""Where `ppd preview` writes its picture (a black-box review, 2026-12-07): by default it went to the
working folder, often the photos' own; the next `ppd poison` patched the collage as a photo and the
clean original inside it would have been published. It now goes to ppd's cache folder unless --out
says otherwise, and --out among photos is refused before anything is written."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_image

runner = CliRunner()


def _pngs(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*.png"))


def test_the_preview_is_never_written_among_photos(
    tmp_path: Path, ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setenv("PPD_CACHE_DIR", str(cache))
    new, patched = tmp_path / "new", tmp_path / "patched"
    for folder in (new, patched):
        for i in range(3):
            make_image(folder / f"v{i}.png", i)
    (patched / "sub").mkdir()
    assert runner.invoke(app, ["poison", str(patched)]).exit_code == 0
    before = {f: _pngs(f) for f in (new, patched, ppd_env["outbox"])}

    monkeypatch.chdir(new)  # the working folder holds the photos: the default is not written here
    done = runner.invoke(app, ["preview", "v0.png", "--no-visibility"])
    assert done.exit_code == 0, done.output
    written = sorted((cache / "previews").rglob("*.png"))
    assert [p.name for p in written] == ["v0.png.ppd-preview.png"], written  # previews/FOLDER-HASH/
    assert written[0].parent.name.startswith("new-") and str(written[0]) in done.output.replace("\n", "")

    refused = [
        (new / "v1.png", new / "p.png"),  # beside the photo, not patched yet
        (patched / "v1.png", patched / "sub" / "p.png"),  # a dataset's folder, any depth
        (new / "v1.png", patched / "p.png"),  # another dataset's folder
        (new / "v1.png", ppd_env["outbox"] / "p.png"),  # the outbox
        (new / "v1.png", Path("p.png")),  # relative: the working folder, the photos'
    ]
    for photo, out in refused:
        result = runner.invoke(app, ["preview", str(photo), "--out", str(out), "--no-visibility"])
        assert result.exit_code == 2, (out, result.output)
        assert "shows the original" in result.output and len(result.output.strip().splitlines()) == 1
    assert {f: _pngs(f) for f in before} == before

    elsewhere = tmp_path / "previews" / "p.png"  # beside the folders, not in them: written
    ok = runner.invoke(app, ["preview", str(new / "v1.png"), "--out", str(elsewhere), "--no-visibility"])
    assert ok.exit_code == 0 and elsewhere.is_file(), ok.output
    assert os.path.getsize(elsewhere) > 0


def test_the_data_folder_takes_no_preview_and_keeps_experiments_plots(
    tmp_path: Path, ppd_env: dict[str, Path]
) -> None:
    """A picture in ppd's data folder made it look like a folder of photos: every command then refused
    it (exit 3), the daemon could not start (a black-box review: `ppd preview --out DATA/p.png`, and
    `ppd experiment`'s own tradeoff.png in its default folder, DATA/experiments/NAME)."""
    data = ppd_env["data"]
    make_image(tmp_path / "new" / "v0.png", 0)
    assert runner.invoke(app, ["status"]).exit_code == 0  # the data folder made
    result = runner.invoke(app, ["preview", str(tmp_path / "new" / "v0.png"), "--out", str(data / "p.png"),
                                 "--no-visibility"])  # fmt: skip
    assert result.exit_code == 2 and "is inside ppd's data folder" in " ".join(result.output.split())
    assert not (data / "p.png").exists()
    plot = data / "experiments" / "castle" / "tradeoff.png"  # where `ppd experiment castle` writes it
    make_image(plot, 1)
    result = runner.invoke(app, ["status"])
    assert result.exit_code == 0, result.output
    make_image(data / "elsewhere" / "p.png", 2)  # a picture anywhere else there still stops ppd
    result = runner.invoke(app, ["status"])
    assert result.exit_code == 3 and "holds photos or videos" in " ".join(result.output.split())


def test_a_bad_display_width_is_refused_before_writing(
    tmp_path: Path, ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PPD_CACHE_DIR", str(tmp_path / "cache"))
    make_image(tmp_path / "shoot" / "v0.png", 0)
    out = tmp_path / "p.png"
    result = runner.invoke(app, ["preview", str(tmp_path / "shoot" / "v0.png"), "--out", str(out),
                                 "--display-width", "0"])  # fmt: skip
    assert result.exit_code == 2 and "--display-width" in result.output
    assert not out.exists() and not (tmp_path / "cache" / "previews").exists()


def test_previews_of_files_of_one_name_in_other_folders_are_kept_apart(
    tmp_path: Path, ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A/0000.png's preview and B/0000.png's both went to previews/0000.ppd-preview.png, the second over
    the first (a third black-box review, S9); so did two folders of one name (2024/A and 2025/A)."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("PPD_CACHE_DIR", str(cache))
    photos = [make_image(tmp_path / folder / "0000.png", seed)
              for seed, folder in enumerate(("A", "B", "2025/A"))]  # fmt: skip
    said: list[Path] = []
    for photo in photos:
        done = runner.invoke(app, ["preview", str(photo), "--no-visibility"])
        assert done.exit_code == 0, done.output
        line = " ".join(done.output.split())
        said.append(Path(line.split("preview written to ")[1].split(" mark at ")[0]))
    assert len(set(said)) == 3 and all(p.is_file() for p in said), said
    assert [p.parent.name.split("-")[0] for p in said] == ["A", "B", "A"]  # the folder's name says whose
    assert len({p.read_bytes() for p in said}) == 3  # none overwrote another
