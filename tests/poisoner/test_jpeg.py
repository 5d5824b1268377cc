"""JPEG: the source's tables, subsampling and metadata are kept; the splice leaves other MCUs alone."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, JpegImagePlugin

from poisoner import jpeg as jpeg_codec
from poisoner.blend import apply_patch
from poisoner.formats import poison_file
from poisoner.spec import PatchSpec

needs_jpegtran = pytest.mark.skipif(shutil.which("jpegtran") is None, reason="jpegtran not installed")

ICC = b"\x00\x00\x02\x0cfake-icc" * 8
XMP = b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF/></x:xmpmeta>'
SPEC = PatchSpec(patch_size=40, block_size=4, position="center")


def camera_like(h: int = 240, w: int = 320, seed: int = 0) -> np.ndarray:
    """Smooth gradients + edges + sensor noise: compresses like a photo, unlike pure noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    base = np.stack(
        [128 + 90 * np.sin(xx / 37.0), 100 + 80 * np.cos(yy / 23.0), 60 + 0.4 * xx + 0.3 * yy], axis=-1
    )
    base += 30.0 * ((xx // 29 + yy // 31) % 2)[..., None]
    return np.clip(base + rng.normal(0, 4, base.shape), 0, 255).astype(np.uint8)


def exif() -> Image.Exif:
    e = Image.Exif()
    e[0x010F] = "ppd-cam"
    e[0x0112] = 1
    return e


def write_jpeg(path: Path, pixels: np.ndarray, **opts: object) -> None:
    mode = "L" if pixels.ndim == 2 else "RGB"
    Image.fromarray(pixels, mode).save(
        path, "JPEG", exif=exif(), icc_profile=ICC, xmp=XMP, comment=b"shot by ppd tests", **opts
    )


def decoded(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path)).astype(np.int16)


def grown(box: tuple[int, int, int, int], by: int, w: int, h: int) -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = box
    return (max(0, x0 - by), max(0, y0 - by), min(w, x1 + by), min(h, y1 + by))


def outside(arr: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    mask = np.ones(arr.shape[:2], dtype=bool)
    x0, y0, x1, y1 = box
    mask[y0:y1, x0:x1] = False
    return arr[mask]


# ---- header parsing ----------------------------------------------------------------------------------
@pytest.mark.parametrize(("subsampling", "mcu"), [(0, (8, 8)), (1, (16, 8)), (2, (16, 16))])
def test_read_layout_sampling_and_mcu(tmp_path: Path, subsampling: int, mcu: tuple[int, int]) -> None:
    path = tmp_path / "a.jpg"
    write_jpeg(path, camera_like(), subsampling=subsampling, progressive=True, restart_marker_blocks=5)
    layout = jpeg_codec.read_layout(path.read_bytes())
    assert (layout.width, layout.height, layout.components) == (320, 240, 3)
    assert layout.mcu_size == mcu
    assert layout.progressive and layout.restart_interval == 5
    markers = {s.marker for s in layout.segments}
    assert {0xE1, 0xE2, 0xFE} <= markers


def test_read_layout_rejects_non_jpeg() -> None:
    with pytest.raises(ValueError):
        jpeg_codec.read_layout(b"\x89PNG\r\n")


def test_mcu_box_rounds_out_and_clips() -> None:
    layout = jpeg_codec.JpegLayout(100, 70, 0xC0, 3, ((2, 2), (1, 1), (1, 1)), 0)
    assert jpeg_codec.mcu_box((17, 3, 40, 20), layout) == (16, 0, 48, 32)
    assert jpeg_codec.mcu_box((90, 60, 100, 70), layout) == (80, 48, 100, 70)


# ---- the splice ----------------------------------------------------------------------------------------
@needs_jpegtran
@pytest.mark.parametrize("subsampling", [0, 1, 2])
def test_splice_keeps_everything_outside_the_patch_mcus(tmp_path: Path, subsampling: int) -> None:
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    write_jpeg(src, camera_like(), quality=88, subsampling=subsampling)
    report = poison_file(src, dst, SPEC)
    assert report.method == "jpeg-dct-splice"
    a, b = decoded(src), decoded(dst)
    layout = jpeg_codec.read_layout(src.read_bytes())
    box = jpeg_codec.mcu_box(SPEC.resolve(320, 240).box, layout)
    # Outside the MCU box grown by one MCU: bit-identical (the coefficients were copied).
    ring = grown(box, max(layout.mcu_size), 320, 240)
    assert np.array_equal(outside(a, ring), outside(b, ring))
    # Right next to the box only chroma upsampling can move a decoded pixel, by a little.
    assert np.abs(outside(a, box) - outside(b, box)).max() <= 8
    # The patch is there (lossy): close to the blend of the decoded source.
    placement = SPEC.resolve(320, 240)
    x0, y0, x1, y1 = placement.box
    expected = apply_patch(np.asarray(Image.open(src)), placement).astype(np.int16)
    assert np.abs(b[y0:y1, x0:x1] - expected[y0:y1, x0:x1]).mean() < 25
    assert np.abs(b[y0:y1, x0:x1] - a[y0:y1, x0:x1]).mean() > 60


@needs_jpegtran
def test_splice_keeps_tables_sampling_metadata_progressive_restart(tmp_path: Path) -> None:
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    write_jpeg(src, camera_like(), quality=83, subsampling=1, progressive=True, restart_marker_blocks=7)
    report = poison_file(src, dst, SPEC)
    a, b = Image.open(src), Image.open(dst)
    assert report.method == "jpeg-dct-splice"
    assert b.quantization == a.quantization
    assert JpegImagePlugin.get_sampling(b) == JpegImagePlugin.get_sampling(a) == 1
    for key in ("exif", "icc_profile", "xmp", "comment"):
        assert b.info[key] == a.info[key], key
    layout = jpeg_codec.read_layout(dst.read_bytes())
    assert layout.progressive and layout.restart_interval == 7


@needs_jpegtran
def test_splice_greyscale_and_edge_patch(tmp_path: Path) -> None:
    """A greyscale JPEG whose size is not a multiple of 8, patch touching the bottom-right edge."""
    src, dst = tmp_path / "g.jpg", tmp_path / "out.jpg"
    grey = camera_like(h=203, w=301)[..., 1]
    write_jpeg(src, grey, quality=90)
    spec = PatchSpec(patch_size=40, block_size=4, position="bottom-right")
    report = poison_file(src, dst, spec)
    assert report.method == "jpeg-dct-splice"
    a, b = decoded(src), decoded(dst)
    box = jpeg_codec.mcu_box(spec.resolve(301, 203).box, jpeg_codec.read_layout(src.read_bytes()))
    assert np.array_equal(outside(a, box), outside(b, box))  # no chroma: nothing moves outside
    assert Image.open(dst).quantization == Image.open(src).quantization


# ---- the fallback ----------------------------------------------------------------------------------------
def test_fallback_reencode_keeps_tables_and_metadata(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "")  # no splice available
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    write_jpeg(src, camera_like(), quality=91, subsampling=2, progressive=True, restart_marker_blocks=3)
    report = poison_file(src, dst, SPEC)
    assert report.method == "jpeg-reencode-same-tables"
    assert any("DCT splice impossible" in n for n in report.notes)
    a, b = Image.open(src), Image.open(dst)
    assert b.quantization == a.quantization
    assert JpegImagePlugin.get_sampling(b) == 2
    for key in ("exif", "icc_profile", "xmp", "comment"):
        assert b.info[key] == a.info[key], key
    layout = jpeg_codec.read_layout(dst.read_bytes())
    assert layout.progressive and layout.restart_interval == 3
    # One generation of loss outside the patch: small but (in general) not zero.
    box = SPEC.resolve(320, 240).box
    assert np.abs(outside(decoded(src), box) - outside(decoded(dst), box)).mean() < 3


def test_fallback_when_jpegtran_refuses(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "/bin/false")
    monkeypatch.setenv("PPD_TURBOJPEG", "")  # and no in-process pass
    monkeypatch.setenv("PPD_JPEG_SCAN", "")  # nor the bit-level one
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    write_jpeg(src, camera_like(), quality=80)
    report = poison_file(src, dst, SPEC)
    assert report.method == "jpeg-reencode-same-tables"
    assert Image.open(dst).quantization == Image.open(src).quantization


def test_other_app_segments_pass_through_reencode(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "")
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    iptc = jpeg_codec.Segment(0xED, b"Photoshop 3.0\x008BIM\x04\x04\x00\x00\x00\x00\x00\x00")
    write_jpeg(src, camera_like(), quality=85, extra=iptc.raw())
    report = poison_file(src, dst, SPEC)
    assert iptc in jpeg_codec.read_layout(dst.read_bytes()).segments
    assert "JPEG IPTC/Photoshop" in report.preserved


# ---- a real photo ------------------------------------------------------------------------------------------
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(255.0**2 / np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


@needs_jpegtran
@pytest.mark.integration
def test_fountain_splice_beats_reencode(
    tmp_path: Path, shared_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    src = shared_dir / "datasets/fountain_P11/images/0005.jpg"
    spec = PatchSpec()
    spliced, reencoded = tmp_path / "s.jpg", tmp_path / "r.jpg"
    assert poison_file(src, spliced, spec).method == "jpeg-dct-splice"
    monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "")
    assert poison_file(src, reencoded, spec).method == "jpeg-reencode-same-tables"
    a = decoded(src)
    h, w = a.shape[:2]
    box = jpeg_codec.mcu_box(spec.resolve(w, h).box, jpeg_codec.read_layout(src.read_bytes()))
    ring = grown(box, 16, w, h)
    assert np.array_equal(outside(a, ring), outside(decoded(spliced), ring))
    assert not np.array_equal(outside(a, ring), outside(decoded(reencoded), ring))
    assert psnr(a, decoded(spliced)) > psnr(a, decoded(reencoded))
