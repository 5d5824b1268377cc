"""display_detail with the caller's decoded image (issue 30: one decode per PNG, not two) judges the
very thumbnail its bytes give, for every format where it is used; a JPEG (scaled decode) never
takes that path."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.formats import poison_file
from poisoner.image.read import open_decoded
from poisoner.ladder import default_spec
from poisoner.subject import display_detail, reuses_decode


def _scene(seed: int, size: tuple[int, int] = (640, 480)) -> np.ndarray:
    """A plain backdrop with a textured block and a soft gradient: detail in some cells, not all."""
    rng = np.random.default_rng(seed)
    w, h = size
    img = np.full((h, w, 3), 200, dtype=np.uint8)
    img[:, :, 0] = np.linspace(150, 220, w, dtype=np.uint8)[None, :]
    x0, y0 = rng.integers(0, w // 2), rng.integers(0, h // 2)
    img[y0 : y0 + h // 2, x0 : x0 + w // 3] = rng.integers(0, 256, (h // 2, w // 3, 3), dtype=np.uint8)
    return img


def _encoded(kind: str, seed: int) -> bytes:
    rgb = _scene(seed)
    im = Image.fromarray(rgb)
    buf = io.BytesIO()
    exif = Image.Exif()
    exif[0x0112] = 6  # shown turned: the orientation must come through the decoded image too
    if kind == "png-rgb":
        im.save(buf, "PNG", exif=exif)
    elif kind == "png-rgba":
        alpha = np.where(rgb[:, :, 1] > 128, 255, 40).astype(np.uint8)
        Image.fromarray(np.dstack([rgb, alpha]), "RGBA").save(buf, "PNG")
    elif kind == "png-p-transparency":
        im.quantize(64).save(buf, "PNG", transparency=0)
    elif kind == "png-l16":
        # 16-bit levels (x 257: 255 is white); levels 0-255 would be a near-black picture, no detail
        Image.fromarray(rgb[:, :, 1].astype(np.uint16) * 257).save(buf, "PNG")
    elif kind == "tiff":
        im.save(buf, "TIFF", exif=exif)
    elif kind == "webp-lossless":
        im.save(buf, "WEBP", lossless=True, exif=exif)
    elif kind == "webp-lossy":
        im.save(buf, "WEBP", quality=80)
    elif kind == "bmp":
        im.save(buf, "BMP")
    else:
        raise AssertionError(kind)
    return buf.getvalue()


KINDS = ("png-rgb", "png-rgba", "png-p-transparency", "png-l16", "tiff", "webp-lossless", "webp-lossy", "bmp")


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_the_decoded_image_gives_the_thumbnail_its_bytes_give(kind: str, seed: int) -> None:
    data = _encoded(kind, seed)
    decoded = open_decoded(Path(f"x.{kind}"), data)
    assert reuses_decode(decoded)
    before = decoded.tobytes()
    detail, orientation = display_detail(data, "x")
    reused, reused_orientation = display_detail(data, "x", decoded)
    assert reused_orientation == orientation
    assert reused.shape == detail.shape and np.array_equal(reused, detail)
    assert 0 < detail.mean() < 1  # the scene has detail somewhere and not everywhere: a real comparison
    assert decoded.tobytes() == before  # the caller's image is not resized under it


def test_a_jpeg_is_decoded_at_its_own_scale_never_from_the_full_decode() -> None:
    buf = io.BytesIO()
    Image.fromarray(_scene(3, (2400, 1600))).save(buf, "JPEG", quality=92)
    data = buf.getvalue()
    full = open_decoded(Path("x.jpg"), data)
    assert not reuses_decode(full)
    # the full decode's thumbnail differs from the 1/8 decode's: passing it must change nothing
    assert np.array_equal(display_detail(data, "x", full)[0], display_detail(data, "x")[0])


@pytest.mark.parametrize("kind", ["png-rgb", "png-rgba", "tiff"])
def test_poison_file_writes_the_same_bytes_as_with_a_second_decode(
    kind: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    src = tmp_path / f"view.{'tif' if kind == 'tiff' else 'png'}"
    src.write_bytes(_encoded(kind, 5))
    spec = default_spec()
    poison_file(src, tmp_path / f"reused{src.suffix}", spec)
    monkeypatch.setattr("poisoner.subject.reuses_decode", lambda _im: False)  # the old path: decode again
    poison_file(src, tmp_path / f"again{src.suffix}", spec)
    assert (tmp_path / f"reused{src.suffix}").read_bytes() == (tmp_path / f"again{src.suffix}").read_bytes()
