"""What ppd changed in a file beyond its mark reaches the user (a black-box review, 2026-12-07: a
lossy WebP re-encoded at another quality, a full palette widened to RGB, location removed: all only
in the store's notes). The summary names the files per kind of change; `ppd -v poison` gives each
file's notes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app

runner = CliRunner()


def test_summary_and_verbose_lines_say_what_changed_beyond_the_mark(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)).save(shoot / "a.webp", quality=70)
    full = Image.fromarray(rng.integers(0, 256, (240, 320), dtype=np.uint8), "P")
    full.putpalette(list(rng.integers(0, 256, 768, dtype=np.uint8)))
    full.save(shoot / "b.png")
    Image.fromarray(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)).save(shoot / "c.png")
    result = runner.invoke(app, ["-v", "poison", str(shoot)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "re-encoded (lossy: one more generation of its codec's loss): 1 file(s) (a.webp)" in text, text
    assert "written in another pixel layout (e.g. a full palette widened to RGB): 1 file(s) (b.png)" in text
    assert "note: lossy WebP re-encoded at quality" in text
    assert "note: palette full (256 + " in text
    assert "c.png)" not in text  # nothing beyond its mark changed in it


def test_restore_says_the_published_copies_it_removed(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd restore` of a dataset with a publish folder said 'restored 2' and deleted both published
    copies without a word (a black-box review). It now says so."""
    publish = tmp_path / "www"
    (ppd_env["config"] / "config.toml").write_text(f'publish_dir = "{publish}"\n')
    shoot = ppd_env["outbox"] / "pubset"
    shoot.mkdir()
    for i in range(2):
        Image.new("RGB", (200, 150), (40 * i, 90, 160)).save(shoot / f"v{i}.png")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert sorted(p.name for p in (publish / "pubset").iterdir()) == ["v0.png", "v1.png"]
    result = runner.invoke(app, ["restore", "pubset"])
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "restored 2" in text, text
    assert "removed 2 published copies from the publish folder" in text
    assert not any((publish / "pubset").iterdir()) and len(list(shoot.iterdir())) == 2


def test_a_name_with_a_newline_stays_on_its_line(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd -v poison` printed a name with a newline raw, splitting its line (a black-box review)."""
    shoot = tmp_path / "d"
    shoot.mkdir()
    Image.new("RGB", (800, 600), (9, 99, 199)).save(shoot / "new\nline.png")  # no small-squares line
    result = runner.invoke(app, ["-v", "poison", str(shoot)])
    assert result.exit_code == 0, result.output
    lines = [x for x in result.output.splitlines() if "line.png" in x]
    assert len(lines) == 1 and "new\\nline.png" in lines[0] and lines[0].startswith("patched "), lines
    # the summary's lines that name a file escape it too (small squares: a 200 x 150 photo)
    Image.new("RGB", (200, 150), (9, 99, 199)).save(shoot / "small\nline.png")
    result = runner.invoke(app, ["poison", str(shoot)])
    said = [x for x in result.output.splitlines() if "blocks across" in x or x.startswith("line.png")]
    assert len(said) == 1 and "small\\nline.png" in said[0], result.output


def test_restore_and_status_keep_a_name_with_a_newline_on_its_line(ppd_env: dict[str, Path],
                                                                    tmp_path: Path) -> None:  # fmt: skip
    """`ppd -v restore` and `ppd status --failed` printed such a name raw: one file read as two lines,
    the second starting "restored" (a black-box review, F9); poison escaped it."""
    shoot = tmp_path / "nl"
    shoot.mkdir()
    Image.new("RGB", (800, 600), (9, 99, 199)).save(shoot / "evil\nrestored  etc.png")
    (shoot / "bad\nfile.png").write_bytes(b"")  # fails: empty
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 1
    failed = runner.invoke(app, ["status", "nl", "--failed"])
    lines = [x for x in failed.output.splitlines() if "file.png" in x]
    assert len(lines) == 1 and "bad\\nfile.png" in lines[0], failed.output
    result = runner.invoke(app, ["-v", "restore", "nl"])
    lines = [x for x in result.output.splitlines() if "etc.png" in x]
    assert lines == [f"restored {shoot}/evil\\nrestored  etc.png"], result.output
