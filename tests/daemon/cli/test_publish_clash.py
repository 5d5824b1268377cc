"""A publish folder already holding a photo under a name: ppd never moves another file over it. A diff
review: a photo moved in from another dataset (re-marked, then published) and a new photo dropped under
a published photo's name were each moved over it, and the first photo was gone from the publish folder,
its original given back by no restore. Now the move refuses the name (one line, the file stays patched
where it is), a moved-in file does not take the published photo's row, and a restore that cannot put
the original back leaves the published copy. Real shoots, store, vault and `ppd poison`/`ppd restore`."""

from __future__ import annotations

import errno
import hashlib
import os
from pathlib import Path

import pytest

from daemon.fsops import move_out, open_dir
from daemon.store import Store
from testkit.cli import said
from testkit.photos import make_image


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _rows(data: Path) -> dict[str, dict]:
    store = Store(data / "ppd.sqlite3")
    try:
        return {r["path"]: r for name in ("X", "Y") for r in store.files(name)}
    finally:
        store.close()


def _published_y(outbox: Path, pub: Path) -> tuple[Path, str, str]:
    """Dataset Y (publish folder pub) with a.png patched and published: (Y's folder, the original's
    sha256, the published file's)."""
    y = outbox / "Y"
    make_image(y / "a.png", 2, (320, 240))
    original = _sha(y / "a.png")
    assert said("dataset", "set", "Y", "--publish-dir", str(pub))[0] == 0
    code, text = said("poison", str(y))
    assert code == 0 and (pub / "a.png").is_file() and not (y / "a.png").exists(), text
    return y, original, _sha(pub / "a.png")


def test_a_new_photo_under_a_published_name_is_patched_and_not_moved_over_it(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    pub = tmp_path / "pub"
    y, first, published = _published_y(ppd_env["outbox"], pub)
    make_image(y / "a.png", 5, (320, 240))  # another photo, the same name
    second = _sha(y / "a.png")
    code, text = said("poison", str(y))
    assert code == 1, text
    assert f"not moved to {pub}: another file is there under this name ({pub / 'a.png'})" in text, text
    assert _sha(pub / "a.png") == published  # the first photo, as published
    assert _sha(y / "a.png") not in (second, published)  # the new one patched, where it is
    # the first photo's original is named by the restore (saved over), the new one's put back
    code, text = said("restore", "Y")
    assert _sha(y / "a.png") == second, text
    assert first in text.replace(" ", ""), text  # its vault copy named
    assert (ppd_env["data"] / "vault" / first[:2] / first).is_file()


def test_a_photo_moved_in_under_a_published_name_keeps_both_rows_and_restore_removes_nothing(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    outbox, data, pub = ppd_env["outbox"], ppd_env["data"], tmp_path / "pub"
    make_image(outbox / "X" / "a.png", 1, (320, 240))
    assert said("poison", str(outbox / "X"))[0] == 0
    y, _, published = _published_y(outbox, pub)
    before = _rows(data)
    moved = (outbox / "X" / "a.png").rename(y / "a.png")
    marked = _sha(moved)
    code, text = said("poison", str(y))
    assert code == 1, text
    assert f"but dataset 'Y' published another photo under this name ({pub / 'a.png'})" in text, text
    assert _rows(data) == before  # X's row is X's, Y's still its published photo's
    assert _sha(pub / "a.png") == published and _sha(moved) == marked
    code, text = said("restore", "Y")
    assert code == 1 and "nor removing the published copy" in text, text
    assert _sha(pub / "a.png") == published and _sha(moved) == marked  # nothing removed, nothing written


def test_move_out_never_replaces_a_file(tmp_path: Path) -> None:
    """On one filesystem (rename) and across two (the copy): FileExistsError, both files as they were.
    /dev/shm is another filesystem than the temporary folder where the machine has one."""
    places = [tmp_path / "pub"]
    shm = Path("/dev/shm")
    if shm.is_dir() and os.access(shm, os.W_OK) and os.stat(shm).st_dev != os.stat(tmp_path).st_dev:
        places.append(Path(__import__("tempfile").mkdtemp(dir=shm)))
    for where in places:
        src = tmp_path / "out"
        src.mkdir(exist_ok=True)
        (src / "a.jpg").write_bytes(b"new photo")
        where.mkdir(exist_ok=True)
        (where / "a.jpg").write_bytes(b"published photo")
        fd = open_dir(src)
        try:
            with pytest.raises(FileExistsError) as caught:
                move_out(fd, "a.jpg", where / "a.jpg")
            assert caught.value.errno == errno.EEXIST
            assert (where / "a.jpg").read_bytes() == b"published photo"
            assert (src / "a.jpg").read_bytes() == b"new photo"
            assert sorted(p.name for p in where.iterdir()) == ["a.jpg"]  # no temporary left
            assert move_out(fd, "a.jpg", where / "b.jpg") == where / "b.jpg"  # a free name: moved
            assert not (src / "a.jpg").exists() and (where / "b.jpg").read_bytes() == b"new photo"
        finally:
            os.close(fd)
