"""poisoner.image.resaved: ppd's output saved again (lossless: the same levels; lossy: a re-encode's
noise) against edits of it and a re-save of the original (a black-box review, 2026-12-07, F1)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.formats import poison_bytes
from poisoner.image.resaved import is_resaved_output
from poisoner.spec import PatchSpec
from testkit.photos import textured


def _coded(pixels: np.ndarray, fmt: str, **options: int) -> bytes:
    out = io.BytesIO()
    Image.fromarray(pixels).save(out, format=fmt, **options)
    return out.getvalue()


def _decoded(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        return np.asarray(im.convert("RGB")).copy()


@pytest.fixture(params=["a.png", "a.jpg"])
def case(request: pytest.FixtureRequest) -> tuple[str, bytes, bytes]:
    """(name, original, ppd's output of it)."""
    name = str(request.param)
    fmt = "JPEG" if name.endswith(".jpg") else "PNG"
    original = _coded(textured(240, 320, seed=5), fmt, **({"quality": 95} if fmt == "JPEG" else {}))
    output, _ = poison_bytes(Path(name), PatchSpec(), data=original)
    return name, original, output


def test_ppds_output_saved_again_is_recognised(case: tuple[str, bytes, bytes]) -> None:
    name, original, output = case
    assert is_resaved_output(name, original, output, _coded(_decoded(output), "PNG"))
    for quality in (75, 90, 95):
        assert is_resaved_output(name, original, output, _coded(_decoded(output), "JPEG", quality=quality))


def test_edits_and_the_original_are_not(case: tuple[str, bytes, bytes]) -> None:
    name, original, output = case
    pixels = _decoded(output)
    retouched = pixels.copy()
    retouched[100:116, 100:116] = 255 - retouched[100:116, 100:116]
    brighter = np.clip(pixels.astype(np.int16) + 8, 0, 255).astype(np.uint8)
    one_pixel = pixels.copy()
    one_pixel[3, 3] = (255, 0, 0)
    for edited in (
        _coded(retouched, "JPEG", quality=90),
        _coded(brighter, "JPEG", quality=90),
        _coded(pixels[:200, :280], "PNG"),  # a crop
        _coded(one_pixel, "PNG"),  # lossless: any level changed is an edit
        _coded(_decoded(original), "JPEG", quality=90),  # the original, no mark
        _coded(_decoded(original), "PNG"),
    ):
        assert not is_resaved_output(name, original, output, edited)
