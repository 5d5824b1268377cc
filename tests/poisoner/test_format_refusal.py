"""What no writer takes is said from the header, with the writer's own words (format_refusal):
ppd fails such a file before its original reaches the vault, and a dry run or a preview no longer
promises a mark that `ppd poison` then refuses (a black-box review, 2026-12-07: a CMYK JPEG was
'would patch' in a dry run and got a preview)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.errors import ImageFormatError
from poisoner.formats import poison_file
from poisoner.image.read import check_writable_image
from poisoner.ladder import default_spec


def png_16bit_grey_alpha(path: Path, w: int = 64, h: int = 48) -> Path:
    raw = b"".join(b"\x00" + np.full((w, 2), 30000, ">u2").tobytes() for _ in range(h))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 4, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))  # fmt: skip
    return path


UNSUPPORTED = {
    "cmyk.jpg": lambda p: Image.new("CMYK", (64, 48), (10, 200, 30, 0)).save(p, "JPEG"),
    "grey-alpha-16.png": png_16bit_grey_alpha,
    "cmyk.tif": lambda p: Image.new("CMYK", (64, 48), (10, 200, 30, 0)).save(p, "TIFF"),
}


@pytest.mark.parametrize("name", sorted(UNSUPPORTED))
def test_header_check_says_what_the_writer_says(tmp_path: Path, name: str) -> None:
    src = tmp_path / name
    UNSUPPORTED[name](src)
    with pytest.raises(ImageFormatError) as early:
        check_writable_image(src, name)
    with pytest.raises(ImageFormatError) as late:
        poison_file(src, tmp_path / f"out-{name}", default_spec())
    assert str(late.value).removeprefix(f"{name}: ") in str(early.value), (early.value, late.value)
    assert not (tmp_path / f"out-{name}").exists()


@pytest.mark.parametrize(("name", "mode"), [("a.jpg", "RGB"), ("g.jpg", "L"), ("a.png", "RGBA"),
                                            ("p.png", "P"), ("a.tif", "RGB"), ("a.webp", "RGB")])  # fmt: skip
def test_what_the_writers_take_passes(tmp_path: Path, name: str, mode: str) -> None:
    src = tmp_path / name
    Image.new(mode, (64, 48)).save(src)
    check_writable_image(src, name)  # no error


def test_the_header_check_keeps_the_users_raised_pixel_limit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 95 MP photo with [limits] max_megapixels = 150 was refused here ("decompression-bomb limit":
    Pillow's own 89.5 MP, raised only later by the poisoner) and the daemon quarantined it (a diff
    review). The header check raises Pillow's limit to the user's, as the poisoner does."""
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", Image.MAX_IMAGE_PIXELS)  # restored afterwards

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    big = tmp_path / "big.png"  # the header of a 10000 x 9500 RGB PNG: nothing is decoded here
    big.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 10000, 9500, 8, 2, 0, 0, 0))
                    + chunk(b"IDAT", zlib.compress(b"\x00")) + chunk(b"IEND", b""))  # fmt: skip
    with pytest.raises(ImageFormatError, match="decompression-bomb"):
        check_writable_image(big, "big.png")  # Pillow's default: over it
    check_writable_image(big, "big.png", max_pixels=150_000_000)  # the user's: within it
