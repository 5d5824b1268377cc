"""poisoner.image.coded: the same picture under other metadata compares equal; another picture,
palette or transparency does not; other formats are not compared."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
from PIL import Image

from poisoner.image.coded import same_coded_picture


def encoded(arr: np.ndarray, fmt: str, **opts: object) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, fmt, **opts)
    return buf.getvalue()


def with_png_chunk(data: bytes, kind: bytes, body: bytes) -> bytes:
    chunk = struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    return data[:-12] + chunk + data[-12:]


def test_jpeg_and_png_compare_as_coded() -> None:
    rng = np.random.default_rng(0)
    a, b = (rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(2))
    jpeg = encoded(a, "JPEG", quality=90)
    tagged = jpeg[:2] + b"\xff\xfe\x00\x07hello" + jpeg[2:]
    assert same_coded_picture(jpeg, tagged) is True
    assert same_coded_picture(jpeg, encoded(b, "JPEG", quality=90)) is False
    assert same_coded_picture(jpeg, encoded(a, "JPEG", quality=80)) is False  # other tables, other picture
    png = encoded(a, "PNG")
    assert same_coded_picture(png, with_png_chunk(png, b"tEXt", b"Comment\x00hi")) is True
    assert same_coded_picture(png, with_png_chunk(png, b"tRNS", b"\x00\x01\x00\x02\x00\x03")) is False
    assert same_coded_picture(png, encoded(b, "PNG")) is False
    assert same_coded_picture(encoded(a, "WEBP"), encoded(a, "WEBP")) is None  # not compared
    assert same_coded_picture(jpeg, png) is None
