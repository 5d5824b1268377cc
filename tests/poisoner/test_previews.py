"""A patched file carries no picture of the unmarked original in its metadata (a black-box review,
F3: the EXIF thumbnail of every camera JPEG came out byte for byte the original's).

Every file here carries a real thumbnail of the original picture (testkit.thumbnails); each test
fails if a run of that thumbnail's coded bytes is still in the output, and checks that what takes
its place decodes and shows the patched picture, and that the rest of the metadata is as it was."""

from __future__ import annotations

import base64
import io
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import ExifTags, Image, ImageCms, PngImagePlugin

from poisoner import jpeg as jpeg_codec
from poisoner import location
from poisoner.formats import png_chunks, poison_file
from poisoner.spec import PatchSpec
from testkit.thumbnails import (
    ARTIST,
    MAKER_NOTE,
    camera_picture,
    exif_with_thumbnail,
    extended_xmp_segments,
    flashpix_segments,
    jpeg_of,
    photoshop_thumbnail_block,
    with_app_segment,
    xmp_with_thumbnail,
)

# a mark large enough to show in a 160x120 thumbnail (40 px there)
SPEC = PatchSpec(patch_size=160, block_size=16, position="top-left", offset=(16, 16))
THUMB = (160, 120)


def original_thumbnail(picture: Image.Image, size: tuple[int, int] = THUMB) -> bytes:
    return jpeg_of(picture.resize(size, Image.Resampling.LANCZOS))


def assert_no_run_of(old_jpeg: bytes, out: bytes) -> None:
    """No 32-byte run of the old thumbnail's entropy-coded data is anywhere in out (its headers, the
    standard Huffman tables and the quantisation tables, may well be: the same quality is kept)."""
    scan = old_jpeg[old_jpeg.index(b"\xff\xda") + 14 : -2]
    assert len(scan) > 1000
    for i in range(0, len(scan) - 32, 16):
        assert scan[i : i + 32] not in out, f"the original's thumbnail is still there (byte {i})"


def tiff_of(im: Image.Image) -> bytes:
    exif = im.info["exif"]
    return exif[6:] if exif.startswith(b"Exif\x00\x00") else exif


def exif_thumbnail(im: Image.Image) -> bytes | None:
    """The thumbnail IFD1 points at, read by Pillow (not by ppd's parser)."""
    ifd1 = im.getexif().get_ifd(ExifTags.IFD.IFD1)
    if 0x0201 not in ifd1:
        return None
    tiff = tiff_of(im)
    return tiff[ifd1[0x0201] : ifd1[0x0201] + ifd1[0x0202]]


def assert_shows_the_patched_picture(thumb: Image.Image, patched: Image.Image, original: Image.Image) -> None:
    """The thumbnail is the patched picture made small, not the original: compared where the mark is."""
    size = thumb.size
    x0, y0 = 16 * size[0] // patched.width, 16 * size[1] // patched.height
    x1, y1 = 176 * size[0] // patched.width, 176 * size[1] // patched.height

    def diff(other: Image.Image) -> float:
        small = np.asarray(other.convert("RGB").resize(size, Image.Resampling.LANCZOS), dtype=np.int32)
        return float(np.abs(np.asarray(thumb.convert("RGB"), dtype=np.int32) - small)[y0:y1, x0:x1].mean())

    to_patched, to_original = diff(patched), diff(original)
    # (the mark's sharp squares at 4 px, coded lossily, each writer scaling its own way: never exact;
    # the original is far off: 120 where the patched picture is 10 to 30)
    assert to_patched < 40 and to_original > 3 * to_patched, (to_patched, to_original)


@pytest.mark.parametrize("order", ["<", ">"], ids=["II", "MM"])
@pytest.mark.parametrize("keep_location", [False, True])
def test_jpeg_exif_thumbnail_is_the_patched_pictures(tmp_path: Path, order: str, keep_location: bool) -> None:
    picture = camera_picture()
    old = original_thumbnail(picture)
    exif = exif_with_thumbnail(old, order)
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    buf = io.BytesIO()
    picture.save(buf, "JPEG", quality=90, exif=exif.block)
    src.write_bytes(buf.getvalue())
    report = poison_file(src, dst, SPEC, keep_location=keep_location)
    out = dst.read_bytes()
    assert_no_run_of(old, out)
    assert "EXIF thumbnail (160x120) replaced by the patched picture's" in report.notes
    with Image.open(dst) as done:
        block = done.info["exif"]
        thumb_bytes = exif_thumbnail(done)
        done.load()
        assert thumb_bytes is not None
        with Image.open(io.BytesIO(thumb_bytes)) as thumb:
            assert thumb.size == THUMB
            thumb.load()
            assert_shows_the_patched_picture(thumb, done, picture)
    # the block is as long as it was and every byte outside the thumbnail and its length is the same
    assert len(block) == len(exif.block)
    la, ta = exif.length_at, exif.thumbnail_at
    assert block[:la] == exif.block[:la] and block[la + 4 : ta] == exif.block[la + 4 : ta]
    assert struct.unpack(order + "I", block[la : la + 4])[0] == len(thumb_bytes)
    assert block[ta + len(thumb_bytes) :] == bytes(len(exif.block) - ta - len(thumb_bytes))
    assert MAKER_NOTE in block and ARTIST in block


def test_a_thumbnail_the_patched_picture_cannot_fit_is_removed_bytes_and_all(tmp_path: Path) -> None:
    """A tiny thumbnail (a flat grey, 600 bytes) no JPEG of the detailed patched picture fits in: its
    bytes are zeros, IFD1 is unlinked, everything else in the block stays."""
    picture = Image.fromarray(np.random.default_rng(2).integers(0, 256, (480, 640, 3), dtype=np.uint8))
    old = jpeg_of(Image.new("RGB", THUMB, (90, 90, 90)))
    exif = exif_with_thumbnail(old)
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    picture.save(src, "JPEG", quality=90, exif=exif.block)
    report = poison_file(src, dst, SPEC)
    assert any(n.startswith("EXIF thumbnail removed") for n in report.notes), report.notes
    with Image.open(dst) as done:
        block = done.info["exif"]
        assert exif_thumbnail(done) is None and done.getexif().get_ifd(ExifTags.IFD.IFD1) == {}
        assert done.getexif()[0x013B] == ARTIST[:-1].decode()
    assert len(block) == len(exif.block) and old not in dst.read_bytes()
    assert block[exif.thumbnail_at :] == bytes(len(old))
    assert block[exif.next_ifd_at : exif.next_ifd_at + 4] == bytes(4)
    assert block[: exif.next_ifd_at] == exif.block[: exif.next_ifd_at]


def test_an_uncompressed_strip_thumbnail_is_rewritten_in_place(tmp_path: Path) -> None:
    picture = camera_picture()
    old = picture.resize((80, 60)).tobytes()
    exif = exif_with_thumbnail(old, strips=(80, 60))
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    picture.save(src, "JPEG", quality=90, exif=exif.block)
    report = poison_file(src, dst, SPEC)
    assert "EXIF thumbnail (80x60) replaced by the patched picture's" in report.notes
    with Image.open(dst) as done:
        block = done.info["exif"]
        done.load()
        new = block[exif.thumbnail_at : exif.thumbnail_at + len(old)]
        thumb = Image.frombytes("RGB", (80, 60), new)
        assert_shows_the_patched_picture(thumb, done, picture)
    assert block[: exif.thumbnail_at] == exif.block[: exif.thumbnail_at]


def test_photoshop_and_xmp_thumbnails_are_not_the_originals(tmp_path: Path) -> None:
    """Photoshop and Bridge write a thumbnail resource (APP13 0x040C) and XMP a base64 one: the first is
    rewritten from the patched picture (the IPTC beside it kept), the second removed (the rest kept)."""
    picture = camera_picture()
    old_ps, old_xmp = original_thumbnail(picture, (160, 120)), original_thumbnail(picture, (128, 96))
    iptc = b"\x1c\x02\x78" + struct.pack(">H", 12) + b"kept-caption"
    data = jpeg_of(picture, 90)
    data = with_app_segment(data, 0xED, photoshop_thumbnail_block(old_ps, (160, 120), iptc))
    data = with_app_segment(data, 0xE1, b"http://ns.adobe.com/xap/1.0/\x00" + xmp_with_thumbnail(old_xmp))
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    src.write_bytes(data)
    report = poison_file(src, dst, SPEC, keep_location=True)
    out = dst.read_bytes()
    assert_no_run_of(old_ps, out)
    assert base64.b64encode(old_xmp)[200:264] not in out and b"xmpGImg:image" not in out
    assert b"kept-caption" in out and b"kept-creator" in out
    assert "Photoshop thumbnail (160x120) replaced by the patched picture's" in report.notes
    assert "XMP thumbnail removed" in report.notes
    with Image.open(dst) as done:
        ps = done.info["photoshop"][0x040C]
        done.load()
        w, h = struct.unpack(">II", ps[4:12])
        assert (w, h) == (160, 120) and struct.unpack(">I", ps[20:24])[0] == len(ps) - 28
        with Image.open(io.BytesIO(ps[28:])) as thumb:
            thumb.load()
            assert_shows_the_patched_picture(thumb, done, picture)


@pytest.mark.parametrize("fmt", ["PNG", "WEBP", "WEBP-lossy", "HEIF", "AVIF"])
def test_other_formats_exif_thumbnail_is_the_patched_pictures(tmp_path: Path, fmt: str) -> None:
    """The same EXIF block in a PNG (eXIf), a WebP (EXIF chunk), a HEIC and an AVIF (Exif item)."""
    import pillow_heif

    pillow_heif.register_heif_opener()
    picture = camera_picture()
    old = original_thumbnail(picture)
    exif = exif_with_thumbnail(old, orientation=fmt != "AVIF")
    name = {"PNG": "a.png", "WEBP": "a.webp", "WEBP-lossy": "b.webp", "HEIF": "a.heic", "AVIF": "a.avif"}[fmt]
    src, dst = tmp_path / name, tmp_path / ("out" + Path(name).suffix)
    opts: dict[str, object] = {"lossless": True} if fmt == "WEBP" else {"quality": 90}
    picture.save(src, fmt.split("-")[0], exif=exif.block, **({} if fmt == "PNG" else opts))
    with Image.open(src) as check:  # the fixture really carries it
        assert exif_thumbnail(check) == old
    report = poison_file(src, dst, SPEC)
    assert_no_run_of(old, dst.read_bytes())
    assert "EXIF thumbnail (160x120) replaced by the patched picture's" in report.notes
    with Image.open(dst) as done:
        thumb_bytes = exif_thumbnail(done)
        assert ARTIST in tiff_of(done) and MAKER_NOTE in tiff_of(done)
        done.load()
        assert thumb_bytes is not None
        with Image.open(io.BytesIO(thumb_bytes)) as thumb:
            thumb.load()
            assert_shows_the_patched_picture(thumb, done, picture)
    if fmt == "PNG":  # every other chunk as it was
        assert [t for t, _ in png_chunks(dst.read_bytes())].count(b"eXIf") == 1


def test_an_exif_block_whose_ifd1_does_not_parse_is_dropped(tmp_path: Path) -> None:
    """IFD1 pointing past the block: ppd cannot say where a thumbnail is, a carver still finds it."""
    picture = camera_picture()
    old = original_thumbnail(picture)
    exif = exif_with_thumbnail(old)
    broken = bytearray(exif.block)
    broken[exif.next_ifd_at : exif.next_ifd_at + 4] = struct.pack("<I", len(broken) + 100)
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    picture.save(src, "JPEG", quality=90, exif=bytes(broken))
    report = poison_file(src, dst, SPEC, keep_location=True)
    assert any(n.startswith("EXIF dropped: unreadable, could hold a thumbnail") for n in report.notes)
    assert_no_run_of(old, dst.read_bytes())
    with Image.open(dst) as done:
        assert "exif" not in done.info


def test_an_avif_with_an_orientation_tag_is_said_to_lose_its_thumbnail(tmp_path: Path) -> None:
    """Pillow's AVIF writer turns an orientation tag into `irot` and writes the EXIF again without IFD1:
    the output has no thumbnail, and the note says removed, not replaced. (Pillow writes no such AVIF
    either: the fixture's Artist entry becomes Orientation = 1 in the file's bytes, same length.)"""
    picture = camera_picture()
    old = original_thumbnail(picture)
    exif = exif_with_thumbnail(old, orientation=False)
    src, dst = tmp_path / "a.avif", tmp_path / "out.avif"
    picture.save(src, "AVIF", quality=90, exif=exif.block)
    artist = struct.pack("<HHI", 0x013B, 2, len(ARTIST))
    data = src.read_bytes()
    assert data.count(artist) == 1
    entry = data[data.index(artist) :][:12]
    src.write_bytes(data.replace(entry, struct.pack("<HHIHH", 0x0112, 3, 1, 1, 0)))
    with Image.open(src) as check:
        assert exif_thumbnail(check) == old and check.getexif()[0x0112] == 1
    report = poison_file(src, dst, SPEC)
    gone = "EXIF thumbnail removed (Pillow's AVIF writer"
    assert any(n.startswith(gone) for n in report.notes), report.notes
    assert not any("replaced" in n for n in report.notes)
    assert_no_run_of(old, dst.read_bytes())
    with Image.open(dst) as done:
        assert exif_thumbnail(done) is None


def test_heic_thumbnails_are_made_from_the_patched_picture(tmp_path: Path) -> None:
    """A HEIC's own `thmb` item (an iPhone's): written again at its size from the patched picture (it
    was dropped before; no run of the old one can be left, the whole file is encoded anew)."""
    import pillow_heif

    pillow_heif.register_heif_opener()
    picture = camera_picture()
    src, dst = tmp_path / "a.heic", tmp_path / "out.heic"
    picture.save(src, "HEIF", quality=90, thumbnails=[256])
    report = poison_file(src, dst, SPEC)
    assert "HEIF thumbnail (256 px) replaced by the patched picture's" in report.notes
    out = pillow_heif.open_heif(dst)[0]
    assert out.info["thumbnails"] == [256]
    thumb = out.get_thumbnail(0).to_pillow()
    assert thumb.size == (256, 192)
    with Image.open(dst) as done:
        done.load()
        assert_shows_the_patched_picture(thumb, done, picture)


def test_a_preview_in_the_maker_note_is_the_patched_pictures_too(tmp_path: Path) -> None:
    """Nikon, Sony and Olympus keep a larger preview (640 px) inside their maker note, which ppd does
    not parse: found as a whole JPEG inside the EXIF block and rewritten in its bytes, the vendor's
    bytes around it and the block's length as they were."""
    picture = camera_picture()
    preview = original_thumbnail(picture, (320, 240))
    note = b"Nikon\x00\x02\x10\x00\x00" + bytes(range(30)) + preview + b"vendor-tail"
    exif = exif_with_thumbnail(original_thumbnail(picture), maker_note=note)
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    picture.save(src, "JPEG", quality=90, exif=exif.block)
    report = poison_file(src, dst, SPEC)
    assert_no_run_of(preview, dst.read_bytes())
    assert "EXIF maker-note thumbnail (320x240) replaced by the patched picture's" in report.notes
    assert "EXIF thumbnail (160x120) replaced by the patched picture's" in report.notes
    with Image.open(dst) as done:
        block = done.info["exif"]
        done.load()
        at = block.index(b"Nikon\x00")
        la = exif.length_at  # (IFD1's thumbnail length: its new one)
        assert len(block) == len(exif.block) and block[:la] == exif.block[:la]
        assert block[la + 4 : at + 40] == exif.block[la + 4 : at + 40]
        assert block[at + 40 + len(preview) :].startswith(b"vendor-tail")
        with Image.open(io.BytesIO(block[at + 40 : at + 40 + len(preview)])) as thumb:
            thumb.load()
            assert thumb.size == (320, 240)
            assert_shows_the_patched_picture(thumb, done, picture)


def test_a_png_from_imagemagick_has_no_thumbnail_of_the_original_in_its_raw_profiles(tmp_path: Path) -> None:
    """`convert photo.jpg photo.png` carries the JPEG's EXIF (thumbnail and all) as hex text in a zTXt
    "Raw profile type exif", and its XMP as another: the thumbnail is the patched picture's, XMP's gone."""
    picture = camera_picture()
    old, old_xmp = original_thumbnail(picture), original_thumbnail(picture, (128, 96))
    exif = exif_with_thumbnail(old)

    def raw_profile(kind: str, blob: bytes) -> str:
        hexed = blob.hex()
        lines = "\n".join(hexed[i : i + 72] for i in range(0, len(hexed), 72))
        return f"\n{kind}\n{len(blob):8d}\n{lines}\n"

    info = PngImagePlugin.PngInfo()
    info.add_text("Raw profile type exif", raw_profile("exif", exif.block), zip=True)
    info.add_text("Raw profile type xmp", raw_profile("xmp", xmp_with_thumbnail(old_xmp)), zip=True)
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    picture.save(src, pnginfo=info)
    report = poison_file(src, dst, SPEC, keep_location=True)
    assert "EXIF thumbnail (160x120) replaced by the patched picture's" in report.notes
    assert "XMP thumbnail removed" in report.notes
    with Image.open(dst) as done:
        done.load()
        texts = {k: v for k, v in done.info.items() if isinstance(v, str)}
        block = bytes.fromhex("".join(texts["Raw profile type exif"].split("\n")[3:]))
        xmp = bytes.fromhex("".join(texts["Raw profile type xmp"].split("\n")[3:]))
        assert b"kept-creator" in xmp and b"xmpGImg:image" not in xmp
        assert_no_run_of(old, block)
        (length,) = struct.unpack("<I", block[exif.length_at : exif.length_at + 4])
        assert len(block) == len(exif.block) and MAKER_NOTE in block
        with Image.open(io.BytesIO(block[exif.thumbnail_at : exif.thumbnail_at + length])) as thumb:
            thumb.load()
            assert_shows_the_patched_picture(thumb, done, picture)


def test_an_extended_xmp_copy_of_the_original_is_removed_with_its_pointer(tmp_path: Path) -> None:
    """Google Camera's Lens Blur photos keep the original picture, whole, as base64 in Extended XMP
    (GImage:Data, several APP1 segments): those segments go, with xmpNote:HasExtendedXMP; the rest of
    the main packet stays."""
    picture = camera_picture()
    whole = jpeg_of(picture, 90)
    data = jpeg_of(picture, 90)
    for payload in reversed(extended_xmp_segments(whole)):
        data = with_app_segment(data, 0xE1, payload)
    assert data.count(b"http://ns.adobe.com/xmp/extension/") >= 2  # the fixture spans segments
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    src.write_bytes(data)
    report = poison_file(src, dst, SPEC, keep_location=True)
    out = dst.read_bytes()
    encoded = base64.b64encode(whole)
    assert all(encoded[i : i + 64] not in out for i in range(0, len(encoded) - 64, 4096))
    assert b"http://ns.adobe.com/xmp/extension/" not in out and b"HasExtendedXMP" not in out
    assert b"kept-creator" in out
    assert "Extended XMP holding a picture of the original (GImage:Data, a thumbnail) removed" in report.notes


@pytest.mark.parametrize("splice", [True, False], ids=["splice", "reencode"])
def test_a_flashpix_screennail_of_the_original_is_removed_and_the_icc_profile_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, splice: bool
) -> None:
    """Kodak and Casio cameras keep a preview JPEG of the photo (the ScreenNail) in FlashPix APP2 FPXR
    segments: copied as they were, every patched file published it. Every FPXR segment goes, on the
    splice and on the whole re-encode alike; the ICC profile (APP2 too) stays byte for byte."""
    if not splice:
        monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "")  # no splice: Pillow's same-tables re-encode
    picture = camera_picture()
    old = original_thumbnail(picture, (320, 240))
    buf = io.BytesIO()
    icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    picture.save(buf, "JPEG", quality=90, icc_profile=icc)
    data = buf.getvalue()
    segments = flashpix_segments(old)
    for payload in reversed(segments):
        data = with_app_segment(data, 0xE2, payload)
    assert len(segments) >= 3 and old[1000:1032] in data  # the preview is there, over several segments
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    src.write_bytes(data)
    report = poison_file(src, dst, SPEC, keep_location=True)
    assert report.method == ("jpeg-dct-splice" if splice else "jpeg-reencode-same-tables")
    out = dst.read_bytes()
    assert_no_run_of(old, out)
    assert b"FPXR\x00" not in out
    said = f"FlashPix data (FPXR APP2, {len(segments)} segment(s)) removed: "
    assert said + "cameras keep a preview of the original there" in report.notes

    def icc_segments(jpeg: bytes) -> list[bytes]:
        return [p for m, p in location.jpeg_header_segments(jpeg)[0] if p.startswith(b"ICC_PROFILE\x00")]

    assert icc_segments(out) == icc_segments(data) != []
    with Image.open(dst) as done:
        done.load()
        assert done.size == picture.size and done.info["icc_profile"] == icc


def test_an_ifd1_without_a_picture_is_left_as_it_is(tmp_path: Path) -> None:
    """Some cameras write IFD1 with a zero-length thumbnail: nothing shows the original, nothing is
    said or changed (it was called removed, and the summary said a thumbnail showed the original)."""
    picture = camera_picture()
    exif = exif_with_thumbnail(b"")
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    picture.save(src, "JPEG", quality=90, exif=exif.block)
    report = poison_file(src, dst, SPEC, keep_location=True)
    assert not any("thumbnail" in n for n in report.notes), report.notes
    with Image.open(dst) as done:
        assert done.info["exif"] == exif.block
