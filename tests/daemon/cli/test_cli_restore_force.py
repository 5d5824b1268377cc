"""`ppd restore --force` over a file that is not ppd's output keeps that file: a black-box review (F6)
replaced a patched photo by another one with the same name, and `ppd restore FILE --force` destroyed
it with no copy kept; an edit made in another program went the same way. The user's file now goes to
DATA/displaced/DATASET/ (never the dataset folder, the outbox or a publish folder), the summary names
it, and the refusal without --force says whether the file holds another picture or an edit."""

from __future__ import annotations

import hashlib
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_image

runner = CliRunner()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _kept(data: Path) -> list[Path]:
    return sorted(p for p in (data / "displaced").rglob("*") if p.is_file())


def test_force_keeps_another_photo_saved_under_the_patched_name(ppd_env: dict[str, Path],
                                                                tmp_path: Path) -> None:  # fmt: skip
    shoot = tmp_path / "shoot"
    originals = {i: _sha(make_image(shoot / f"v{i}.png", i)) for i in range(3)}
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    other = make_image(shoot / "v1.png", 42, size=(200, 100)).read_bytes()  # a new photo, same name
    refused = runner.invoke(app, ["restore", str(shoot)])
    text = " ".join(refused.output.split())
    assert refused.exit_code == 1 and "another picture now (200x100 PNG" in text, text
    assert "160x120 PNG" in text and (shoot / "v1.png").read_bytes() == other
    forced = runner.invoke(app, ["restore", str(shoot / "v1.png"), "--force"])
    text = " ".join(forced.output.split())
    assert forced.exit_code == 0 and "restored 1" in text, text
    assert _sha(shoot / "v1.png") == originals[1]
    (kept,) = _kept(ppd_env["data"])
    assert kept.read_bytes() == other and kept.parent.name == "shoot" and kept.suffix == ".png"
    assert f"kept your version of v1.png at {kept}" in text, text
    assert sorted(p.name for p in shoot.iterdir()) == ["v0.png", "v1.png", "v2.png"]  # nothing added there
    # the data folder with a photo kept in it is still ppd's own (daemon.paths refuses one holding photos)
    assert runner.invoke(app, ["status"]).exit_code == 0


def test_force_keeps_an_edit_and_the_refusal_says_it_is_one(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot = tmp_path / "shoot"
    original = _sha(make_image(shoot / "v0.png", 0))
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    photo = shoot / "v0.png"
    with Image.open(photo) as im:
        edited = im.copy()
    edited.putpixel((3, 3), (255, 0, 0))  # a retouch in another program: same size, other bytes
    edited.save(photo)
    edit = photo.read_bytes()
    refused = runner.invoke(app, ["restore", str(photo)])
    text = " ".join(refused.output.split())
    assert refused.exit_code == 1 and "same 160x120 PNG picture, other bytes" in text, text
    forced = runner.invoke(app, ["restore", str(photo), "--force"])
    assert forced.exit_code == 0 and _sha(photo) == original, forced.output
    (kept,) = _kept(ppd_env["data"])
    assert kept.read_bytes() == edit
    # patched and edited again: a second copy, never written over the first (one name, one second)
    assert runner.invoke(app, ["poison", str(shoot), "--force"]).exit_code == 0
    photo.write_bytes(edit[:-1] + b"\0")
    assert runner.invoke(app, ["restore", str(photo), "--force"]).exit_code == 0
    assert sorted(p.read_bytes() for p in _kept(ppd_env["data"])) == sorted([edit, edit[:-1] + b"\0"])


def test_force_keeps_an_edited_out_copy_it_removes(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot, pub = tmp_path / "shoot", tmp_path / "pub"
    make_image(shoot / "v0.png", 0)
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(pub)]).exit_code == 0
    (copy,) = pub.rglob("v0.png")
    copy.write_bytes(copy.read_bytes() + b"edited")
    edit = copy.read_bytes()
    forced = runner.invoke(app, ["restore", str(shoot), "--force"])
    assert forced.exit_code == 0 and not copy.exists(), forced.output
    (kept,) = _kept(ppd_env["data"])
    assert kept.read_bytes() == edit and "kept your version of v0.png" in " ".join(forced.output.split())


def test_force_names_both_copies_it_keeps_of_a_published_file(ppd_env: dict[str, Path]) -> None:
    """A diff review (F8): an edited publish copy and another photo at its source path were both kept
    aside, but the summary named only the second."""
    shoot, pub = ppd_env["outbox"] / "shoot", ppd_env["outbox"].parent / "pub"
    original = _sha(make_image(shoot / "v0.png", 0))
    assert runner.invoke(app, ["dataset", "set", "shoot", "--publish-dir", str(pub)]).exit_code == 0
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    (copy,) = pub.rglob("v0.png")
    copy.write_bytes(copy.read_bytes() + b"edited")  # the published copy, edited
    edit = copy.read_bytes()
    other = make_image(shoot / "v0.png", 42, size=(200, 100)).read_bytes()  # a new photo at the source
    forced = runner.invoke(app, ["restore", str(shoot / "v0.png"), "--force"])
    text = " ".join(forced.output.split())
    assert forced.exit_code == 0 and _sha(shoot / "v0.png") == original and not copy.exists(), text
    kept = _kept(ppd_env["data"])
    assert sorted(p.read_bytes() for p in kept) == sorted([edit, other])
    for p in kept:
        assert f"at {p}" in text, text
