"""The provenance marker (issue 20): written by poison_file in every image format, read back by
read_marker from metadata alone, deterministic, None for anything ppd did not write."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, PngImagePlugin

from poisoner import location
from poisoner.formats import png_chunks, poison_file
from poisoner.provenance import Marker, read_marker, xmp_with_marker
from poisoner.spec import PatchSpec

SPEC = PatchSpec(patch_size=40, block_size=4, position="top-left", offset=(8, 8))
MARKER = Marker(spec_id="spec-7f3a", original_sha256="ab" * 32, tool='ppd 0.test "quoted" <&>')
USER_XMP = (
    b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
    b'<rdf:Description rdf:about="" xmlns:dc="http://purl.org/dc/elements/1.1/" dc:format="user-kept"/>'
    b"</rdf:RDF></x:xmpmeta>"
)


def pixels(h: int = 120, w: int = 160) -> np.ndarray:
    return np.random.default_rng(2).integers(0, 256, size=(h, w, 3)).astype(np.uint8)


def write(path: Path, kind: str, xmp: bool) -> None:
    im = Image.fromarray(pixels())
    extra: dict[str, object] = {}
    if kind == "jpeg":
        extra = {"quality": 90, "xmp": USER_XMP} if xmp else {"quality": 90}
        im.save(path, "JPEG", **extra)
    elif kind == "png":
        info = PngImagePlugin.PngInfo()
        if xmp:
            info.add_itxt("XML:com.adobe.xmp", USER_XMP.decode())
        im.save(path, "PNG", pnginfo=info)
    elif kind in ("webp-lossless", "webp-lossy"):
        im.save(path, "WEBP", lossless=kind == "webp-lossless", **({"xmp": USER_XMP} if xmp else {}))
    elif kind == "tiff":
        im.save(path, "TIFF", tiffinfo={700: USER_XMP} if xmp else {})
    else:
        import pillow_heif

        pillow_heif.register_heif_opener()
        im.save(path, kind.upper(), quality=90, **({"xmp": USER_XMP} if xmp else {}))


KINDS = {
    "jpeg": ".jpg",
    "png": ".png",
    "webp-lossless": ".webp",
    "webp-lossy": ".webp",
    "tiff": ".tif",
    "heif": ".heic",
    "avif": ".avif",
}


@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.parametrize("xmp", [False, True])
def test_marker_round_trip_deterministic(tmp_path: Path, kind: str, xmp: bool) -> None:
    suffix = KINDS[kind]
    src = tmp_path / f"src{suffix}"
    write(src, kind, xmp)
    assert read_marker(src) is None  # an ordinary file has none
    poison_file(src, tmp_path / f"a{suffix}", SPEC, marker=MARKER)
    poison_file(src, tmp_path / f"b{suffix}", SPEC, marker=MARKER)
    a, b = (tmp_path / f"a{suffix}").read_bytes(), (tmp_path / f"b{suffix}").read_bytes()
    assert hashlib.sha256(a).digest() == hashlib.sha256(b).digest()  # the daemon re-poisons to verify
    assert read_marker(tmp_path / f"a{suffix}") == MARKER
    assert Image.open(tmp_path / f"a{suffix}").size == (160, 120)  # still a valid image
    if xmp:
        assert b"user-kept" in a  # the user's own XMP stays
    # protecting a marked file again replaces the marker (one marker, the newest)
    other = Marker("spec-2", "cd" * 32, "ppd")
    poison_file(tmp_path / f"a{suffix}", tmp_path / f"c{suffix}", SPEC, marker=other)
    assert read_marker(tmp_path / f"c{suffix}") == other
    assert (tmp_path / f"c{suffix}").read_bytes().count(b"OriginalSha256") <= 1


def test_jpeg_marker_touches_only_the_header(tmp_path: Path) -> None:
    src = tmp_path / "a.jpg"
    write(src, "jpeg", xmp=False)
    poison_file(src, tmp_path / "plain.jpg", SPEC, keep_location=True)
    poison_file(src, tmp_path / "marked.jpg", SPEC, marker=MARKER, keep_location=True)
    plain, marked = (tmp_path / "plain.jpg").read_bytes(), (tmp_path / "marked.jpg").read_bytes()
    _, sos_plain = location.jpeg_header_segments(plain)
    _, sos_marked = location.jpeg_header_segments(marked)
    assert plain[sos_plain:] == marked[sos_marked:]


def test_png_marker_chunk_sits_after_ihdr(tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    write(src, "png", xmp=False)
    poison_file(src, tmp_path / "m.png", SPEC, marker=MARKER)
    chunks = png_chunks((tmp_path / "m.png").read_bytes())
    assert (
        chunks[0][0] == b"IHDR" and chunks[1][0] == b"iTXt" and chunks[1][1].startswith(b"ppd:provenance\x00")
    )
    poison_file(src, tmp_path / "plain.png", SPEC)
    np.testing.assert_array_equal(
        np.asarray(Image.open(tmp_path / "m.png")), np.asarray(Image.open(tmp_path / "plain.png"))
    )


@pytest.mark.parametrize(
    "content",
    [
        b"",
        b"garbage" * 100,
        b"\xff\xd8\xff\xe1\xff\xff",
        b"\x89PNG\r\n\x1a\n\x00\x00",
        b"RIFF\x00\x00\x00\x00WEBPVP8X",
        b"II*\x00\xff\xff\xff\x7f",
        b"\x00\x00\x00\x18ftypisom" + b"\xff" * 20,
        b"\x1a\x45\xdf\xa3\x80",
    ],
)
def test_garbage_and_truncated_files_have_no_marker(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "x.bin"
    path.write_bytes(content)
    assert read_marker(path) is None


def test_truncated_marked_file_reads_none_or_the_marker(tmp_path: Path) -> None:
    src = tmp_path / "a.jpg"
    write(src, "jpeg", xmp=False)
    poison_file(src, tmp_path / "m.jpg", SPEC, marker=MARKER)
    data = (tmp_path / "m.jpg").read_bytes()
    for cut in range(0, 400, 7):
        (tmp_path / "t.jpg").write_bytes(data[:cut])
        assert read_marker(tmp_path / "t.jpg") in (None, MARKER)


def test_missing_file_reads_none(tmp_path: Path) -> None:
    assert read_marker(tmp_path / "nope.jpg") is None


def test_xmp_with_marker_without_rdf_makes_a_packet() -> None:
    out = xmp_with_marker(b"<not-xmp/>", MARKER)
    assert b"ppd:SpecId" in out and out.count(b"ppd:SpecId") == 1
