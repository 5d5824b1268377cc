"""Format defects a black-box review found (2026-12-07), each written as the file that showed it."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from poisoner.formats import poison_file
from poisoner.image.read import check_writable_image
from poisoner.ladder import default_spec
from poisoner.location import jpeg_header_segments


def photo(w: int = 640, h: int = 480, seed: int = 3) -> Image.Image:
    """A photo-like picture: smooth gradients with a little noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    base = np.stack([x * 255 / w, y * 255 / h, (x + y) * 127 / (w + h) + 60], axis=2)
    return Image.fromarray(np.clip(base + rng.normal(0, 6, base.shape), 0, 255).astype(np.uint8))


def test_jpeg_with_an_mpf_second_image_is_patched_without_it(tmp_path: Path) -> None:
    """A JPEG carrying a second image indexed by MPF (Pillow opens it as MPO: phones' Ultra HDR, many
    Nikon/Fuji JPEGs) was refused whole ("MPO with 2 frames/pages is not supported"). Its picture is
    patched like any JPEG's; the second image and the MPF segment that indexes it are not written,
    and the report says so (trailer_bytes: what ppd poison's summary counts)."""
    src, dst = tmp_path / "cam.jpg", tmp_path / "out.jpg"
    first = photo()
    first.save(src, format="MPO", save_all=True, append_images=[first.resize((320, 240))], quality=93)
    with Image.open(src) as opened:
        assert opened.format == "MPO" and opened.n_frames == 2  # what the review's camera wrote
    check_writable_image(src, src.name)  # the dry run's and preview's header check: no refusal
    report = poison_file(src, dst, default_spec())
    assert report.method == "jpeg-dct-splice"
    assert report.trailer_bytes > 0
    assert any("MPF segment" in n and "not written" in n for n in report.notes)
    out = dst.read_bytes()
    with Image.open(io.BytesIO(out)) as patched:
        assert patched.format == "JPEG" and getattr(patched, "n_frames", 1) == 1
        assert (np.asarray(patched) != np.asarray(Image.open(src))).any()
    segments, _ = jpeg_header_segments(out)
    assert not any(m == 0xE2 and p.startswith(b"MPF\x00") for m, p in segments)
    assert out.endswith(b"\xff\xd9") and out.count(b"\xff\xd8") == 1  # no second image after the EOI
