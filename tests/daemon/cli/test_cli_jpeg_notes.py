"""`ppd poison`'s summary says when a JPEG was written otherwise than a photographer assumes (found by
testing an installed wheel, issue 30's round 10): re-encoded whole, so every pixel moved (padding or
damage before EOI, a chroma sampling Pillow cannot write), and data after the picture left out. And an
arithmetic-coded JPEG Pillow cannot decode fails saying so."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import textured

runner = CliRunner()
needs_cjpeg = pytest.mark.skipif(shutil.which("cjpeg") is None, reason="cjpeg (libjpeg-turbo-progs) missing")


def said(result) -> str:
    return " ".join(result.output.split())


def photo(path: Path, seed: int = 0, size: tuple[int, int] = (320, 240)) -> bytes:
    Image.fromarray(textured(size[1], size[0], seed)).save(path, "JPEG", quality=90)
    return path.read_bytes()


def pixels(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")).astype(int)


def test_a_jpeg_reencoded_whole_is_said(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """Zero bytes before EOI: decoders play it, no splice takes it, so the whole picture is re-encoded:
    pixels far from the mark move, and the summary says so, naming the file."""
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    photo(shoot / "clean.jpg", 1)
    data = photo(shoot / "padded.jpg", 2)
    (shoot / "padded.jpg").write_bytes(data[:-2] + b"\x00" * 16 + b"\xff\xd9")
    before = pixels(shoot / "padded.jpg")
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    assert "JPEG re-encoded whole in 1 photo (padded.jpg)" in said(result), result.output
    assert "every pixel went through one more JPEG generation" in said(result)
    assert (np.abs(pixels(shoot / "padded.jpg") - before).max(axis=-1) > 0).mean() > 0.05  # what it says


def test_data_after_the_picture_is_said_left_out(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    photo(shoot / "a.jpg", 1)
    second = photo(tmp_path / "preview.jpg", 3, (64, 48))
    original = photo(shoot / "b.jpg", 2) + second  # a phone's appended preview
    (shoot / "b.jpg").write_bytes(original)
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    assert "data after the picture left out of 1 photo (b.jpg)" in said(result), result.output
    assert "JPEG re-encoded whole" not in said(result)  # the splice took it
    assert second not in (shoot / "b.jpg").read_bytes()
    assert runner.invoke(app, ["restore", str(shoot)]).exit_code == 0
    assert (shoot / "b.jpg").read_bytes() == original


@needs_cjpeg
def test_a_sampling_pillow_cannot_write_is_said(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    Image.fromarray(textured(240, 320, 4)).save(tmp_path / "a.ppm")
    subprocess.run(["cjpeg", "-quality", "90", "-sample", "4x1,1x1,1x1", "-outfile", str(shoot / "s411.jpg"),
                    str(tmp_path / "a.ppm")], check=True)  # fmt: skip
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    assert "JPEG re-encoded whole in 1 photo (s411.jpg)" in said(result), result.output
    assert "1 of them now 4:2:0" in said(result)  # (the splice wrote its patched blocks 4:2:0 into 4:1:1)


@needs_cjpeg
def test_an_arithmetic_jpeg_pillow_cannot_decode_fails_saying_so_without_jpegtran(
    ppd_env: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without jpegtran (PPD_JPEGTRAN empty) ppd cannot read it as Huffman-coded: it fails, untouched;
    with jpegtran it is patched (tests/poisoner/test_format_review.py) and restored byte for byte."""
    monkeypatch.setenv("PPD_JPEGTRAN", "")
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    Image.fromarray(textured(1200, 1600, 5)).save(tmp_path / "a.ppm")
    subprocess.run(["cjpeg", "-arithmetic", "-quality", "90", "-outfile", str(shoot / "arith.jpg"),
                    str(tmp_path / "a.ppm")], check=True)  # fmt: skip
    try:
        Image.open(shoot / "arith.jpg").load()
        pytest.skip("this Pillow decodes the arithmetic-coded file")
    except OSError:
        pass
    before = (shoot / "arith.jpg").read_bytes()
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 1, result.output
    assert "arith.jpg: arithmetic-coded JPEG that Pillow cannot decode" in said(result), result.output
    assert (shoot / "arith.jpg").read_bytes() == before
    monkeypatch.delenv("PPD_JPEGTRAN")
    if shutil.which("jpegtran") is None:
        return
    patched = runner.invoke(app, ["poison", str(shoot)])
    assert patched.exit_code == 0 and "patched 1," in said(patched), patched.output
    assert (shoot / "arith.jpg").read_bytes() != before
    assert runner.invoke(app, ["restore", str(shoot)]).exit_code == 0
    assert (shoot / "arith.jpg").read_bytes() == before
