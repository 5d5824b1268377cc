"""`ppd key import` counts what the key it replaces sealed by the seals in the patched files (a fourth
black-box review, finding 4): it counted every patched file of the store against the key being
replaced, so putting back the key that sealed them all said "the key it replaced sealed the patched
files of 90 original(s)" where the replaced key had sealed none."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from daemon.paths import AppPaths
from testkit.photos import make_image, make_shoot

runner = CliRunner()


def _ppd(*args: str) -> tuple[int, str]:
    result = runner.invoke(app, list(args))
    return result.exit_code, " ".join(result.output.split())


def _keys(tmp_path: Path) -> tuple[Path, Path]:
    """The installation's key exported (k1), and another key (other)."""
    k1, other = tmp_path / "k1.key", tmp_path / "other.key"
    assert _ppd("key", "export", str(k1))[0] == 0
    other.write_text("ab" * 32 + "\n")
    return k1, other


def test_putting_the_sealing_key_back_gives_no_scare(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 3)
    assert _ppd("poison", str(shoot))[0] == 0
    k1, other = _keys(tmp_path)
    rc, said = _ppd("key", "import", "--force", str(other))  # true: k1 sealed the 3
    assert rc == 0 and "the key it replaced sealed the patched files of 3 original(s)" in said, said

    rc, said = _ppd("key", "import", str(k1))  # refused all the same, saying what each key sealed
    assert rc == 2 and "which sealed none of the patched files here" in said, said
    assert f"the key in {k1} sealed those of 3 original(s)" in said, said
    rc, said = _ppd("key", "import", "--force", str(k1))
    assert rc == 0 and "the key it replaced" not in said, said  # before: "... sealed ... 3 original(s)"
    assert "the key you installed is the one that sealed the patched files of 3 original(s)" in said, said

    (paths.data_dir / "seal.key").unlink()  # a new key that sealed nothing, then k1 back
    assert _ppd("key", "new")[0] == 0
    rc, said = _ppd("key", "import", "--force", str(k1))
    assert rc == 0 and "the key it replaced" not in said, said
    assert "is the one that sealed the patched files of 3 original(s)" in said, said


def test_each_key_is_counted_what_it_sealed(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """Two shoots sealed with two keys: replacing one counts its own files only, in the refusal and
    after --force; a file restored since carries no seal and is not counted."""
    first, second = tmp_path / "first", tmp_path / "second"
    make_shoot(first, 3)
    second.mkdir()
    for seed in (10, 11):  # photos of their own: originals not in the first shoot
        make_image(second / f"w{seed}.png", seed)
    assert _ppd("poison", str(first))[0] == 0
    k1, other = _keys(tmp_path)
    assert _ppd("key", "import", "--force", str(other))[0] == 0
    assert _ppd("poison", str(second))[0] == 0  # sealed with the other key

    rc, said = _ppd("key", "import", str(k1))
    assert rc == 2 and "which sealed the patched files of 2 original(s) in the" in said, said  # before: 5
    rc, said = _ppd("key", "import", "--force", str(k1))
    assert rc == 0 and "the key it replaced sealed the patched files of 2 original(s)" in said, said
    assert "is the one that sealed the patched files of 3 original(s)" in said, said

    restored = sorted(first.iterdir())[0]
    assert _ppd("restore", str(restored))[0] == 0  # its sealed bytes are gone from the folder
    rc, said = _ppd("key", "import", "--force", str(other))
    assert rc == 0 and "the key it replaced sealed the patched files of 2 original(s)" in said, said
    assert "is the one that sealed the patched files of 2 original(s)" in said, said
