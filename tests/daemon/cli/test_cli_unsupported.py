"""A file `ppd poison` cannot protect is said so everywhere, before anything is kept (a black-box
review, 2026-12-07): a CMYK JPEG was 'would patch' in a dry run, got a preview, and had its original
copied into the vault before the writer refused it; a GIF, which poison skips, got a preview."""

from __future__ import annotations

from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_image

runner = CliRunner()


def test_cmyk_jpeg_fails_before_the_vault_in_a_dry_run_and_a_preview(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "shoot"
    make_image(shoot / "a.jpg", 1, size=(200, 150))
    Image.new("CMYK", (200, 150), (10, 200, 30, 0)).save(shoot / "print.jpg", "JPEG")
    dry = runner.invoke(app, ["poison", str(shoot), "--dry-run"])
    text = " ".join(dry.output.split())
    assert "would patch 1," in text and "failed 1" in text and "CMYK JPEG is not supported" in text, text
    real = runner.invoke(app, ["poison", str(shoot)])
    assert real.exit_code == 1 and "patched 1," in " ".join(real.output.split())
    kept = [p for p in (ppd_env["data"] / "vault").rglob("*") if p.is_file() and len(p.name) == 64]
    assert len(kept) == 1  # a.jpg's original only: nothing kept for a file that was never patched
    for name, said in (("print.jpg", "CMYK JPEG is not supported"), ("anim.gif", "ppd poison skips it")):
        if name.endswith(".gif"):
            Image.new("P", (32, 32)).save(shoot / name)
        result = runner.invoke(app, ["preview", str(shoot / name), "--out", str(tmp_path / "p.png")])
        assert result.exit_code == 2 and said in " ".join(result.output.split()), result.output
        assert not (tmp_path / "p.png").exists()


def test_photos_ppd_cannot_read_are_named_apart_from_sidecars(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A GIF or a camera's raw file in the folder was only counted 'skipped', like a sidecar, and the
    run said nothing else: published beside the patched photos it hands a reconstruction a clean view."""
    shoot = tmp_path / "shoot"
    make_image(shoot / "a.jpg", 1, size=(200, 150))
    Image.new("P", (64, 48)).save(shoot / "loop.gif")
    Image.new("RGB", (64, 48)).save(shoot / "scan.bmp")
    (shoot / "raw.DNG").write_bytes(b"II*\x00" + bytes(60))
    (shoot / "notes.txt").write_text("shot list")
    (shoot / "a.xmp").write_text("<x:xmpmeta/>")
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 1, result.output  # left unprotected beside the patched photo: exit 1
    text = " ".join(result.output.split())
    assert "skipped 5" in text and "not protected: 3 photo(s) or video(s) ppd cannot read" in text, text
    line = text[text.index("not protected:") :]
    assert all(n in line for n in ("loop.gif", "scan.bmp", "raw.DNG"))
    assert "notes.txt" not in line and "a.xmp" not in line
    # and ever after: status counts them and --check fails (it forgot them: a black-box review)
    status = runner.invoke(app, ["status", "shoot"])
    said = " ".join(status.output.split())
    assert "not counted: in a format ppd cannot protect 3" in said, said
    assert "3 photo(s) or video(s) in a format ppd cannot protect" in said, said
    check = runner.invoke(app, ["status", "shoot", "--check"])
    assert check.exit_code == 1 and "3 in a format ppd cannot protect" in " ".join(check.output.split())
    (shoot / "loop.gif").unlink(), (shoot / "scan.bmp").unlink(), (shoot / "raw.DNG").unlink()
    assert "cannot protect" not in runner.invoke(app, ["status", "shoot", "--check"]).output


def test_a_ts_file_is_a_video_only_when_it_reads_as_an_mpeg_transport_stream(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`.ts` names TypeScript source too: a script beside the photos made `ppd poison` exit 1 and
    `ppd status` say "NOT protected" (a black-box review)."""
    shoot = tmp_path / "shoot"
    make_image(shoot / "a.jpg", 1, size=(200, 150))
    (shoot / "gallery.ts").write_text("export const views = 25;\n" * 20)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert "cannot protect" not in runner.invoke(app, ["status", "shoot", "--check"]).output
    (shoot / "clip.ts").write_bytes((bytes([0x47]) + bytes(187)) * 4)  # two packets and more
    result = runner.invoke(app, ["poison", str(shoot)])
    line = " ".join(result.output.split())
    assert result.exit_code == 1 and "ppd cannot read (clip.ts)" in line, result.output
    shown = " ".join(runner.invoke(app, ["status", "shoot"]).output.split())
    assert "not counted: in a format ppd cannot protect 1" in shown, shown
    # a camera's M2TS (192-byte packets: a time code before each), cut mid-packet: a video too (diff review)
    (shoot / "avchd.ts").write_bytes(((bytes(4) + bytes([0x47]) + bytes(187)) * 5)[70:])
    shown = " ".join(runner.invoke(app, ["status", "shoot"]).output.split())
    assert "not counted: in a format ppd cannot protect 2" in shown, shown


def test_a_file_named_twice_is_one_job(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd poison a.jpg a.jpg --out X` said 'patched 1, unchanged 1' and 'written to X/a.jpg/'; a
    folder and a file in it made two copies in two places (a black-box review). The first naming
    counts, once."""
    shoot = tmp_path / "bad"
    make_image(shoot / "a.jpg", 1, size=(200, 150))
    twice = runner.invoke(
        app, ["poison", str(shoot / "a.jpg"), str(shoot / "a.jpg"), "--out", str(tmp_path / "o1")]
    )
    text = " ".join(twice.output.split())
    assert twice.exit_code == 0 and "patched 1, unchanged 0" in text, text
    assert f"written to {tmp_path / 'o1' / 'a.jpg'}" in text and f"{tmp_path / 'o1' / 'a.jpg'}/" not in text
    both = runner.invoke(app, ["poison", str(shoot), str(shoot / "a.jpg"), "--out", str(tmp_path / "o2")])
    assert both.exit_code == 0 and "patched 1, unchanged 0" in " ".join(both.output.split()), both.output
    assert sorted(p.relative_to(tmp_path / "o2").as_posix() for p in (tmp_path / "o2").rglob("*.jpg")) == [
        "bad/a.jpg"
    ]


def test_a_photo_still_being_written_is_said_not_patched_and_fails_the_run(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd poison` skips a file another program still writes. It said 'patched once it is closed'
    (what the daemon's watcher does; nothing does it after a one-shot run) and exited 0 (a black-box
    review): the photo stays unprotected in the folder."""
    import subprocess
    import sys
    import time

    shoot = tmp_path / "shoot"
    make_image(shoot / "a.jpg", 1, size=(200, 150))
    busy = make_image(shoot / "b.jpg", 2, size=(200, 150))
    writer = subprocess.Popen([sys.executable, "-c", f"f = open({str(busy)!r}, 'ab'); print(1, flush=True); "
                               "import time; time.sleep(60)"], stdout=subprocess.PIPE)  # fmt: skip
    try:
        assert writer.stdout is not None and writer.stdout.readline()  # the file is open for writing now
        result = runner.invoke(app, ["-v", "poison", str(shoot)])
    finally:
        writer.kill()
        writer.wait()
    text = " ".join(result.output.split())
    assert result.exit_code == 1, text
    said = "not patched: 1 file(s) still being written by another program (b.jpg): run ppd poison again"
    assert said in text, text
    # -v's line for the file says the same, not the daemon's 'patched once it is closed' (a black-box review)
    line = f"b.jpg (still open for writing by pid {writer.pid}; not patched: run ppd poison again once it"
    assert line in text and "once it is closed" not in text, text
    time.sleep(0.1)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0  # closed now: patched


def test_with_out_a_photo_ppd_cannot_read_stays_behind_and_fails_nothing(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """--out copies the patched photos elsewhere; a BMP left in the private source folder is published
    nowhere: no exit 1, no failing --check (a diff review: it asked to move it out of the source)."""
    shoot = tmp_path / "shoot"
    make_image(shoot / "a.jpg", 1, size=(200, 150))
    Image.new("RGB", (64, 48)).save(shoot / "scan.bmp")
    result = runner.invoke(app, ["poison", str(shoot), "--out", str(tmp_path / "pub")])
    assert result.exit_code == 0 and "ppd cannot read (scan.bmp)" in " ".join(result.output.split())
    assert not list((tmp_path / "pub").rglob("*.bmp"))
    assert "cannot protect" not in runner.invoke(app, ["status", "shoot", "--check"]).output


def test_a_photo_with_another_formats_suffix_is_not_said_to_change_its_pixel_layout(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: a PNG named .jpg was listed under "written in another pixel layout (e.g. a
    full palette widened to RGB)": its note's "written as PNG" matched that line."""
    shoot = tmp_path / "shoot"
    make_image(shoot / "a.jpg", 1, size=(200, 150))
    make_image(tmp_path / "b.png", 2, size=(200, 150))
    (tmp_path / "b.png").rename(shoot / "b.jpg")  # PNG content, JPEG name
    result = runner.invoke(app, ["-v", "poison", str(shoot)])
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "patched 2," in text, result.output
    assert "another pixel layout" not in text, text
    assert "content is PNG despite the .jpg suffix: kept as PNG" in text, text


def test_a_symlinked_folder_is_skipped_and_its_photos_named_not_protected(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: `shoot/day2 -> elsewhere` (2 photos) was one failed file ('refusing symlink
    day2', '2 of 4 patched'), its photos neither counted nor named. Still never followed."""
    shoot, elsewhere = tmp_path / "shoot", tmp_path / "elsewhere"
    make_image(shoot / "a.jpg", 1, size=(200, 150))
    originals = [make_image(elsewhere / f"{n}.jpg", i, size=(200, 150)) for i, n in enumerate("cd", 2)]
    before = [p.read_bytes() for p in originals]
    (shoot / "day2").symlink_to(elsewhere)
    result = runner.invoke(app, ["-v", "poison", str(shoot)])
    text = " ".join(result.output.split())
    assert "patched 1, unchanged 0, skipped 1, failed 0" in text, text
    assert f"skipped {shoot / 'day2'} (symlinked folder, not followed" in text, text
    said = "not protected: 2 photo(s) or video(s) in 1 symlinked folder(s) ppd does not follow"
    assert f"{said} (day2 -> {elsewhere}: 2)" in text and "refusing symlink" not in text, text
    assert result.exit_code == 1  # published with the folder, they are views a reconstruction reads
    assert [p.read_bytes() for p in originals] == before  # not followed


def test_a_name_that_is_not_utf8_is_counted_by_status_not_sent_back_to_poison(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review (F7): after `ppd poison` refused caf\\xe9.png, `ppd status` said "1 not patched
    yet: run `ppd poison FOLDER`", which fails the same way every time, and --failed "0 failed"."""
    import os

    shoot = tmp_path / "latin"
    make_image(shoot / "ok.png", 1, size=(200, 150))
    os.rename(make_image(shoot / "x.png", 2, size=(200, 150)), os.fsencode(shoot) + b"/caf\xe9.png")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 1
    said = " ".join(runner.invoke(app, ["status", "latin"]).output.split())
    assert "not patched yet" not in said and "udce9" not in said, said
    assert ("latin: 1 file(s) whose names are not UTF-8 (caf\\xe9.png), NOT protected: ppd cannot record "
            "such names: rename them") in said, said  # fmt: skip
    failed = runner.invoke(app, ["status", "latin", "--failed"]).output.splitlines()
    assert failed[0] == "latin: 0 failed, 0 quarantined, 1 named in bytes that are not UTF-8", failed
    assert failed[1].startswith(f"  {shoot}/caf\\xe9.png: the file name is not valid UTF-8"), failed
    check = runner.invoke(app, ["status", "--check"])
    assert check.exit_code == 1 and "1 named in bytes that are not UTF-8" in check.output, check.output
