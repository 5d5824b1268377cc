"""Location privacy: protected files carry no GPS or place names unless keep_location (issue 15).

Every file here is written with real GPS metadata (Pillow's Exif GPS IFD, real XMP/IPTC blocks);
each test fails if a coordinate, the GPS IFD or a place name survives."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, PngImagePlugin

from poisoner import location
from poisoner.formats import png_chunks, poison_file
from poisoner.spec import PatchSpec

SPEC = PatchSpec(patch_size=40, block_size=4, position="top-left", offset=(8, 8))
LAT = (48.0, 51.0, 29.5)
LON = (2.0, 17.0, 40.25)
CITY = "Montmartre-ppd-test"

XMP = (
    '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>'
    '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
    '<rdf:Description rdf:about="" xmlns:exif="http://ns.adobe.com/exif/1.0/"'
    ' xmlns:photoshop="http://ns.adobe.com/photoshop/1.0/"'
    ' xmlns:Iptc4xmpExt="http://iptc.org/std/Iptc4xmpExt/2008-02-29/"'
    ' xmlns:Iptc4xmpCore="http://iptc.org/std/Iptc4xmpCore/1.0/xmlns/"'
    ' xmlns:dc="http://purl.org/dc/elements/1.1/"'
    ' exif:GPSLatitude="48,51.49N" exif:GPSLongitude="2,17.67E" photoshop:City="' + CITY + '"'
    ' photoshop:Country="France" Iptc4xmpCore:Location="Rue Lepic" photoshop:Headline="kept-headline">'
    "<exif:GPSAltitude>130/1</exif:GPSAltitude>"
    '<Iptc4xmpExt:LocationCreated><rdf:Bag><rdf:li rdf:parseType="Resource">'
    "<Iptc4xmpExt:City>" + CITY + "</Iptc4xmpExt:City></rdf:li></rdf:Bag></Iptc4xmpExt:LocationCreated>"
    "<dc:creator><rdf:Seq><rdf:li>kept-creator</rdf:li></rdf:Seq></dc:creator>"
    "</rdf:Description></rdf:RDF></x:xmpmeta>"
    '<?xpacket end="w"?>'
).encode()
PLACE_STRINGS = [b"GPSLatitude", b"GPSLongitude", b"GPSAltitude", CITY.encode(), b"France", b"Rue Lepic"]
KEPT_STRINGS = [b"kept-headline", b"kept-creator"]


def gps_exif() -> Image.Exif:
    exif = Image.Exif()
    exif[0x010F] = "ppd-test-camera"
    exif[0x0112] = 1
    gps = exif.get_ifd(0x8825)
    gps[1], gps[2], gps[3], gps[4] = "N", LAT, "E", LON
    gps[6] = 130.5
    return exif


def rational_bytes(order: str) -> bytes:
    """How the latitude sits in an EXIF block (three rationals); its absence proves erasure."""
    from fractions import Fraction

    fracs = [Fraction(v).limit_denominator(1 << 20) for v in LAT]
    return b"".join(struct.pack(order + "II", f.numerator, f.denominator) for f in fracs)


def pixels(h: int = 120, w: int = 160) -> np.ndarray:
    return np.random.default_rng(1).integers(0, 256, size=(h, w, 3)).astype(np.uint8)


def assert_no_location(data: bytes, img: Image.Image) -> None:
    assert dict(img.getexif().get_ifd(0x8825)) == {}
    assert 0x8825 not in img.getexif()
    for s in PLACE_STRINGS:
        assert s not in data, s


def iptc_block() -> bytes:
    def ds(n: int, v: bytes) -> bytes:
        return b"\x1c\x02" + bytes([n]) + struct.pack(">H", len(v)) + v

    iim = ds(0, b"\x00\x04") + ds(90, CITY.encode()) + ds(101, b"France") + ds(120, b"kept-caption")
    res = b"8BIM" + struct.pack(">H", 0x0404) + b"\x00\x00" + struct.pack(">I", len(iim)) + iim
    return location.PHOTOSHOP_HEADER + res + b"\x00" * (len(iim) & 1)


def jpeg_with_location(path: Path) -> None:
    buf = io.BytesIO()
    Image.fromarray(pixels(240, 320)).save(buf, "JPEG", quality=90, exif=gps_exif(), xmp=XMP)
    data = buf.getvalue()
    app13 = b"\xff\xed" + struct.pack(">H", len(iptc_block()) + 2) + iptc_block()
    path.write_bytes(data[:2] + app13 + data[2:])


@pytest.mark.parametrize("splice", [True, False])
def test_jpeg_location_removed_rest_kept(
    tmp_path: Path, splice: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    if not splice:
        monkeypatch.setenv("PPD_JPEGTRAN", "")
    src = tmp_path / "phone.jpg"
    jpeg_with_location(src)
    source = src.read_bytes()
    assert rational_bytes(">") in source and CITY.encode() in source  # the fixture really has them
    report = poison_file(src, tmp_path / "out.jpg", SPEC)
    kept = poison_file(src, tmp_path / "kept.jpg", SPEC, keep_location=True)
    data = (tmp_path / "out.jpg").read_bytes()
    out = Image.open(tmp_path / "out.jpg")
    assert_no_location(data, out)
    assert rational_bytes(">") not in data
    assert out.getexif()[0x010F] == "ppd-test-camera"  # the rest of EXIF kept
    for s in KEPT_STRINGS + [b"kept-caption"]:
        assert s in data
    assert "EXIF GPS IFD" in report.location_removed
    assert any("City" in r for r in report.location_removed) and any(
        "IPTC 2:90" in r for r in report.location_removed
    )
    # Only the header changed: the entropy-coded scans are byte-identical to the keep_location output.
    keep = (tmp_path / "kept.jpg").read_bytes()
    _, sos_out = location.jpeg_header_segments(data)
    _, sos_keep = location.jpeg_header_segments(keep)
    assert data[sos_out:] == keep[sos_keep:]
    assert np.array_equal(np.asarray(out), np.asarray(Image.open(tmp_path / "kept.jpg")))
    # keep_location: exactly today's output, GPS and all
    kept_img = Image.open(tmp_path / "kept.jpg")
    assert dict(kept_img.getexif().get_ifd(0x8825))[2] == LAT
    assert CITY.encode() in keep and kept.location_removed == []


def test_png_location_removed_from_exif_xmp_and_raw_profile(tmp_path: Path) -> None:
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    info = PngImagePlugin.PngInfo()
    info.add_itxt("XML:com.adobe.xmp", XMP.decode(), zip=True)
    raw = gps_exif().tobytes()
    hexed = raw.hex()
    profile = "\nexif\n" + f"{len(raw):8d}\n" + "\n".join(hexed[i : i + 72] for i in range(0, len(hexed), 72))
    info.add(b"zTXt", b"Raw profile type exif\x00\x00" + zlib.compress(profile.encode()))
    info.add_text("Title", "kept-title")
    Image.fromarray(pixels()).save(src, pnginfo=info, exif=gps_exif())
    profile_in = zlib.decompress(png_text(src.read_bytes(), b"zTXt")[len(b"Raw profile type exif") + 2 :])
    assert rational_bytes(">").hex().encode() in profile_in.replace(b"\n", b"")  # the fixture has GPS there
    report = poison_file(src, dst, SPEC)
    data = dst.read_bytes()
    out = Image.open(dst)
    assert_no_location(data, out)
    assert rational_bytes(">") not in data
    profile_out = zlib.decompress(png_text(data, b"zTXt")[len(b"Raw profile type exif") + 2 :])
    assert rational_bytes(">").hex().encode() not in profile_out.replace(b"\n", b"")
    assert out.info["Title"] == "kept-title" and out.getexif()[0x010F] == "ppd-test-camera"
    xmp = out.info["XML:com.adobe.xmp"].encode()
    assert all(s in xmp for s in KEPT_STRINGS) and b"GPS" not in xmp and CITY.encode() not in xmp
    assert any("eXIf" in r for r in report.location_removed)
    assert any("zTXt" in r for r in report.location_removed)
    poison_file(src, tmp_path / "k.png", SPEC, keep_location=True)
    kept = Image.open(tmp_path / "k.png")
    np.testing.assert_array_equal(np.asarray(out), np.asarray(kept))
    assert dict(kept.getexif().get_ifd(0x8825))[2] == LAT


def png_text(data: bytes, ctype: bytes) -> bytes:
    return next(b for t, b in png_chunks(data) if t == ctype)


@pytest.mark.parametrize("lossless", [True, False])
def test_webp_location_removed(tmp_path: Path, lossless: bool) -> None:
    src, dst = tmp_path / "a.webp", tmp_path / "out.webp"
    Image.fromarray(pixels()).save(src, lossless=lossless, exif=gps_exif(), xmp=XMP)
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert_no_location(dst.read_bytes(), out)
    assert out.getexif()[0x010F] == "ppd-test-camera"
    assert all(s in dst.read_bytes() for s in KEPT_STRINGS)
    assert "WebP EXIF GPS IFD" in report.location_removed
    poison_file(src, tmp_path / "k.webp", SPEC, keep_location=True)
    assert dict(Image.open(tmp_path / "k.webp").getexif().get_ifd(0x8825))[2] == LAT


def test_tiff_gps_ifd_and_xmp_removed(tmp_path: Path) -> None:
    src, dst = tmp_path / "a.tif", tmp_path / "out.tif"
    gps = gps_exif().get_ifd(0x8825)
    Image.fromarray(pixels()).save(src, tiffinfo={271: "ppd", 34853: gps, 33723: iptc_block()[26:], 700: XMP})
    assert dict(Image.open(src).getexif().get_ifd(0x8825))[2] == LAT
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert_no_location(dst.read_bytes(), out)
    assert 34853 not in out.tag_v2 and out.tag_v2[271] == "ppd"
    assert all(s in dst.read_bytes() for s in KEPT_STRINGS + [b"kept-caption"])
    assert "TIFF GPS IFD" in report.location_removed
    poison_file(src, tmp_path / "k.tif", SPEC, keep_location=True)
    kept = Image.open(tmp_path / "k.tif")
    assert (
        dict(kept.getexif().get_ifd(0x8825))[2] == LAT and CITY.encode() in (tmp_path / "k.tif").read_bytes()
    )


@pytest.mark.parametrize(("fmt", "suffix"), [("HEIF", ".heic"), ("AVIF", ".avif")])
def test_heic_avif_location_removed(tmp_path: Path, fmt: str, suffix: str) -> None:
    import pillow_heif

    pillow_heif.register_heif_opener()
    src, dst = tmp_path / f"a{suffix}", tmp_path / f"out{suffix}"
    Image.fromarray(pixels(128, 192)).save(src, fmt, quality=90, exif=gps_exif().tobytes(), xmp=XMP)
    assert dict(Image.open(src).getexif().get_ifd(0x8825))[2] == LAT
    report = poison_file(src, dst, SPEC)
    out = Image.open(dst)
    assert_no_location(dst.read_bytes(), out)
    assert out.getexif()[0x010F] == "ppd-test-camera"
    assert f"{fmt} EXIF GPS IFD" in report.location_removed
    poison_file(src, tmp_path / f"k{suffix}", SPEC, keep_location=True)
    assert dict(Image.open(tmp_path / f"k{suffix}").getexif().get_ifd(0x8825))[2] == LAT


# ---- the byte-level functions ----------------------------------------------------------------------
@pytest.mark.parametrize("order", ["<", ">"])
def test_strip_exif_gps_is_in_place(order: str) -> None:
    exif = gps_exif().tobytes()
    if order == "<":  # Pillow writes big-endian here; build a little-endian one through a TIFF
        buf = io.BytesIO()
        Image.fromarray(pixels(8, 8)).save(buf, "JPEG", exif=gps_exif())
        exif = Image.open(buf).info["exif"]
    stripped, removed = location.strip_exif_gps(exif)
    assert removed and len(stripped) == len(exif)
    assert location.strip_exif_gps(stripped) == (stripped, False)  # idempotent
    parsed = Image.Exif()
    parsed.load(stripped)
    assert dict(parsed.get_ifd(0x8825)) == {} and parsed[0x010F] == "ppd-test-camera"


def test_unreadable_exif_is_dropped_not_kept() -> None:
    exif, notes = location.clean_exif(b"Exif\x00\x00garbage-not-tiff")
    assert exif is None and "dropped" in notes[0]


def test_iim_strips_location_datasets_only() -> None:
    block, removed = location.strip_photoshop_location(iptc_block())
    assert CITY.encode() not in block and b"France" not in block and b"kept-caption" in block
    assert removed == ["IPTC 2:90", "IPTC 2:101"]


def test_xmp_without_location_is_unchanged() -> None:
    plain = b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF/></x:xmpmeta>'
    assert location.strip_xmp_location(plain) == (plain, [])


@pytest.mark.parametrize(
    ("key", "expected"),
    [
        ("location", True),
        ("location-eng", True),
        ("com.apple.quicktime.location.ISO6709", True),
        ("RECORDING_LOCATION", True),
        ("title", False),
        ("creation_time", False),
        ("comment", False),
    ],
)
def test_video_location_tags(key: str, expected: bool) -> None:
    assert location.is_location_tag(key) is expected
