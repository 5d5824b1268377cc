"""A photo moved or copied into a dataset with a publish folder from a dataset of another spec is marked
again with this one's (daemon.protect.remark), then published as every patched file of the dataset is. A
diff review: the re-marked file stayed in the outbox while the dataset's other files were published. A
publish folder that refuses the move is a failure recorded like any other, and the next run moves the
file. Real shoots, a real store and vault, `ppd poison` and a real `ppd watch`."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from daemon.store import Store
from testkit.cli import said
from testkit.daemon_proc import start_daemon, stop_daemon, wait_for
from testkit.photos import make_image, make_shoot


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _row(data: Path, path: Path) -> dict:
    store = Store(data / "ppd.sqlite3")
    try:
        return store.file(path) or {}
    finally:
        store.close()


def _spec_id(name: str) -> str:
    code, text = said("dataset", "show", name, "--json")
    assert code == 0, text
    return str(json.loads(text)["spec_id"])


def _shoot_and_published_papers(outbox: Path, pub: Path) -> tuple[Path, Path]:
    """shoot (the default spec, kept in the outbox) and papers (the paper design, published to pub),
    both patched."""
    shoot = make_shoot(outbox / "shoot", 3)
    papers = outbox / "papers"
    make_image(papers / "p0.png", 30)
    assert said("dataset", "set", "papers", "--design", "paper", "--publish-dir", str(pub))[0] == 0
    for folder in (shoot, papers):
        code, text = said("poison", str(folder))
        assert code == 0, text
    assert (pub / "p0.png").is_file() and not (papers / "p0.png").exists()  # papers' own file: published
    return shoot, papers


def test_a_re_marked_photo_is_published_with_its_dataset(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    data, pub = ppd_env["data"], tmp_path / "pub"
    shoot, papers = _shoot_and_published_papers(ppd_env["outbox"], pub)
    moved = (shoot / "v1.png").rename(papers / "moved.png")
    copied = papers / "copied.png"
    copied.write_bytes((shoot / "v2.png").read_bytes())

    code, text = said("-v", "poison", str(papers))
    assert code == 0 and "patched 2" in text, text
    assert "re-marked with this dataset's spec" in text, text
    for photo in (moved, copied):
        out = pub / photo.name
        assert not photo.exists(), f"{photo.name} left in the outbox"  # before: here, not in pub
        row = _row(data, photo)
        assert row["published_path"] == str(out) and row["poisoned_sha256"] == _sha(out), row
        assert row["spec_id"] == _spec_id("papers") and row["error"] is None, row
    code, text = said("status", "papers")
    assert code == 0 and "not moved" not in text.lower(), text


def test_a_photo_moved_in_with_the_datasets_spec_is_published(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Nothing to mark again (both datasets have the default spec): it is the dataset's patched file as it
    is, published with the others (it stayed in the outbox, "unchanged", at every run)."""
    data, pub = ppd_env["data"], tmp_path / "pub"
    shoot = make_shoot(ppd_env["outbox"] / "shoot", 2)
    beach = ppd_env["outbox"] / "beach"
    make_image(beach / "b0.png", 40)
    assert said("dataset", "set", "beach", "--publish-dir", str(pub))[0] == 0
    for folder in (shoot, beach):
        assert said("poison", str(folder))[0] == 0
    assert _spec_id("beach") == _spec_id("shoot")
    moved = (shoot / "v1.png").rename(beach / "moved.png")
    code, text = said("poison", str(beach))
    assert code == 0 and "patched 0, unchanged 1" in text, text
    assert not moved.exists() and _row(data, moved)["published_path"] == str(pub / "moved.png")


def test_a_re_mark_its_publish_folder_refuses_is_recorded_and_moved_next_time(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The move fails (the publish folder's place holds a file: no folder can be made there): the re-marked
    file stays patched in the outbox, the failure is said and counted by `ppd status`, and the next run,
    the folder back, moves it (publishing.retry_publish)."""
    data, pub = ppd_env["data"], tmp_path / "pub"
    shoot, papers = _shoot_and_published_papers(ppd_env["outbox"], pub)
    aside = pub.rename(tmp_path / "pub-aside")
    pub.write_text("not a folder")
    moved = (shoot / "v1.png").rename(papers / "moved.png")

    code, text = said("poison", str(papers))
    assert code == 1 and "failed 1" in text, text  # before: exit 0, the file kept in the outbox unsaid
    assert f"patched, but not moved to {pub}" in text, text
    row = _row(data, moved)
    assert row["state"] == "patched" and row["spec_id"] == _spec_id("papers"), row  # re-marked all the same
    assert row["poisoned_sha256"] == _sha(moved) and row["published_path"] is None, row
    code, text = said("status", "papers")
    assert "1 NOT moved to the publish folder" in text, text

    pub.unlink()
    aside.rename(pub)
    code, text = said("poison", str(papers))
    assert code == 0, text
    assert not moved.exists() and _row(data, moved)["published_path"] == str(pub / "moved.png")
    assert "not moved" not in said("status", "papers")[1].lower()


def test_a_reprotect_leaves_a_file_not_moved_to_be_moved(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd dataset set NAME --reprotect` re-marks a file its publish folder refused: it cleared the
    file's "not moved" note, so no later run moved it and `ppd status` stopped counting it."""
    data, pub = ppd_env["data"], tmp_path / "pub"
    beach = ppd_env["outbox"] / "beach"
    make_image(beach / "b0.png", 40)
    assert said("dataset", "set", "beach", "--publish-dir", str(pub))[0] == 0
    pub.write_text("not a folder")
    assert said("poison", str(beach))[0] == 1  # patched, not moved
    photo = beach / "b0.png"
    code, text = said("dataset", "set", "beach", "--design", "paper", "--reprotect")
    assert code == 0, text
    row = _row(data, photo)
    assert row["spec_id"] == _spec_id("beach") and row["poisoned_sha256"] == _sha(photo), row
    assert "1 NOT moved to the publish folder" in said("status", "beach")[1]  # before: not counted
    pub.unlink()
    assert said("poison", str(beach))[0] == 0
    assert not photo.exists() and _row(data, photo)["published_path"] == str(pub / "b0.png")


def test_the_daemon_publishes_a_photo_it_re_marks(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The daemon's path: a photo moved in by hand while `ppd watch` runs."""
    data, pub = ppd_env["data"], tmp_path / "pub"
    shoot, papers = _shoot_and_published_papers(ppd_env["outbox"], pub)
    ours = _spec_id("papers")
    daemon = start_daemon(tmp_path, "--no-verify")
    try:
        moved = (shoot / "v1.png").rename(papers / "moved.png")
        wait_for(lambda: _row(data, moved).get("spec_id") == ours, 60, "re-marked")
        wait_for(lambda: not moved.exists(), 30, "published")  # before: it stayed in the outbox
    finally:
        stop_daemon(daemon)
    log = daemon.log.read_text()
    assert "re-marked with this dataset's spec: it came from dataset 'shoot'" in log, log
    row = _row(data, moved)
    assert row["published_path"] == str(pub / "moved.png") and row["poisoned_sha256"] == _sha(
        pub / "moved.png"
    )
