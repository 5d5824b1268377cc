"""Format defects a black-box review found (2026-12-07), each written as the file that showed it."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
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


@pytest.mark.parametrize("mode", ["RGB;16", "L;16"])
def test_ten_bit_heic_keeps_its_bit_depth(tmp_path: Path, mode: str) -> None:
    """A 10-bit HEIC came out 8-bit, its note saying only "re-encoded at quality 90". Now pillow-heif
    decodes and writes it at 10 bits and the note says so; the mark is there at full scale."""
    pillow_heif = pytest.importorskip("pillow_heif")
    src, dst = tmp_path / "x.heic", tmp_path / "out.heic"
    levels = np.asarray(photo(320, 240)).astype(np.uint16) * 257
    if mode == "L;16":
        levels = np.ascontiguousarray(levels[:, :, 1])
    pillow_heif.from_bytes(mode=mode, size=(320, 240), data=levels.tobytes()).save(src, quality=90)
    assert pillow_heif.open_heif(src).info["bit_depth"] == 10
    report = poison_file(src, dst, default_spec())
    assert pillow_heif.open_heif(dst).info["bit_depth"] == 10
    assert any("10-bit kept" in n for n in report.notes), report.notes
    before = np.asarray(pillow_heif.open_heif(src, convert_hdr_to_8bit=False)[0]).astype(int)
    after = np.asarray(pillow_heif.open_heif(dst, convert_hdr_to_8bit=False)[0]).astype(int)
    x0, y0, x1, y1 = report.placement.box
    changed = np.abs(after - before)[y0:y1, x0:x1]
    assert changed.max() > 8000  # the mark, not the re-encode's noise


def ten_bit_avif(path: Path, picture: Image.Image) -> None:
    """A 10-bit AVIF written with FFmpeg's SVT-AV1 (PyAV): Pillow's AVIF writer has 8 bits only."""
    av = pytest.importorskip("av")
    if "libsvtav1" not in av.codecs_available:
        pytest.skip("no AV1 encoder in this FFmpeg")
    with av.open(str(path), "w", format="avif") as out:
        stream = out.add_stream("libsvtav1", rate=1)
        stream.width, stream.height, stream.pix_fmt = picture.width, picture.height, "yuv420p10le"
        levels = np.asarray(picture).astype(np.uint16) * 257
        frame = av.VideoFrame.from_ndarray(levels, format="rgb48le").reformat(format="yuv420p10le")
        for packet in [*stream.encode(frame), *stream.encode()]:
            out.mux(packet)


def test_ten_bit_avif_written_as_eight_bit_says_so(tmp_path: Path) -> None:
    """Pillow reads and writes AVIF at 8 bits a sample and pillow-heif here has no AV1 codec: a
    10-bit AVIF cannot keep its depth, so the note says it was written as 8-bit (ppd poison's
    summary counts notes saying " written as ")."""
    from poisoner.image.heif import declared_bit_depth

    src, dst = tmp_path / "a.avif", tmp_path / "out.avif"
    ten_bit_avif(src, photo(320, 240))
    assert declared_bit_depth(src.read_bytes()) == 10
    report = poison_file(src, dst, default_spec())
    assert declared_bit_depth(dst.read_bytes()) == 8
    assert any("10-bit samples written as 8-bit" in n for n in report.notes), report.notes


@pytest.mark.parametrize(("mode", "key"), [("RGB", (0, 0, 0)), ("L", 0), ("RGB", (255, 255, 255))])
def test_colour_key_png_mark_stays_opaque(tmp_path: Path, mode: str, key: object) -> None:
    """A PNG with a tRNS colour key (RGB or grey saved with transparency=): mark pixels equal to the
    key showed as transparent (on a black background most of the mark vanished). Each such pixel is
    moved one level off the key; the photo's own transparent pixels stay transparent."""
    from poisoner.blend import lane_placements, patch_coverage

    src, dst = tmp_path / "key.png", tmp_path / "out.png"
    level = key[0] if isinstance(key, tuple) else key
    picture = np.full((240, 320, 3) if mode == "RGB" else (240, 320), level, np.uint8)
    picture[:, 200:] = 128  # an opaque part
    Image.fromarray(picture, mode).save(src, transparency=key)
    report = poison_file(src, dst, default_spec())
    with Image.open(dst) as out:
        assert out.info.get("transparency") == key  # the key itself is kept
        alpha = np.asarray(out.convert("RGBA"))[:, :, 3]
        values = np.asarray(out)
    covered = np.zeros(alpha.shape, dtype=bool)
    for part in lane_placements(report.placement) or [report.placement]:
        x0, y0, x1, y1 = part.box
        covered[y0:y1, x0:x1] |= patch_coverage(part)
    assert covered.any() and (alpha[covered] == 255).all()  # every mark pixel opaque
    clear = (picture[..., 0] if mode == "RGB" else picture) == level
    assert (alpha[~covered & clear] == 0).all()  # the photo's transparent pixels stay so
    moved = np.abs(values[covered].astype(int) - level).max(axis=-1) == 1 if mode == "RGB" else None
    assert moved is None or moved.any()
    assert any("tRNS colour key moved one level off it" in n for n in report.notes), report.notes


def arithmetic_jpeg(path: Path, progressive: bool = False, picture: Image.Image | None = None) -> Path:
    """A JPEG coded arithmetically by jpegtran (libjpeg-turbo) from Pillow's Huffman-coded one."""
    import shutil
    import subprocess

    jpegtran = shutil.which("jpegtran")
    if jpegtran is None:
        pytest.skip("no jpegtran")
    huffman = io.BytesIO()
    (photo() if picture is None else picture).save(huffman, "JPEG", quality=90)
    cmd = [jpegtran, "-copy", "all", "-arithmetic", *(["-progressive"] if progressive else [])]
    path.write_bytes(subprocess.run(cmd, input=huffman.getvalue(), capture_output=True, check=True).stdout)
    return path


def cjpeg_arithmetic(path: Path) -> Path:
    """An arithmetic JPEG of noise as libjpeg-turbo's cjpeg writes it, like the review's file: Pillow's
    libjpeg fails on it ("broken data stream"), where it decodes the small smooth ones above."""
    import shutil
    import subprocess

    if shutil.which("cjpeg") is None:
        pytest.skip("no cjpeg")
    ppm = path.with_suffix(".ppm")
    Image.fromarray(np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)).save(ppm)
    subprocess.run(["cjpeg", "-arithmetic", "-outfile", str(path), str(ppm)], check=True)
    return path


def decoded(data: bytes) -> np.ndarray:
    """Pixels of any JPEG, arithmetic or not: jpegtran codes it with Huffman tables, Pillow decodes."""
    import subprocess

    run = subprocess.run(["jpegtran", "-copy", "none"], input=data, capture_output=True, check=True)
    huffman = run.stdout
    return np.asarray(Image.open(io.BytesIO(huffman))).astype(int)


@pytest.mark.parametrize("progressive", [False, True])
def test_arithmetic_jpeg_is_patched_and_stays_arithmetic(tmp_path: Path, progressive: bool) -> None:
    """An arithmetic-coded JPEG: the dry run said "would patch", the run failed ("arithmetic-coded JPEG
    that Pillow cannot decode"). jpegtran codes it with Huffman tables (the same coefficients), ppd
    patches that, and the output is coded back as the source was; outside the mark's MCUs no pixel
    moves."""
    from poisoner.errors import MarkNotWritten
    from poisoner.jpeg import read_layout

    src, dst = arithmetic_jpeg(tmp_path / "a.jpg", progressive), tmp_path / "out.jpg"
    assert read_layout(src.read_bytes()).arithmetic
    check_writable_image(src, src.name)
    report = poison_file(src, dst, default_spec())
    layout = read_layout(dst.read_bytes())
    assert layout.arithmetic and layout.progressive == progressive
    assert any("arithmetic coding" in n for n in report.notes), report.notes
    before, after = decoded(src.read_bytes()), decoded(dst.read_bytes())
    x0, y0, x1, y1 = report.placement.box
    moved = np.argwhere((before != after).any(axis=2))
    assert len(moved)
    mcu = 16  # Pillow's 4:2:0
    assert moved.min(0).tolist() >= [y0 // mcu * mcu - 1, x0 // mcu * mcu - 1]
    assert moved.max(0).tolist() <= [-(-y1 // mcu) * mcu, -(-x1 // mcu) * mcu]
    plain = arithmetic_jpeg(tmp_path / "white.jpg", progressive, Image.new("RGB", (640, 480), "white"))
    with pytest.raises(MarkNotWritten, match="too faint"):  # checked before it is coded back
        poison_file(plain, tmp_path / "faint.jpg", default_spec().replace(alpha=0.001))
    assert not (tmp_path / "faint.jpg").exists()


def test_arithmetic_jpeg_without_jpegtran_is_refused_by_the_header_check_too(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without jpegtran (PPD_JPEGTRAN="") an arithmetic JPEG that Pillow's libjpeg cannot decode is
    refused: by the dry run's and preview's header check with the same line as by the run."""
    from poisoner.errors import ImageFormatError

    src = cjpeg_arithmetic(tmp_path / "a.jpg")
    monkeypatch.setenv("PPD_JPEGTRAN", "")
    try:
        Image.open(src).load()
        pytest.skip("this Pillow decodes arithmetic coding")
    except OSError:
        pass
    with pytest.raises(ImageFormatError) as late:
        poison_file(src, tmp_path / "out.jpg", default_spec())
    with pytest.raises(ImageFormatError) as early:
        check_writable_image(src, src.name)
    assert str(early.value) == str(late.value) and "arithmetic-coded" in str(early.value)


@pytest.mark.parametrize("compression", ["tiff_lzw", "tiff_adobe_deflate"])
def test_tiff_keeps_its_horizontal_predictor(tmp_path: Path, compression: str) -> None:
    """An LZW TIFF with the horizontal predictor (tag 317 = 2) lost it and grew ~23%. Pillow's libtiff
    writer applies the predictor when the tag is passed: it is, and the size stays the source's."""
    src, dst = tmp_path / "t.tif", tmp_path / "out.tif"
    photo(800, 600).save(src, compression=compression, tiffinfo={317: 2})
    with Image.open(src) as opened:
        assert opened.tag_v2.get(317) == 2
    report = poison_file(src, dst, default_spec())
    with Image.open(dst) as out:
        assert out.tag_v2.get(317) == 2 and out.info["compression"] == compression
    assert dst.stat().st_size < src.stat().st_size * 1.05, (dst.stat().st_size, src.stat().st_size)
    assert "TIFF Predictor" in report.preserved


def test_data_after_a_png_iend_is_counted_like_a_jpeg_trailer(tmp_path: Path) -> None:
    """Bytes after a PNG's IEND were dropped without a word; a JPEG's trailer gets a note and ppd
    poison's summary line (trailer_bytes). A PNG's now does too."""
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    photo().save(src)
    src.write_bytes(src.read_bytes() + b"TRAILER!" * 4)
    report = poison_file(src, dst, default_spec())
    assert report.trailer_bytes == 32
    assert any("32 bytes after the picture's end" in n for n in report.notes), report.notes
    assert dst.read_bytes().endswith(b"IEND\xaeB`\x82")


def test_the_arithmetic_check_reads_the_frame_header_only(tmp_path: Path) -> None:
    """The header check read every JPEG whole to look for arithmetic coding (a diff review); the frame
    header says it. Baseline and progressive, Huffman and arithmetic, and a file cut after its header."""
    import shutil as _shutil
    import subprocess as _subprocess

    from poisoner.image.read import _arithmetic_frame

    if _shutil.which("cjpeg") is None:
        pytest.skip("cjpeg (libjpeg-turbo's tools) is not installed")
    Image.fromarray(np.random.default_rng(3).integers(0, 256, (120, 160, 3), dtype=np.uint8)).save(
        tmp_path / "x.ppm"
    )
    for flags, arithmetic in (([], False), (["-progressive"], False), (["-arithmetic"], True),
                              (["-arithmetic", "-progressive"], True)):  # fmt: skip
        out = tmp_path / f"{'_'.join(flags) or 'plain'}.jpg"
        _subprocess.run(["cjpeg", *flags, "-outfile", str(out), str(tmp_path / "x.ppm")], check=True)
        assert _arithmetic_frame(out) is arithmetic, flags
        cut = tmp_path / "cut.jpg"
        data = out.read_bytes()
        cut.write_bytes(data[: data.index(b"\xff\xda") + 2])  # nothing after the first scan's marker
        assert _arithmetic_frame(cut) is arithmetic, flags
