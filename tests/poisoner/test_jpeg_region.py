"""JPEG region decode: only a lossless crop around the patch's MCUs is decoded, and the output is
byte-for-byte what the whole-picture decode gave; nothing outside the patch's MCU box changes."""

from __future__ import annotations

import io
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner import formats, jpeg_scan
from poisoner import jpeg as jpeg_codec
from poisoner.formats import ImageFormatError, poison_file
from poisoner.ladder import default_spec
from poisoner.provenance import Marker
from poisoner.spec import PatchSpec
from testkit.photos import gps_exif, textured

pytestmark = pytest.mark.skipif(shutil.which("jpegtran") is None, reason="jpegtran not installed")


# (name, size, save options): every sampling, greyscale, progressive, restart markers, odd sizes.
CASES = {
    "444": ((331, 250), {"subsampling": 0}),
    "422": ((320, 241), {"subsampling": 1}),
    "420": ((333, 247), {"subsampling": 2}),
    "420-progressive-restart": (
        (320, 240),
        {"subsampling": 2, "progressive": True, "restart_marker_blocks": 3},
    ),
    "grey": ((250, 190), {"grey": True}),
}
SPECS = {
    "center": PatchSpec(patch_size=37, block_size=4, position="center"),
    "top-left": PatchSpec(patch_size=30, block_size=4),
    "bottom-right": PatchSpec(patch_size=29, block_size=5, position="bottom-right"),
    "product-default": default_spec(),
}


@pytest.fixture(autouse=True)
def _libjpeg_paths(monkeypatch: pytest.MonkeyPatch) -> None:
    """These tests are about libjpeg-turbo's paths: the bit-level splice, which poison_file takes
    first, is off (tests/poisoner/test_jpeg_scan.py tests it against them)."""
    monkeypatch.setenv(jpeg_scan.SCAN_ENV, "")


def write_case(path: Path, case: str, seed: int = 0) -> None:
    (w, h), opts = CASES[case]
    opts = dict(opts)
    pixels = textured(h, w, seed)
    im = Image.fromarray(pixels).convert("L") if opts.pop("grey", False) else Image.fromarray(pixels)
    im.save(path, "JPEG", quality=90, exif=gps_exif(), comment=b"region test", **opts)


def both_paths(monkeypatch: pytest.MonkeyPatch, src: Path, tmp: Path, spec: PatchSpec, **kw: object):
    outs = {}
    for region in (False, True):
        monkeypatch.setattr(formats, "JPEG_REGION_DECODE", region)
        dst = tmp / f"out-{region}.jpg"
        report = poison_file(src, dst, spec, **kw)
        outs[region] = (dst.read_bytes(), report)
    return outs


@pytest.mark.parametrize("spec_name", sorted(SPECS))
@pytest.mark.parametrize("case", sorted(CASES))
def test_region_decode_gives_the_same_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str, spec_name: str
) -> None:
    src = tmp_path / "IMG_0007.jpg"
    write_case(src, case)
    marker = Marker.placeholder(bytes(32), "s" * 16, "0" * 64)
    outs = both_paths(monkeypatch, src, tmp_path, SPECS[spec_name], marker=marker)
    (old, old_report), (new, new_report) = outs[False], outs[True]
    assert new_report.method == old_report.method == "jpeg-dct-splice"
    assert new == old
    assert new_report.location_removed == old_report.location_removed != []
    assert new_report.notes == old_report.notes


@pytest.mark.parametrize("case", sorted(CASES))
def test_decode_box_equals_the_whole_decode(tmp_path: Path, case: str) -> None:
    src = tmp_path / "a.jpg"
    write_case(src, case, seed=3)
    data = src.read_bytes()
    im = Image.open(io.BytesIO(data))
    layout = jpeg_codec.read_layout(data)
    whole = np.asarray(Image.open(src))
    w, h = im.size
    for box in ((5, 7, 40, 33), (w // 2 - 20, h // 2 - 9, w // 2 + 21, h // 2 + 30), (w - 19, h - 23, w, h)):
        mbox = jpeg_codec.mcu_box(box, layout)
        got = jpeg_codec.decode_box(src, im, layout, mbox)
        x0, y0, x1, y1 = mbox
        assert np.array_equal(got, whole[y0:y1, x0:x1]), (case, mbox)


def _crop(path: Path, region: tuple[int, int, int, int]) -> bytes:
    x0, y0, x1, y1 = region
    cmd = ["jpegtran", "-copy", "none", "-crop", f"{x1 - x0}x{y1 - y0}+{x0}+{y0}", str(path)]
    return subprocess.run(cmd, capture_output=True, check=True).stdout


@pytest.mark.parametrize("case", sorted(CASES))
def test_nothing_outside_the_mcu_box_changes(tmp_path: Path, case: str) -> None:
    """Every MCU outside the patch's MCU box keeps its coefficients: a lossless crop of each of the
    four strips around the box is the same file, and decodes to the same pixels, in the source and
    the output. Greyscale (no chroma upsampling): the whole decoded picture outside the box too."""
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    write_case(src, case, seed=5)
    spec = SPECS["center"]
    poison_file(src, dst, spec)
    layout = jpeg_codec.read_layout(src.read_bytes())
    w, h = layout.width, layout.height
    x0, y0, x1, y1 = jpeg_codec.mcu_box(spec.resolve(w, h).box, layout)
    strips = [(0, 0, w, y0), (0, y1, w, h), (0, y0, x0, y1), (x1, y0, w, y1)]
    for strip in strips:
        if strip[2] > strip[0] and strip[3] > strip[1]:
            a, b = _crop(src, strip), _crop(dst, strip)
            assert a == b, strip
            pixels_a, pixels_b = (np.asarray(Image.open(io.BytesIO(x))) for x in (a, b))
            assert np.array_equal(pixels_a, pixels_b)
    inside_a = _crop(src, (x0, y0, x1, y1))
    assert inside_a != _crop(dst, (x0, y0, x1, y1))  # the patch is really in the box
    if case == "grey":
        a, b = np.asarray(Image.open(src)), np.asarray(Image.open(dst))
        mask = np.ones(a.shape, dtype=bool)
        mask[y0:y1, x0:x1] = False
        assert np.array_equal(a[mask], b[mask])


def test_truncated_jpeg_still_fails_before_writing(tmp_path: Path) -> None:
    src, dst = tmp_path / "half.jpg", tmp_path / "out.jpg"
    write_case(src, "420")
    data = src.read_bytes()
    src.write_bytes(data[: len(data) * 3 // 4])  # the patch's rows are intact, the end is missing
    with pytest.raises(ImageFormatError) as err:
        poison_file(src, dst, SPECS["top-left"])
    assert "half.jpg" in str(err.value) and "\n" not in str(err.value)
    assert not dst.exists()


def test_region_decode_falls_back_when_crop_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A jpegtran that fails and no in-process pass: whole decode and same-tables re-encode."""
    monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "/bin/false")
    monkeypatch.setenv("PPD_TURBOJPEG", "")
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    write_case(src, "420")
    report = poison_file(src, dst, SPECS["center"])
    assert report.method == "jpeg-reencode-same-tables"
    assert Image.open(dst).quantization == Image.open(src).quantization


@pytest.mark.parametrize("case", ["444", "420", "grey"])
def test_standard_huffman_source_keeps_its_tables_same_coefficients(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """A source coded with the standard Huffman tables is written with them (no -optimize pass):
    the bytes differ from the re-optimised output only in the entropy coding, so both decode to
    the same pixels everywhere and carry the same metadata segments."""
    src = tmp_path / "a.jpg"
    write_case(src, case)
    assert jpeg_codec.keeps_standard_huffman(jpeg_codec.read_layout(src.read_bytes()))
    outs = {}
    for keep in (False, True):
        monkeypatch.setattr(jpeg_codec, "STANDARD_HUFFMAN_AS_SOURCE", keep)
        dst = tmp_path / f"out-{keep}.jpg"
        poison_file(src, dst, SPECS["center"])
        outs[keep] = dst.read_bytes()
    optimised, standard = (jpeg_codec.read_layout(outs[k]) for k in (False, True))
    assert outs[True] != outs[False]
    assert set(standard.huffman) <= jpeg_codec.standard_huffman_tables()
    assert not set(optimised.huffman) <= jpeg_codec.standard_huffman_tables()
    assert standard.segments == optimised.segments
    a, b = (Image.open(io.BytesIO(outs[k])) for k in (False, True))
    assert a.quantization == b.quantization
    assert np.array_equal(np.asarray(a), np.asarray(b))


def test_optimised_source_is_reoptimised(tmp_path: Path) -> None:
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    Image.fromarray(textured(240, 320)).save(src, "JPEG", quality=90, optimize=True)
    layout = jpeg_codec.read_layout(src.read_bytes())
    assert not jpeg_codec.keeps_standard_huffman(layout)
    poison_file(src, dst, SPECS["center"])
    assert not set(jpeg_codec.read_layout(dst.read_bytes()).huffman) <= jpeg_codec.standard_huffman_tables()
