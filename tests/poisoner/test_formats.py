"""poisoner.formats: every format round-trips with the patch in and everything else kept."""

from __future__ import annotations

import hashlib
import io
import os
import stat
import struct
import subprocess
import sys
import textwrap
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, PngImagePlugin

from poisoner.blend import apply_patch
from poisoner.formats import (
    ImageFormatError,
    image_from_array,
    png_chunks,
    poison_file,
    poison_in_place,
)
from poisoner.image.png import _encode_png16_colour
from poisoner.media import IMAGE_SUFFIXES, is_image
from poisoner.spec import PatchSpec

SPEC = PatchSpec(patch_size=40, block_size=4, position="top-left", offset=(8, 8))
ICC = b"\x00\x00\x02\x0cfake-icc-profile-bytes" * 4
EXIF_ORIENT_6 = Image.Exif()
EXIF_ORIENT_6[0x0112] = 6
EXIF_ORIENT_6[0x010F] = "ppd-test-camera"
EXIF_PLAIN = Image.Exif()
EXIF_PLAIN[0x010F] = "ppd-test-camera"
XMP = b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF/></x:xmpmeta>'


def textured(
    h: int = 120, w: int = 160, channels: int = 3, dtype: type = np.uint8, seed: int = 0
) -> np.ndarray:
    rng = np.random.default_rng(seed)
    top = 65535 if dtype == np.uint16 else 255
    shape = (h, w) if channels == 1 else (h, w, channels)
    arr = rng.integers(0, top + 1, size=shape).astype(dtype)
    if channels in (2, 4):
        arr[..., -1] = rng.choice([0, top // 3, top], size=(h, w)).astype(dtype)
    return arr


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def outside_patch(arr: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    mask = np.ones(arr.shape[:2], dtype=bool)
    x0, y0, x1, y1 = box
    mask[y0:y1, x0:x1] = False
    return arr[mask]


def assert_lossless_patch_shown(src_pixels: np.ndarray, out_pixels: np.ndarray, spec: PatchSpec) -> None:
    """assert_lossless_patch as a viewer sees a photo stored with EXIF orientation 6 (EXIF_ORIENT_6):
    the mark goes where the photo shows its corner (issue 25)."""
    from poisoner.orientation import orient_array

    assert_lossless_patch(orient_array(src_pixels, 6), orient_array(out_pixels, 6), spec)


def assert_lossless_patch(src_pixels: np.ndarray, out_pixels: np.ndarray, spec: PatchSpec) -> None:
    placement = spec.resolve(src_pixels.shape[1], src_pixels.shape[0])
    expected = apply_patch(src_pixels, placement)
    assert out_pixels.dtype == src_pixels.dtype
    np.testing.assert_array_equal(
        outside_patch(out_pixels, placement.box), outside_patch(src_pixels, placement.box)
    )
    np.testing.assert_array_equal(out_pixels, expected)
    assert not np.array_equal(out_pixels, src_pixels)


# ---- PNG -------------------------------------------------------------------------------------------
def png_metadata() -> PngImagePlugin.PngInfo:
    info = PngImagePlugin.PngInfo()
    info.add_text("Title", "fountain")
    info.add_itxt("Description", "vue d'ensemble", lang="fr")
    info.add(b"gAMA", struct.pack(">I", 45455))
    info.add(b"tIME", struct.pack(">HBBBBB", 2024, 5, 6, 7, 8, 9))
    return info


ANCILLARY = (b"tEXt", b"iTXt", b"gAMA", b"tIME", b"iCCP", b"eXIf", b"pHYs")


@pytest.mark.parametrize("mode", ["L", "LA", "RGB", "RGBA", "I;16"])
def test_png_modes_round_trip_lossless_with_metadata(tmp_path: Path, mode: str) -> None:
    channels = {"L": 1, "LA": 2, "RGB": 3, "RGBA": 4, "I;16": 1}[mode]
    pixels = textured(channels=channels, dtype=np.uint16 if mode == "I;16" else np.uint8)
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    image_from_array(pixels, mode).save(
        src, pnginfo=png_metadata(), icc_profile=ICC, exif=EXIF_ORIENT_6, dpi=(300, 300)
    )
    before = sha(src)
    report = poison_file(src, dst, SPEC)
    assert sha(src) == before
    out = Image.open(dst)
    assert out.mode == mode
    assert_lossless_patch_shown(pixels, np.asarray(out), SPEC)
    src_chunks = {t: b for t, b in png_chunks(src.read_bytes()) if t in ANCILLARY}
    out_chunks = {t: b for t, b in png_chunks(dst.read_bytes()) if t in ANCILLARY}
    assert set(src_chunks) == set(ANCILLARY)
    assert out_chunks == src_chunks  # every metadata chunk byte for byte
    assert report.lossless and report.method == "png-lossless"
    assert report.format == "PNG" and (report.width, report.height) == (160, 120)
    assert out.info["Title"] == "fountain" and out.info["icc_profile"] == ICC


@pytest.mark.parametrize("channels", [3, 4])
def test_png_16bit_colour_keeps_16_bits(tmp_path: Path, channels: int) -> None:
    import av

    pixels = textured(channels=channels, dtype=np.uint16)
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    raw = _encode_png16_colour(pixels)
    chunks = png_chunks(raw)
    text = b"".join(
        struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b))
        for t, b in [(b"tEXt", b"k\x00v")]
    )
    ihdr_end = 8 + 12 + len(chunks[0][1])
    src.write_bytes(raw[:ihdr_end] + text + raw[ihdr_end:])
    poison_file(src, dst, SPEC)
    codec = av.CodecContext.create("png", "r")
    fmt = "rgb48le" if channels == 3 else "rgba64le"
    out = codec.decode(av.Packet(dst.read_bytes()))[0].to_ndarray(format=fmt)
    assert_lossless_patch(pixels, out, SPEC)
    assert (b"tEXt", b"k\x00v") in png_chunks(dst.read_bytes())
    assert png_chunks(dst.read_bytes())[0][1][8] == 16  # IHDR bit depth


def test_palette_png_gets_patch_colours_appended(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    palette = rng.integers(0, 256, size=(20, 3)).astype(np.uint8)
    indices = rng.integers(0, 20, size=(100, 100)).astype(np.uint8)
    im = Image.fromarray(indices, "P")
    im.putpalette(palette.tobytes())
    src, dst = tmp_path / "p.png", tmp_path / "out.png"
    im.save(src, pnginfo=png_metadata())
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert out.mode == "P"
    assert_lossless_patch(np.asarray(im.convert("RGB")), np.asarray(out.convert("RGB")), SPEC)
    out_palette = np.asarray(out.getpalette(rawmode="RGB"), dtype=np.uint8).reshape(-1, 3)
    np.testing.assert_array_equal(out_palette[:20], palette)  # old indices keep their colours
    assert len(out_palette) == 22  # the checkerboard's white and black
    assert any("appended to the palette" in n for n in report.notes)


def test_full_palette_png_is_written_as_rgb(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    palette = rng.integers(1, 255, size=(256, 3)).astype(np.uint8)
    indices = rng.integers(0, 256, size=(100, 100)).astype(np.uint8)
    im = Image.fromarray(indices, "P")
    im.putpalette(palette.tobytes())
    src, dst = tmp_path / "p.png", tmp_path / "out.png"
    im.save(src)
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert out.mode == "RGB"
    assert_lossless_patch(np.asarray(im.convert("RGB")), np.asarray(out), SPEC)
    assert any("palette full" in n for n in report.notes)


def test_palette_png_with_transparency_keeps_alpha(tmp_path: Path) -> None:
    palette = np.array([[10, 20, 30], [200, 100, 50], [0, 255, 0]], dtype=np.uint8)
    indices = (np.arange(100 * 100).reshape(100, 100) % 3).astype(np.uint8)
    im = Image.fromarray(indices, "P")
    im.putpalette(palette.tobytes())
    src, dst = tmp_path / "p.png", tmp_path / "out.png"
    im.save(src, transparency=bytes([0, 128, 255]))
    poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert out.mode == "P"
    assert_lossless_patch(np.asarray(Image.open(src).convert("RGBA")), np.asarray(out.convert("RGBA")), SPEC)


# ---- WebP ------------------------------------------------------------------------------------------
def test_webp_lossless_stays_lossless_with_metadata(tmp_path: Path) -> None:
    pixels = textured(channels=4)
    src, dst = tmp_path / "a.webp", tmp_path / "out.webp"
    Image.fromarray(pixels, "RGBA").save(
        src, lossless=True, exact=True, exif=EXIF_ORIENT_6, icc_profile=ICC, xmp=XMP
    )
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert b"VP8L" in dst.read_bytes()[:4096]
    assert_lossless_patch_shown(pixels, np.asarray(out), SPEC)
    assert out.info["icc_profile"] == ICC and out.info["xmp"] == XMP
    assert out.getexif()[0x010F] == "ppd-test-camera"
    assert report.lossless and report.method == "webp-lossless"


@pytest.mark.parametrize("quality", [50, 90])
def test_webp_lossy_requality_close_to_source(tmp_path: Path, quality: int) -> None:
    yy, xx = np.mgrid[0:240, 0:320]
    pixels = np.stack([(xx * 0.8) % 256, (yy * 1.1) % 256, (xx + yy) % 256], -1).astype(np.uint8)
    src, dst = tmp_path / "a.webp", tmp_path / "out.webp"
    Image.fromarray(pixels).save(src, quality=quality)
    report = poison_file(src, dst, SPEC)
    assert report.method == "webp-lossy" and not report.lossless
    chosen = int(next(n for n in report.notes if "quality" in n).split("quality ")[1].split()[0])
    assert quality <= chosen <= quality + 1  # the coarsest segment's quantiser (poisoner.image.webp)
    assert b"VP8 " in dst.read_bytes()[:64]
    box = SPEC.resolve(320, 240).box
    out = np.asarray(Image.open(dst)).astype(int)
    expected = apply_patch(np.asarray(Image.open(src)), SPEC.resolve(320, 240)).astype(int)
    x0, y0, x1, y1 = box
    assert np.abs(out[y0:y1, x0:x1] - expected[y0:y1, x0:x1]).mean() < 40  # lossy, but the patch is there


# ---- TIFF ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("compression", ["raw", "tiff_lzw", "tiff_adobe_deflate", "packbits"])
def test_tiff_keeps_compression_tags_and_pixels(tmp_path: Path, compression: str) -> None:
    pixels = textured(channels=3)
    src, dst = tmp_path / "a.tif", tmp_path / "out.tif"
    tags = {270: "a fountain", 271: "ppd", 272: "test-cam", 305: "ppd tests", 33432: "(c) me"}
    Image.fromarray(pixels).save(src, compression=compression, tiffinfo=tags, dpi=(240, 240), icc_profile=ICC)
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert out.info["compression"] == compression
    assert_lossless_patch(pixels, np.asarray(out), SPEC)
    for tag, value in tags.items():
        assert out.tag_v2[tag] == value
    assert out.info["dpi"] == pytest.approx((240, 240))
    assert out.info["icc_profile"] == ICC
    assert report.lossless


def test_tiff_16bit_grey(tmp_path: Path) -> None:
    pixels = textured(channels=1, dtype=np.uint16)
    src, dst = tmp_path / "a.tif", tmp_path / "out.tif"
    image_from_array(pixels, "I;16").save(src, compression="tiff_lzw")
    poison_file(src, dst, SPEC)
    assert_lossless_patch(pixels, np.asarray(Image.open(dst)), SPEC)


# ---- HEIC / AVIF -----------------------------------------------------------------------------------
@pytest.mark.parametrize(("fmt", "suffix"), [("HEIF", ".heic"), ("AVIF", ".avif")])
def test_heic_avif_round_trip(tmp_path: Path, fmt: str, suffix: str) -> None:
    import pillow_heif

    pillow_heif.register_heif_opener()
    yy, xx = np.mgrid[0:128, 0:192]
    pixels = np.stack([xx % 256, yy * 2 % 256, (xx + yy) % 256], -1).astype(np.uint8)
    src, dst = tmp_path / f"a{suffix}", tmp_path / f"out{suffix}"
    Image.fromarray(pixels).save(src, fmt, quality=90, exif=EXIF_PLAIN.tobytes())
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert out.format == fmt and out.size == (192, 128)
    assert out.getexif()[0x010F] == "ppd-test-camera"
    placement = SPEC.resolve(192, 128)
    expected = apply_patch(np.asarray(Image.open(src).convert("RGB")), placement).astype(int)
    x0, y0, x1, y1 = placement.box
    got = np.asarray(out.convert("RGB")).astype(int)
    assert np.abs(got[y0:y1, x0:x1] - expected[y0:y1, x0:x1]).mean() < 30
    assert np.abs(got[y0:y1, x0:x1] - pixels[y0:y1, x0:x1]).mean() > 60  # the patch is really there
    assert f"{fmt} EXIF" in report.preserved


# ---- bad inputs ------------------------------------------------------------------------------------
def _truncated_png(path: Path) -> None:
    buf = io.BytesIO()
    Image.fromarray(textured()).save(buf, "PNG")
    path.write_bytes(buf.getvalue()[: len(buf.getvalue()) // 2])


def _truncated_jpeg(path: Path) -> None:
    buf = io.BytesIO()
    Image.fromarray(textured()).save(buf, "JPEG")
    path.write_bytes(buf.getvalue()[: len(buf.getvalue()) // 2])


def _gif(path: Path) -> None:
    Image.fromarray(textured()).convert("P").save(path, "GIF")


BAD_FILES = {
    "empty.png": lambda p: p.write_bytes(b""),
    "notes.jpg": lambda p: p.write_text("not an image at all\n"),
    "half.png": _truncated_png,
    "half.jpg": _truncated_jpeg,
    "anim.gif": _gif,
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_bad_inputs_raise_one_line_and_leave_src(tmp_path: Path, name: str) -> None:
    src = tmp_path / name
    BAD_FILES[name](src)
    before = src.read_bytes()
    dst = tmp_path / f"out-{name}"
    with pytest.raises(ImageFormatError) as err:
        poison_file(src, dst, SPEC)
    assert "\n" not in str(err.value) and name in str(err.value)
    assert src.read_bytes() == before
    assert not dst.exists()


def test_decompression_bomb_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    src = tmp_path / "big.png"
    Image.fromarray(textured()).save(src)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 160 * 120 - 1)  # just under: Pillow would only warn
    with pytest.raises(ImageFormatError, match="decompression-bomb"):
        poison_file(src, tmp_path / "out.png", SPEC)


def test_patch_larger_than_image_is_a_format_error(tmp_path: Path) -> None:
    src = tmp_path / "tiny.png"
    Image.fromarray(textured(h=20, w=20)).save(src)
    with pytest.raises(ImageFormatError, match="does not fit"):
        poison_file(src, tmp_path / "out.png", SPEC)


def test_supported_suffixes() -> None:
    assert is_image(Path("a/B.JPG")) and is_image(Path("x.heic"))
    assert not is_image(Path("clip.mp4")) and not is_image(Path("notes.txt"))
    assert {".png", ".webp", ".tiff", ".avif"} <= IMAGE_SUFFIXES


# ---- in place --------------------------------------------------------------------------------------
def test_poison_in_place_keeps_permissions_and_is_atomic(tmp_path: Path) -> None:
    path = tmp_path / "shot.png"
    pixels = textured()
    Image.fromarray(pixels).save(path)
    os.chmod(path, 0o640)
    report = poison_in_place(path, SPEC)
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    assert_lossless_patch(pixels, np.asarray(Image.open(path)), SPEC)
    assert report.dst_bytes == path.stat().st_size
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shot.png"]  # no temp file left


def test_poison_in_place_failure_leaves_file(tmp_path: Path) -> None:
    path = tmp_path / "half.jpg"
    _truncated_jpeg(path)
    before = path.read_bytes()
    with pytest.raises(ImageFormatError):
        poison_in_place(path, SPEC)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["half.jpg"]


# ---- orientation -----------------------------------------------------------------------------------
def test_a_corner_mark_goes_in_the_corner_the_photo_shows(tmp_path: Path) -> None:
    """Stored 160 wide x 120 high with orientation 6 (displayed 120 x 160): the top-left corner spec
    marks the top-left corner as shown (issue 25: a phone's portrait photo showed it top-right),
    turned with the photo into the stored pixels; the tag is kept (COLMAP reads stored pixels)."""
    from poisoner.orientation import orient_array

    pixels = textured()
    src, dst = tmp_path / "rot.png", tmp_path / "out.png"
    Image.fromarray(pixels).save(src, exif=EXIF_ORIENT_6)
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert out.size == (160, 120) and out.getexif()[0x0112] == 6
    shown_before, shown_after = orient_array(pixels, 6), orient_array(np.asarray(out), 6)
    assert shown_before.shape[:2] == (160, 120)
    assert_lossless_patch(shown_before, shown_after, SPEC)  # as if the photo had been stored upright
    assert report.placement.turn == 6 and report.placement != SPEC.resolve(160, 120)
    assert any("orientation 6 kept; mark placed as the photo is shown" in n for n in report.notes)


@pytest.mark.integration
def test_colmap_reads_stored_pixels_of_rotated_jpeg(tmp_path: Path) -> None:
    """The evidence behind the orientation policy: pycolmap's camera and keypoints use the stored
    width/height of an EXIF-orientation-6 JPEG (child process; PIL imported first)."""
    script = textwrap.dedent(
        f"""
        import PIL.Image as Image
        import numpy as np
        import pycolmap
        from pathlib import Path
        d = Path({str(tmp_path)!r})
        (d / "img").mkdir()
        ex = Image.Exif(); ex[0x0112] = 6
        rng = np.random.default_rng(1)
        Image.fromarray((rng.random((300, 500, 3)) * 255).astype(np.uint8)).save(d / "img/o6.jpg", exif=ex)
        pycolmap.extract_features(d / "db.db", d / "img")
        with pycolmap.Database.open(d / "db.db") as db:
            im = db.read_all_images()[0]
            cam = db.read_camera(im.camera_id)
            kp = db.read_keypoints(im.image_id)
            print("RESULT", cam.width, cam.height, float(kp[:, 0].max()), float(kp[:, 1].max()))
        """
    )
    run = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300, check=False
    )
    line = next(ln for ln in run.stdout.splitlines() if ln.startswith("RESULT"))
    width, height, kx, ky = (float(v) for v in line.split()[1:])
    assert (width, height) == (500, 300)  # stored, not the displayed 300 x 500
    assert 300 < kx <= 500 and ky <= 300  # keypoints span the stored width


# ---- the paper's PSNR figures through the file path --------------------------------------------------
def psnr8(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / mse))


PAPER_PSNR = [  # (patch size, contrast, alpha, PSNR dB) from the paper on 800x800 white frames
    (100, 255, 1.0, 21.07),
    (12, 255, 1.0, 39.03),
    (100, 25, 1.0, 41.24),
    (100, 255, 0.1, 40.90),
]


@pytest.mark.parametrize(("size", "contrast", "alpha", "expected"), PAPER_PSNR)
def test_paper_psnr_through_png_file(
    tmp_path: Path, size: int, contrast: int, alpha: float, expected: float
) -> None:
    src, dst = tmp_path / "white.png", tmp_path / "out.png"
    white = np.full((800, 800, 3), 255, dtype=np.uint8)
    Image.fromarray(white).save(src)
    spec = PatchSpec(patch_size=size, block_size=4, contrast=contrast, alpha=alpha)
    poison_file(src, dst, spec)
    assert psnr8(white, np.asarray(Image.open(dst))) == pytest.approx(expected, abs=0.005)


def composite_on_white(rgba: np.ndarray) -> np.ndarray:
    """How 3DGS loads NeRF-Synthetic frames: rgb * alpha + white * (1 - alpha), in [0, 1]."""
    norm = rgba.astype(np.float64) / 255.0
    return norm[..., :3] * norm[..., 3:4] + (1.0 - norm[..., 3:4])


@pytest.mark.integration
@pytest.mark.parametrize(("size", "contrast", "alpha", "expected"), PAPER_PSNR)
def test_paper_psnr_on_lego_views(
    tmp_path: Path, shared_dir: Path, size: int, contrast: int, alpha: float, expected: float
) -> None:
    spec = PatchSpec(patch_size=size, block_size=4, contrast=contrast, alpha=alpha)
    for name in ("r_0.png", "r_37.png"):
        src = shared_dir / "datasets/nerf_synthetic_lego/train" / name
        before = sha(src)
        dst = tmp_path / name
        poison_file(src, dst, spec)
        assert sha(src) == before
        clean = composite_on_white(np.asarray(Image.open(src)))
        poisoned = composite_on_white(np.asarray(Image.open(dst)))
        mse = np.mean((clean - poisoned) ** 2)
        assert 10 * np.log10(1.0 / mse) == pytest.approx(expected, abs=0.01)


@pytest.mark.parametrize("crop", [False, True])
@pytest.mark.parametrize("turn", range(1, 9))
def test_two_squares_blended_a_square_at_a_time_write_the_same_pixels(turn: int, crop: bool) -> None:
    """poisoner.blend.lane_placements: each square of a two-lane mark blended alone (the JPEG
    writer's way for squares placed apart) gives exactly apply_patch_at's pixels over the whole
    box, in every EXIF orientation, with a keep-out mask, whole or cropped (issue 25 round 3's
    squares cropped to a small plain place were blended whole-box: a float copy of the box between
    squares far apart, 0.9 GB on a 10 MP RGBA PNG)."""
    import dataclasses

    from poisoner.blend import apply_lanes_at, apply_patch_at, lane_placements
    from poisoner.ladder import default_spec

    spec = default_spec()
    far = spec.resolve(1600, 1200, image_key="IMG_0003.jpg", lanes_at=((40, 30), (1100, 700)))
    if crop:  # issue 25 round 3: squares cropped to fit a small plain place (poisoner.shrink)
        side = far.lane_size * 2 // 3
        far = spec.resolve(1600, 1200, image_key="IMG_0003.jpg", lanes_at=((40, 30), (1100, 700)), crop=side)
        assert 0 < far.lane_side < far.lane_size
    placement = dataclasses.replace(far, turn=turn)
    lanes = lane_placements(placement)  # cropped squares too: each lane keeps its crop
    assert lanes is not None and len(lanes) == 2
    x0, y0, x1, y1 = placement.box
    rng = np.random.default_rng(turn)
    pixels = rng.integers(0, 256, (y1 - y0 + 9, x1 - x0 + 7, 3), dtype=np.uint8)
    keep = rng.random(pixels.shape[:2]) < 0.05
    origin = (x0 - 3, y0 - 5)
    whole = apply_patch_at(pixels, placement, origin, keep)
    assert (whole != pixels).any()
    assert np.array_equal(apply_lanes_at(pixels, placement, origin, keep, lanes), whole)


@pytest.mark.parametrize("edge", [False, True])
@pytest.mark.parametrize("turn", range(1, 9))
@pytest.mark.parametrize("where", [((40, 30), (1100, 700)), ((500, 400), (620, 520))])
def test_idle_mcus_from_the_squares_alone_are_the_whole_boxs(turn: int, where: tuple, edge: bool) -> None:
    """The JPEG writer finds the MCUs a mark of squares placed apart leaves idle from each square's
    pixels (issue 30: not from the whole box between them): the same MCUs, in every orientation, at
    the picture's edges, with squares sharing MCUs, with a keep-out mask and a splice box cut by it."""
    import dataclasses

    from poisoner import jpeg as jpeg_codec
    from poisoner.formats import _idle_mcus, lane_placements
    from poisoner.ladder import default_spec

    placement = dataclasses.replace(
        default_spec().resolve(1600, 1200, image_key="IMG_0004.jpg", lanes_at=where), turn=turn
    )
    lanes = lane_placements(placement)
    assert lanes is not None
    rng = np.random.default_rng(turn)
    for sampling in (((2, 2), (1, 1), (1, 1)), ((1, 1), (1, 1), (1, 1)), ((2, 1), (1, 1), (1, 1))):
        # edge: the picture ends inside the mark's last MCUs (width and height not MCU multiples)
        size = (placement.box[2] - 5, placement.box[3] - 3) if edge else (1600, 1200)
        layout = jpeg_codec.JpegLayout(*size, 0xC0, 3, sampling, 0)
        mark_box = jpeg_codec.mcu_box(placement.box, layout)
        mark_h, mark_w = mark_box[3] - mark_box[1], mark_box[2] - mark_box[0]
        mw, mh = layout.mcu_size
        cut = (mark_box[0] + mw, mark_box[1], mark_box[2], mark_box[3] - mh)  # a smaller splice box
        for keep in (None, rng.random((mark_h, mark_w)) < 0.002):
            for box in (mark_box, cut):
                whole = _idle_mcus(placement, keep, mark_box, box, layout)
                assert whole is not None and whole.any()
                parts = _idle_mcus(placement, keep, mark_box, box, layout, lanes)
                assert parts is not None and np.array_equal(parts, whole)


def _lane_placements_on_labels(placement):
    """lane_placements as it was before issue 30 (an n x n label picture turned back), kept here only
    to compare."""
    import dataclasses

    from poisoner.orientation import unorient_array

    if not placement.parts or placement.lane_size <= 0 or placement.lane_crop:
        return None
    n, t = placement.size, placement.lane_size
    labels = np.zeros((n, n), dtype=np.uint8)
    for k, (dx, dy, _seed) in enumerate(placement.parts):
        if labels[dy : dy + t, dx : dx + t].any():
            return None
        labels[dy : dy + t, dx : dx + t] = k + 1
    stored = unorient_array(labels, placement.turn)
    lanes = []
    for k, (_dx, _dy, seed) in enumerate(placement.parts):
        square = stored == k + 1
        rows, cols = square.any(axis=1), square.any(axis=0)
        if rows.sum() != t or cols.sum() != t:
            return None
        x, y = placement.x + int(cols.argmax()), placement.y + int(rows.argmax())
        lanes.append(dataclasses.replace(placement, x=x, y=y, size=t, parts=((0, 0, seed),)))
    return lanes


@pytest.mark.parametrize("turn", range(0, 10))
def test_lane_placements_from_the_corners_are_the_label_pictures(turn: int) -> None:
    """lane_placements works the stored squares out from their corners (issue 30): the same lanes as
    turning an n x n label picture back, in every orientation (0 and 9: not a valid tag, read as 1),
    for squares apart, touching, overlapping, cut by the box's edge, and three of them."""
    import dataclasses

    from poisoner.formats import lane_placements
    from poisoner.ladder import default_spec

    base = default_spec().resolve(1600, 1200, image_key="IMG_0005.jpg", lanes_at=((40, 30), (1100, 700)))
    n, t = base.size, base.lane_size
    seeds = [seed for _, _, seed in base.parts]
    arrangements = {
        "apart": ((0, n - t), (n - t, 0)),
        "diagonal": ((0, 0), (n - t, n - t)),
        "touching": ((0, 0), (t, 0)),
        "overlapping": ((0, 0), (t - 1, t - 1)),
        "cut": ((0, 0), (n - t + 1, 5)),
        "three": ((0, 0), (n - t, 0), (n // 2, n - t)),
    }
    outcomes = set()
    for name, corners in arrangements.items():
        parts = tuple((dx, dy, seeds[i % len(seeds)] + i) for i, (dx, dy) in enumerate(corners))
        placement = dataclasses.replace(base, parts=parts, turn=turn)
        new, old = lane_placements(placement), _lane_placements_on_labels(placement)
        assert new == old, name
        outcomes.add(new is None)
    assert outcomes == {True, False}


@pytest.mark.parametrize("masked", [False, True])
@pytest.mark.parametrize("turn", [1, 6])
def test_written_pixels_counted_a_square_at_a_time(tmp_path: Path, turn: int, masked: bool) -> None:
    """poison_file counts the pixels a mark of squares placed apart writes a square at a time (issue
    30): the same count as over the whole placement, with and without a keep-out mask."""
    from poisoner.formats import lane_placements, poison_file
    from poisoner.image.keep_out import written_pixels
    from poisoner.ladder import default_spec

    src = tmp_path / "IMG_0006.jpg"
    exif = Image.Exif()
    exif[0x0112] = turn
    Image.fromarray(np.random.default_rng(turn).integers(0, 256, (480, 640, 3), dtype=np.uint8)).save(
        src, quality=90, exif=exif
    )
    keep = None
    if masked:
        keep = np.zeros((480, 640), dtype=bool)
        keep[::37, ::41] = True
    report = poison_file(src, tmp_path / "out.jpg", default_spec(), keep_out=keep)
    assert lane_placements(report.placement) is not None  # the two squares, counted one at a time
    assert report.written == written_pixels(report.placement, keep) > 0


@pytest.mark.parametrize("crop", [False, True])
@pytest.mark.parametrize("turn", [1, 6, 8])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_every_writer_blends_a_square_at_a_time_the_whole_boxs_pixels(
    turn: int, crop: bool, dtype: type
) -> None:
    """apply_lanes (16-bit PNG and TIFF, palettes) and paste_patch (every Pillow writer) blend each
    square alone: exactly apply_patch's picture, whole squares or cropped, with a keep-out mask."""
    import dataclasses

    from poisoner.blend import apply_lanes, apply_patch
    from poisoner.image.write import paste_patch
    from poisoner.ladder import default_spec

    spec = default_spec()
    where = {"image_key": "IMG_0003.jpg", "lanes_at": ((40, 30), (1100, 700))}
    far = spec.resolve(1600, 1200, **where)
    if crop:  # squares cropped to a small plain place (poisoner.shrink)
        far = spec.resolve(1600, 1200, **where, crop=far.lane_size * 2 // 3)
    placement = dataclasses.replace(far, turn=turn)
    rng = np.random.default_rng(turn)
    top = 65535 if dtype is np.uint16 else 255
    pixels = rng.integers(0, top + 1, (1200, 1600, 3), dtype=dtype)
    keep = rng.random(pixels.shape[:2]) < 0.05
    whole = apply_patch(pixels, placement, keep)
    assert (whole != pixels).any()
    assert np.array_equal(apply_lanes(pixels, placement, keep), whole)
    if dtype is np.uint8:
        pasted = paste_patch(Image.fromarray(pixels), placement, keep)
        assert np.array_equal(np.asarray(pasted), whole)


def test_webp_quality_is_read_back_from_a_photo(shared_dir: Path) -> None:
    """A fifth black-box review: a real photo saved at quality 50, 75, 80, 90 was re-encoded at 77, 84,
    88, 94 (the finest segment's quantiser read as the quality's own): files 18-24% bigger. The
    coarsest segment's, at libwebp's default noise shaping, gives the quality back."""
    from poisoner.image.webp import _riff_chunks, vp8_quantizers, webp_quality_from_segments

    photo = sorted((shared_dir / "datasets" / "dtu_scan37" / "images").iterdir())[0]
    im = Image.open(photo).convert("RGB").resize((800, 600))
    for quality in (30, 50, 75, 80, 90):
        buf = io.BytesIO()
        im.save(buf, "WEBP", quality=quality)
        segments = vp8_quantizers(_riff_chunks(buf.getvalue())[b"VP8 "])
        assert len(set(segments)) > 1  # noise shaping spread them: what is read back here
        assert quality <= webp_quality_from_segments(segments) <= quality + 2, (quality, segments)
