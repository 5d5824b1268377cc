"""The provenance seal (issues 20, 29): embedded by poison_file in every image format, sealed in
place with the installation's key, verified over exactly the file's bytes; deterministic; None for
anything ppd did not write with this key (no token, another key, a copied token, an edited file);
no tool name and no original hash in what is published."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image, PngImagePlugin

from poisoner import location
from poisoner.formats import png_chunks, poison_bytes, poison_file
from poisoner.provenance import Marker, Seal, SealError, read_seal, seal_bytes, seal_file, xmp_with_marker
from poisoner.spec import PatchSpec

SPEC = PatchSpec(patch_size=40, block_size=4, position="top-left", offset=(8, 8))
# the same mark elsewhere: protecting a file again with SPEC would change no pixel (a failure)
MOVED = PatchSpec(patch_size=40, block_size=4, position="top-left", offset=(60, 40))
KEY = bytes(range(32))
ORIGINAL = "ab" * 32
MARKER = Marker.placeholder(KEY, "spec-7f3a", ORIGINAL)
SEAL = Seal(ORIGINAL, "spec-7f3a")
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


def sealed(src: Path, dst: Path, marker: Marker = MARKER, spec: PatchSpec = SPEC, **kw: Any) -> bytes:
    poison_file(src, dst, spec, marker=marker, **kw)
    seal_file(dst, KEY)
    return dst.read_bytes()


@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.parametrize("xmp", [False, True])
def test_seal_round_trip_deterministic(tmp_path: Path, kind: str, xmp: bool) -> None:
    suffix = KINDS[kind]
    src = tmp_path / f"src{suffix}"
    write(src, kind, xmp)
    assert read_seal(src, KEY) is None  # an ordinary file has none
    poison_file(src, tmp_path / f"p{suffix}", SPEC, marker=MARKER)
    assert read_seal(tmp_path / f"p{suffix}", KEY) is None  # a placeholder is no seal
    a, b = sealed(src, tmp_path / f"a{suffix}"), sealed(src, tmp_path / f"b{suffix}")
    assert hashlib.sha256(a).digest() == hashlib.sha256(b).digest()  # the daemon re-poisons to verify
    assert read_seal(tmp_path / f"a{suffix}", KEY) == SEAL
    assert read_seal(tmp_path / f"a{suffix}", bytes(32)) is None  # another installation's key
    assert read_seal(tmp_path / f"a{suffix}", None) is None
    with Image.open(tmp_path / f"a{suffix}") as im:  # still a valid image (a PNG's chunk CRCs too)
        im.load()
        assert im.size == (160, 120)
    if xmp:
        assert b"user-kept" in a  # the user's own XMP stays
    # protecting a sealed file again replaces the seal (one seal, the newest)
    other = Marker.placeholder(KEY, "spec-2", "cd" * 32)
    c = sealed(tmp_path / f"a{suffix}", tmp_path / f"c{suffix}", other, spec=MOVED)
    assert read_seal(tmp_path / f"c{suffix}", KEY) == Seal("cd" * 32, "spec-2")
    assert c.count(b"zQ7kS1") == 1


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_published_file_names_no_tool_and_no_original_hash(tmp_path: Path, kind: str) -> None:
    suffix = KINDS[kind]
    src = tmp_path / f"src{suffix}"
    write(src, kind, xmp=True)
    original = hashlib.sha256(src.read_bytes()).hexdigest()
    data = sealed(src, tmp_path / f"a{suffix}", Marker.placeholder(KEY, "0123456789abcdef", original))
    assert read_seal(tmp_path / f"a{suffix}", KEY) == Seal(original, "0123456789abcdef")
    meta = metadata_bytes(data)
    assert b"zQ7kS1" in meta  # the seal is in the metadata looked at
    for clear in (b"ppd", original.encode(), bytes.fromhex(original), b"0123456789abcdef", b"Sha256"):
        assert clear not in meta.lower() and clear not in data


def metadata_bytes(data: bytes) -> bytes:
    """Everything but the compressed picture: a JPEG's header, a PNG's chunks other than IDAT, the
    whole file for the other formats (their metadata is not separated here)."""
    if data.startswith(b"\xff\xd8"):
        return data[: location.jpeg_header_segments(data)[1]]
    if data.startswith(b"\x89PNG"):
        return b"".join(ctype + body for ctype, body in png_chunks(data) if ctype != b"IDAT")
    return data


@pytest.mark.parametrize("kind", ["jpeg", "png", "webp-lossless", "tiff"])
def test_copied_seal_and_cropped_file_do_not_verify(tmp_path: Path, kind: str) -> None:
    """Issue 29: a seal copied into another photo, or kept in a cropped one, is not ppd's output."""
    suffix = KINDS[kind]
    src = tmp_path / f"src{suffix}"
    write(src, kind, xmp=False)
    patched = tmp_path / f"a{suffix}"
    sealed(src, patched)
    with Image.open(patched) as im:
        im.load()
        crop = im.crop((40, 30, 160, 120))
        info = dict(im.info)
    # the cropped photo keeps the metadata (with the seal) but not the bytes
    cropped = tmp_path / f"crop{suffix}"
    if kind == "png":
        pnginfo = PngImagePlugin.PngInfo()
        for chunk_type, body in png_chunks(patched.read_bytes()):
            if chunk_type == b"iTXt":
                pnginfo.add(chunk_type, body)
        crop.save(cropped, pnginfo=pnginfo)
    else:
        extra = {"tiffinfo": {700: info["xmp"]}} if kind == "tiff" else {"xmp": info["xmp"]}
        crop.save(cropped, **extra)
    assert b"zQ7kS1" in cropped.read_bytes()
    assert read_seal(cropped, KEY) is None
    # a never-patched photo with the patched file's seal copied into it
    other = tmp_path / f"other{suffix}"
    im2 = Image.fromarray(np.full((120, 160, 3), 90, np.uint8))
    token = patched.read_bytes()
    at = token.index(b"zQ7kS1")
    text = token[at : at + 6 + 2 + 2 * int(token[at + 6 : at + 8], 16) + 64].decode()
    forged_xmp = xmp_with_marker(USER_XMP, Marker(text))
    if kind == "png":
        pnginfo = PngImagePlugin.PngInfo()
        pnginfo.add_itxt("sl", text)
        im2.save(other, pnginfo=pnginfo)
    elif kind == "tiff":
        im2.save(other, tiffinfo={700: forged_xmp})
    else:
        im2.save(other, xmp=forged_xmp)
    assert text.encode() in other.read_bytes()
    assert read_seal(other, KEY) is None


def test_jpeg_seal_touches_only_the_header(tmp_path: Path) -> None:
    src = tmp_path / "a.jpg"
    write(src, "jpeg", xmp=False)
    poison_file(src, tmp_path / "plain.jpg", SPEC, keep_location=True)
    sealed(src, tmp_path / "marked.jpg", keep_location=True)
    plain, marked = (tmp_path / "plain.jpg").read_bytes(), (tmp_path / "marked.jpg").read_bytes()
    _, sos_plain = location.jpeg_header_segments(plain)
    _, sos_marked = location.jpeg_header_segments(marked)
    assert plain[sos_plain:] == marked[sos_marked:]


def test_png_seal_chunk_sits_after_ihdr(tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    write(src, "png", xmp=False)
    sealed(src, tmp_path / "m.png")
    chunks = png_chunks((tmp_path / "m.png").read_bytes())
    assert chunks[0][0] == b"IHDR" and chunks[1][0] == b"iTXt" and chunks[1][1].startswith(b"sl\x00")
    poison_file(src, tmp_path / "plain.png", SPEC)
    np.testing.assert_array_equal(
        np.asarray(Image.open(tmp_path / "m.png")), np.asarray(Image.open(tmp_path / "plain.png"))
    )


def test_earlier_clear_marker_is_removed_and_never_trusted(tmp_path: Path) -> None:
    legacy = (
        b'<rdf:Description rdf:about="" xmlns:ppd="http://ns.ppd.invalid/provenance/1.0/" '
        b'ppd:SpecId="s" ppd:OriginalSha256="' + b"ab" * 32 + b'" ppd:Tool="ppd 0.1.0"/>'
    )
    src = tmp_path / "a.jpg"
    Image.fromarray(pixels()).save(src, xmp=USER_XMP.replace(b"</rdf:RDF>", legacy + b"</rdf:RDF>"))
    assert read_seal(src, KEY) is None
    data = sealed(src, tmp_path / "b.jpg")
    assert b"ppd" not in data.lower() and b"user-kept" in data


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_sealed_in_memory_is_sealed_on_disk(tmp_path: Path, kind: str) -> None:
    """The daemon makes an image's patched file in memory (poison_bytes, seal_bytes) and writes it
    once: the very bytes poison_file and seal_file leave on disk (a PNG's chunk CRC included)."""
    suffix = KINDS[kind]
    src = tmp_path / f"src{suffix}"
    write(src, kind, True)
    out, report = poison_bytes(src, SPEC, data=src.read_bytes(), marker=MARKER)
    in_memory = bytearray(out)
    seal_bytes(in_memory, KEY, src.name)
    assert in_memory != out and report.dst_bytes == len(out)
    assert bytes(in_memory) == sealed(src, tmp_path / f"a{suffix}")
    (tmp_path / f"m{suffix}").write_bytes(in_memory)
    assert read_seal(tmp_path / f"m{suffix}", KEY) == SEAL
    unsealed = bytearray(src.read_bytes())
    with pytest.raises(SealError, match="no seal placeholder"):
        seal_bytes(unsealed, KEY, src.name)
    assert unsealed == src.read_bytes()
    with pytest.raises(SealError, match="empty"):
        seal_bytes(bytearray(), KEY, src.name)


def test_seal_file_without_placeholder_refuses(tmp_path: Path) -> None:
    src = tmp_path / "a.png"
    write(src, "png", xmp=False)
    before = src.read_bytes()
    with pytest.raises(SealError):
        seal_file(src, KEY)
    poison_file(src, tmp_path / "p.png", SPEC, marker=Marker.placeholder(bytes(32), "s", ORIGINAL))
    with pytest.raises(SealError):  # another key's placeholder
        seal_file(tmp_path / "p.png", KEY)
    assert src.read_bytes() == before


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
        b"zQ7kS1" + b"ff" + b"0" * 600,
        b"\x1a\x45\xdf\xa3zQ7kS1" + b"05" + b"0" * 80,
    ],
)
def test_garbage_and_truncated_files_have_no_seal(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "x.bin"
    path.write_bytes(content)
    assert read_seal(path, KEY) is None


def test_truncated_sealed_file_reads_none(tmp_path: Path) -> None:
    src = tmp_path / "a.jpg"
    write(src, "jpeg", xmp=False)
    data = sealed(src, tmp_path / "m.jpg")
    for cut in range(0, len(data), max(1, len(data) // 60)):
        (tmp_path / "t.jpg").write_bytes(data[:cut])
        assert read_seal(tmp_path / "t.jpg", KEY) is None


def test_missing_file_reads_none(tmp_path: Path) -> None:
    assert read_seal(tmp_path / "nope.jpg", KEY) is None


def test_xmp_with_marker_without_rdf_makes_a_packet() -> None:
    out = xmp_with_marker(b"<not-xmp/>", MARKER)
    assert out.count(MARKER.text.encode()) == 1


@pytest.mark.parametrize(
    "text",
    ["", "plain", 'a "quoted" one', "it's", "both \" and ' here", "<&>\n\r\t", "&amp; already", "é ü 漢"],
)
def test_quoteattr_is_the_standard_librarys(text: str) -> None:
    from xml.sax.saxutils import quoteattr as standard

    from poisoner.provenance import quoteattr

    assert quoteattr(text) == standard(text)


def _full_xmp(padding: int) -> bytes:
    """An XMP packet filling a JPEG's APP1 segment but for 60 bytes, `padding` of them the trailing
    whitespace writers leave for in-place edits (Adobe's: 2 KB)."""
    head = (b'<?xpacket begin="\xef\xbb\xbf" id="W5M0MpCehiHzreSzNTczkc9d"?>'
            b'<x:xmpmeta xmlns:x="adobe:ns:meta/">'
            b'<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
            b'<rdf:Description rdf:about="" xmlns:dc="http://purl.org/dc/elements/1.1/"><dc:description>')
    tail = b"</dc:description></rdf:Description></rdf:RDF></x:xmpmeta>"
    end = b'<?xpacket end="w"?>'
    size = 0xFFFF - 2 - len(b"http://ns.adobe.com/xap/1.0/\x00") - 60
    words = (size - len(head + tail + end) - padding) // 10
    return head + b"user-kept " * words + tail + b" " * padding + end


def _segments(data: bytes, marker: int) -> list[bytes]:
    segments, _ = location.jpeg_header_segments(data)
    return [p for m, p in segments if m == marker]


@pytest.mark.parametrize("padding", [2048, 0])
def test_a_full_xmp_segment_still_takes_the_seal(tmp_path: Path, padding: int) -> None:
    """A JPEG whose XMP all but fills its 64 KB segment (long histories, extended XMP's main packet)
    was refused ("segment over 64 KB"): the photo stayed unprotected. The seal now takes the packet's
    padding, or, with too little, goes into a comment segment beside the user's packet, kept whole."""
    xmp = _full_xmp(padding)
    src = tmp_path / "a.jpg"
    Image.fromarray(pixels()).save(src, "JPEG", quality=90, xmp=xmp)
    assert _segments(src.read_bytes(), 0xE1)[-1].endswith(xmp)
    out = sealed(src, tmp_path / "b.jpg")
    assert read_seal(tmp_path / "b.jpg", KEY) == SEAL
    packets = [p for p in _segments(out, 0xE1) if p.startswith(b"http://ns.adobe.com/xap/1.0/")]
    comments = [p for p in _segments(out, 0xFE) if p.startswith(MARKER.text[:6].encode())]
    assert len(packets) == 1 and packets[0].count(b"user-kept ") == xmp.count(b"user-kept ")
    if padding:  # in the packet, its padding shortened by what the seal took
        assert comments == [] and MARKER.text[:40].encode() in packets[0]
        assert packets[0].endswith(b'<?xpacket end="w"?>') and b" " * 1000 in packets[0]
    else:  # the user's packet byte for byte, the seal in one comment
        assert packets[0].endswith(xmp) and len(comments) == 1
    # protected again (another spec): one seal, the new one
    other = Marker.placeholder(KEY, "spec-2", "cd" * 32)
    again = sealed(tmp_path / "b.jpg", tmp_path / "c.jpg", other, spec=MOVED)
    assert read_seal(tmp_path / "c.jpg", KEY) == Seal("cd" * 32, "spec-2")
    assert again.count(MARKER.text[:6].encode()) == 1


def test_sealing_key_reads_the_seal_at_either_end_of_a_large_file(tmp_path: Path) -> None:
    """sealing_key reads only a file's first and last MB (`ppd key import` asks it of every patched
    file): a photo's seal is in its header, an MP4's is its last box, beyond the first MB."""
    from poisoner.provenance import mp4_box, sealing_key
    from testkit.video import Clip, make_clip

    lossless = (("qp", "0"), ("preset", "ultrafast"))
    big = Clip(width=1280, height=720, frames=12, audio=None, options=lossless)
    clip = make_clip(tmp_path / "c.mp4", big)
    assert clip.stat().st_size > 3 << 20
    with open(clip, "ab") as f:
        f.write(mp4_box(MARKER))  # as poisoner.video.metadata.append_marker_box does
    seal_file(clip, KEY)
    other = bytes(32)
    assert sealing_key(clip, [other, KEY]) == 1 and sealing_key(clip, [other]) == -1
    write(tmp_path / "src.png", "png", False)
    sealed(tmp_path / "src.png", tmp_path / "out.png")
    assert sealing_key(tmp_path / "out.png", [KEY]) == 0
    (tmp_path / "empty.png").write_bytes(b"")
    for unsealed in ("src.png", "empty.png", "missing.png"):  # no seal to read: None
        assert sealing_key(tmp_path / unsealed, [KEY]) is None
