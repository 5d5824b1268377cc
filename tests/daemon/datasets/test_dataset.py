"""daemon.datasets.dataset.attribute: the one rule for which dataset a file or folder belongs to, on a real
store and real folders."""

from __future__ import annotations

from pathlib import Path

import pytest

from daemon.context import AppContext
from daemon.datasets.dataset import DEFAULT_DATASET, DatasetConflict, attribute, ensure_dataset


@pytest.fixture
def ctx(ppd_env: dict[str, Path]) -> AppContext:
    context = AppContext.open()
    yield context
    context.close()


def _file(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x")
    return path


def test_inside_the_outbox_files_and_folders_take_their_first_level_folder(ctx: AppContext) -> None:
    outbox = ctx.paths.outbox.absolute()
    deep = _file(outbox / "shoot" / "raw" / "a.jpg")
    assert attribute(ctx, deep) == ("shoot", outbox / "shoot")
    assert attribute(ctx, deep.parent) == ("shoot", outbox / "shoot")  # a subfolder: still its dataset
    assert attribute(ctx, outbox / "shoot") == ("shoot", outbox / "shoot")
    loose = _file(outbox / "b.jpg")
    assert attribute(ctx, loose) == (DEFAULT_DATASET, outbox)


def test_outside_the_outbox_a_folder_is_named_after_itself_a_file_after_its_parent(
    ctx: AppContext, tmp_path: Path
) -> None:
    castle = tmp_path / "shoots" / "castle"
    photo = _file(castle / "sub" / "a.jpg")
    assert attribute(ctx, castle) == ("castle", castle)
    assert attribute(ctx, castle / "sub") == ("sub", castle / "sub")
    assert attribute(ctx, photo) == ("sub", castle / "sub")


def test_folder_flag_overrides_what_the_file_system_says(ctx: AppContext) -> None:
    outbox = ctx.paths.outbox.absolute()
    (outbox / "shoot").mkdir()
    # the daemon sees names, not folders: a first-level name is a file of "default"
    assert attribute(ctx, outbox / "shoot", folder=False) == (DEFAULT_DATASET, outbox)
    assert attribute(ctx, outbox / "shoot", folder=True) == ("shoot", outbox / "shoot")


def test_explicit_name_new_dataset_takes_the_folder_or_the_files_parent(
    ctx: AppContext, tmp_path: Path
) -> None:
    photo = _file(tmp_path / "here" / "a.jpg")
    assert attribute(ctx, photo, "trip") == ("trip", photo.parent)
    assert attribute(ctx, photo.parent, "trip") == ("trip", photo.parent)
    inside = _file(ctx.paths.outbox.absolute() / "shoot" / "raw" / "b.jpg")
    assert attribute(ctx, inside.parent, "named") == ("named", inside.parent)


def test_explicit_name_keeps_a_known_datasets_stored_root(ctx: AppContext, tmp_path: Path) -> None:
    root = tmp_path / "shoots" / "castle"
    photo = _file(root / "raw" / "a.jpg")
    ensure_dataset(ctx, "castle", root, None)
    assert attribute(ctx, photo, "castle") == ("castle", root)
    assert attribute(ctx, photo.parent, "castle") == ("castle", root)
    assert attribute(ctx, root, "castle") == ("castle", root)
    elsewhere = _file(tmp_path / "elsewhere" / "b.jpg")
    with pytest.raises(DatasetConflict, match="already belongs to"):
        attribute(ctx, elsewhere, "castle")
    # without a name the location decides, whatever the store holds
    assert attribute(ctx, elsewhere) == ("elsewhere", elsewhere.parent)


def test_outbox_dataset_by_name_keeps_its_root(ctx: AppContext) -> None:
    outbox = ctx.paths.outbox.absolute()
    photo = _file(outbox / "shoot" / "raw" / "a.jpg")
    ensure_dataset(ctx, "shoot", outbox / "shoot", None)
    assert attribute(ctx, photo, "shoot") == ("shoot", outbox / "shoot")
