"""The bit-level JPEG splice (poisoner/jpeg_scan.py over poisoner/_jpeg_entropy.c), checked against
libjpeg-turbo: poison_file writes the coefficients libjpeg-turbo's path writes (same pixels, same
blocks, the same entropy-coded bytes), the placement thumbnail from the luma DCs is the picture
libjpeg's 1/8 greyscale decode gives, anything the path does not handle goes to libjpeg-turbo's path,
and no byte string makes the C code crash (a child process fuzzes it)."""

from __future__ import annotations

import io
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner import jpeg as jpeg_codec
from poisoner import jpeg_scan, jpeg_turbo
from poisoner.formats import poison_file
from poisoner.ladder import default_spec
from poisoner.spec import PatchSpec
from poisoner.subject import display_details
from testkit.photos import gps_exif, textured

needs_turbo = pytest.mark.skipif(jpeg_codec.turbo_available() is not None, reason="libturbojpeg missing")

# (size, save options): every sampling, greyscale, sizes that are no multiple of the MCU.
CASES = {
    "444": ((331, 250), {"subsampling": 0}),
    "422": ((320, 241), {"subsampling": 1}),
    "420": ((333, 247), {"subsampling": 2}),
    "grey": ((250, 190), {"grey": True}),
}
SPECS = {
    "bottom-right": PatchSpec(patch_size=29, block_size=5, position="bottom-right"),
    "center": PatchSpec(patch_size=37, block_size=4, position="center"),
    "product-default": default_spec(),  # per photo, two squares: patched a part at a time
}


def write_case(path: Path, case: str, seed: int = 0, **extra: object) -> bytes:
    (w, h), opts = CASES[case]
    opts = {**opts, **extra}
    im = Image.fromarray(textured(h, w, seed))
    if opts.pop("grey", False):
        im = im.convert("L")
    im.save(path, "JPEG", quality=90, exif=gps_exif(), comment=b"scan test", **opts)
    return path.read_bytes()


def scan_bytes(data: bytes) -> bytes:
    """The entropy-coded data, SOS header to EOI."""
    return data[jpeg_scan.parse(data).scan_start :]


def test_the_extension_is_built_here() -> None:
    """The README's set-up compiles it (setup.py); without it ppd still works, at libjpeg-turbo's cost."""
    assert jpeg_scan.available() is None


@needs_turbo
@pytest.mark.parametrize("spec", sorted(SPECS))
@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("seed", [1, 3])
def test_poison_file_writes_what_libjpeg_turbo_writes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str, spec: str, seed: int
) -> None:
    src = tmp_path / f"IMG_{seed:04d}.jpg"
    write_case(src, case, seed)
    spliced: list[int] = []
    real = jpeg_scan.splice
    monkeypatch.setattr(jpeg_scan, "splice", lambda ix, data, which, coef: spliced.append(len(which)) or real(
        ix, data, which, coef))  # fmt: skip
    ours = poison_file(src, tmp_path / "scan.jpg", SPECS[spec])
    assert spliced and spliced[0] > 0, "the bit-level path was not taken"
    monkeypatch.setenv(jpeg_scan.SCAN_ENV, "")
    theirs = poison_file(src, tmp_path / "turbo.jpg", SPECS[spec])
    assert len(spliced) == 1 and ours.method == theirs.method == "jpeg-dct-splice"
    assert ours.placement == theirs.placement
    a, b, s = ((tmp_path / n).read_bytes() for n in ("scan.jpg", "turbo.jpg", src.name))
    for x, y in zip(jpeg_turbo.read_blocks(a), jpeg_turbo.read_blocks(b), strict=True):
        assert np.array_equal(x, y)
    assert scan_bytes(a) == scan_bytes(b) != scan_bytes(s)
    assert jpeg_codec.read_layout(a).segments == jpeg_codec.read_layout(b).segments  # marker, no GPS
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(a))), np.asarray(Image.open(io.BytesIO(b))))


@needs_turbo
@pytest.mark.parametrize("case", ["420", "444", "grey"])
def test_mcus_the_keep_out_mask_reaches_keep_their_bits(tmp_path: Path, case: str) -> None:
    """A subject mask reaching into the mark's box: those MCUs are never re-coded, so every pixel
    of the subject decodes exactly as before, and the file equals libjpeg-turbo's."""
    src = tmp_path / "a.jpg"
    write_case(src, case)
    w, h = CASES[case][0]
    x0, y0, x1, y1 = SPECS["bottom-right"].resolve(w, h).box
    yy, xx = np.mgrid[0:h, 0:w]
    mask = ((xx - x0) + (yy - y0) < (x1 - x0) // 2).astype(np.uint8)  # the subject reaches into the mark
    ours = poison_file(src, tmp_path / "scan.jpg", SPECS["bottom-right"], keep_out=mask)
    assert any("coefficients copied" in n for n in ours.notes), ours.notes
    before, after = (np.asarray(Image.open(p)).astype(int) for p in (src, tmp_path / "scan.jpg"))
    assert np.array_equal(before[mask > 0], after[mask > 0]) and not np.array_equal(before, after)


def test_box_at_every_edge_and_overlapping_parts(tmp_path: Path) -> None:
    """patch_in_place against libjpeg-turbo's pass on boxes touching each edge of a picture whose
    size is no multiple of the MCU (partial MCUs, dummy blocks), and on two parts sharing an MCU."""
    data = write_case(tmp_path / "a.jpg", "420", 5)
    im, layout = Image.open(io.BytesIO(data)), jpeg_codec.read_layout(data)

    def patch(px: np.ndarray, _part: object = None) -> np.ndarray:
        out = px.copy()
        out[::3, ::2] = 255 - out[::3, ::2]
        return out

    def encode(px: np.ndarray) -> bytes:
        return jpeg_codec.encode_like(px, im, layout, metadata=False)

    w, h = im.size
    edges = [(0, 0, 48, 32), (w - w % 16, h - h % 16, w, h), (16, h - h % 16 - 16, w, h), (96, 64, 160, 96)]
    for box in edges:
        ours = jpeg_scan.patch_in_place(data, encode, box, patch)
        theirs = jpeg_codec.patch_in_one_pass(data, im, layout, box, patch)
        assert scan_bytes(ours) == scan_bytes(theirs), box
    parts = [(96, 64, 144, 96), (128, 64, 160, 96)]  # both hold the MCU at x 128..144
    ours = jpeg_scan.patch_in_place(data, encode, (96, 64, 160, 96), patch, parts=parts)
    assert scan_bytes(ours) == scan_bytes(jpeg_scan.patch_in_place(data, encode, (96, 64, 160, 96), patch))


@pytest.mark.parametrize("size", [(2100, 2060), (2333, 2049), (4100, 2300)])
@pytest.mark.parametrize("grey", [False, True])
def test_luma_thumbnail_is_libjpegs_eighth_scale_grey_decode(tmp_path: Path, size: tuple, grey: bool) -> None:
    w, h = size
    im = Image.fromarray(textured(h, w, 2))
    (im.convert("L") if grey else im).save(tmp_path / "big.jpg", "JPEG", quality=85)
    data = (tmp_path / "big.jpg").read_bytes()
    with Image.open(io.BytesIO(data)) as pil:
        pil.draft("L", (256, 256))
        assert pil.size == (-(-w // 8), -(-h // 8))
        expected = np.asarray(pil)
    assert np.array_equal(jpeg_scan.luma_thumbnail(jpeg_scan.index(data)), expected)


def test_placement_judges_the_same_thumbnail_either_way(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ppd poison (which reads the DCs) and a machine without the extension (Pillow's decode) place the
    mark on the same detail map."""
    Image.fromarray(textured(2080, 2600, 4)).save(tmp_path / "big.jpg", "JPEG", quality=88)
    data = (tmp_path / "big.jpg").read_bytes()
    with_scan = display_details(data, "big.jpg")
    jpeg_scan.forget()
    monkeypatch.setenv(jpeg_scan.SCAN_ENV, "")
    without = display_details(data, "big.jpg")
    assert all(np.array_equal(x, y) for x, y in zip(with_scan[:2], without[:2], strict=True))
    assert with_scan[0].any() and not with_scan[0].all()


@needs_turbo
@pytest.mark.parametrize(
    "kind, options",
    [
        ("progressive", {"progressive": True}),
        ("restart markers", {"restart_marker_blocks": 2}),
        ("CMYK", {}),
    ],
)
def test_files_it_does_not_handle_go_to_libjpeg_turbo(tmp_path: Path, kind: str, options: dict) -> None:
    src = tmp_path / "a.jpg"
    im = Image.fromarray(textured(200, 240))
    (im.convert("CMYK") if kind == "CMYK" else im).save(src, "JPEG", quality=90, **options)
    with pytest.raises(jpeg_scan.Unsupported):
        jpeg_scan.index(src.read_bytes())
    if kind != "CMYK":  # ppd refuses CMYK JPEG anyway
        report = poison_file(src, tmp_path / "out.jpg", SPECS["center"])
        assert report.method == "jpeg-dct-splice"


def test_optimised_tables_kept_or_handed_on(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A source with optimised Huffman tables: the new blocks are coded with its tables where they hold
    every symbol needed, else libjpeg's path re-optimises; either way the coefficients are the same."""
    src = tmp_path / "a.jpg"
    Image.fromarray(textured(240, 320, 7)).save(src, "JPEG", quality=90, optimize=True)
    ours = (poison_file(src, tmp_path / "scan.jpg", SPECS["center"]), (tmp_path / "scan.jpg").read_bytes())
    monkeypatch.setenv(jpeg_scan.SCAN_ENV, "")
    poison_file(src, tmp_path / "turbo.jpg", SPECS["center"])
    theirs = (tmp_path / "turbo.jpg").read_bytes()
    for x, y in zip(jpeg_turbo.read_blocks(ours[1]), jpeg_turbo.read_blocks(theirs), strict=True):
        assert np.array_equal(x, y)


def test_the_c_calls_refuse_bad_arguments() -> None:
    from poisoner import _jpeg_entropy as c  # type: ignore[attr-defined]

    data = write_case_bytes()
    ix = jpeg_scan.index(data)
    lay = ix.layout
    with pytest.raises(ValueError, match="increase"):
        c.splice(ix.clean, ix.nbytes, lay.coding, lay.tables, ix.offsets, ix.dc,
                 np.array([3, 2], dtype=np.int64), np.zeros((2, 6, 64), np.int16))  # fmt: skip
    with pytest.raises(ValueError, match="buffer"):
        c.splice(ix.clean, ix.nbytes, lay.coding, lay.tables, ix.offsets, ix.dc,
                 np.array([3], dtype=np.int64), np.zeros((1, 2, 64), np.int16))  # fmt: skip
    with pytest.raises(ValueError, match="padding"):
        c.decode(ix.clean[:-2000], ix.nbytes, lay.coding, lay.tables, ix.offsets, ix.dc,
                 np.array([0], dtype=np.int64), np.zeros((1, 6, 64), np.int16))  # fmt: skip
    with pytest.raises(ValueError, match="Huffman"):
        c.encode(np.zeros((1, 6, 64), np.int16), lay.coding, (b"\x05" * 16 + b"\x00" * 80, *lay.tables[1:]))


def test_a_table_libjpeg_refuses_is_refused() -> None:
    """A DC table holding a symbol above 15 (one no block uses): libjpeg refuses the file, so does
    this path (found by tests/poisoner/test_properties.py's fuzzing), and never writes it."""
    data = bytearray(write_case_bytes())
    at = data.index(b"\xff\xc4")
    assert data[at + 4] == 0x00  # Pillow's first table: DC 0
    values = at + 4 + 17
    data[values + sum(data[at + 5 : at + 21]) - 1] = 16
    with pytest.raises(jpeg_scan.Unsupported, match="Huffman"):
        jpeg_scan.index(bytes(data))


def write_case_bytes() -> bytes:
    buf = io.BytesIO()
    Image.fromarray(textured(64, 96, 9)).save(buf, "JPEG", quality=90)
    return buf.getvalue()


FUZZ = textwrap.dedent(
    """
    import io, sys
    import numpy as np
    from PIL import Image
    from poisoner import jpeg, jpeg_scan
    from testkit.photos import textured
    buf = io.BytesIO()
    Image.fromarray(textured(72, 104, 1)).save(buf, "JPEG", quality=85)
    seed = buf.getvalue()
    start = jpeg_scan.parse(seed).scan_start
    rng = np.random.default_rng(int(sys.argv[1]))
    counts = {"refused": 0, "written": 0}
    for trial in range(int(sys.argv[2])):
        data = bytearray(seed)
        for _ in range(int(rng.integers(1, 4))):  # header bytes a third of the time, scan bytes else
            pos = int(rng.integers(2, start)) if rng.random() < 0.33 else int(rng.integers(start, len(data)))
            data[pos] = int(rng.integers(0, 256))
        if rng.random() < 0.2:
            data = data[: int(rng.integers(2, len(data)))]
        data = bytes(data)
        jpeg_scan.forget()
        try:
            im = Image.open(io.BytesIO(data))
            layout = jpeg.read_layout(data)
            out = jpeg_scan.patch_in_place(
                data, lambda px: jpeg.encode_like(px, im, layout, metadata=False), (16, 16, 48, 48),
                lambda px, _part: 255 - px)
        except (jpeg_scan.Unsupported, OSError, ValueError, SyntaxError):
            counts["refused"] += 1
            continue
        Image.open(io.BytesIO(out)).load()  # what it wrote, libjpeg decodes
        counts["written"] += 1
    print(counts["refused"], counts["written"])
    """
)


@pytest.mark.parametrize("seed", [0, 1])
def test_no_byte_string_crashes_it(seed: int) -> None:
    """Corrupt headers and scans, truncations: each is refused (libjpeg's path then judges it) or
    written as a file libjpeg decodes; the child process never dies of a signal."""
    done = subprocess.run([sys.executable, "-c", FUZZ, str(seed), "400"], capture_output=True, text=True,
                          timeout=300, cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    refused, written = map(int, done.stdout.split())
    assert refused + written == 400 and refused > 50 and written > 50


def test_next_marker_finds_what_the_completeness_check_finds() -> None:
    """poisoner.completeness uses the C module's next_marker where it is built, its regular expression
    where not: both give the same position on byte strings made of markers, stuffing and fill."""
    from poisoner._jpeg_entropy import next_marker  # type: ignore[attr-defined]

    from poisoner.completeness import _JPEG_MARKER

    rng = np.random.default_rng(0)
    alphabet = np.array([0x00, 0xFF, 0xD0, 0xD7, 0xD8, 0xD9, 0x12, 0xC4], dtype=np.uint8)
    found = 0
    for _ in range(5000):
        data = bytes(rng.choice(alphabet, size=int(rng.integers(0, 40))))
        start = int(rng.integers(0, len(data) + 2))
        m = _JPEG_MARKER.search(data, start)
        assert next_marker(data, start) == (-1 if m is None else m.start()), (data, start)
        found += m is not None
    assert 1000 < found < 4500


# ---- crafted files: what a damaged or hostile header or scan can hold (found by review) -------------


def _bits_of(value: int) -> tuple[int, int]:
    """A coefficient's JPEG size category and its bits (negative: ones' complement)."""
    size = abs(value).bit_length()
    return size, (value if value >= 0 else value + (1 << size) - 1)


def _segment(marker: int, payload: bytes) -> bytes:
    return bytes((0xFF, marker)) + (len(payload) + 2).to_bytes(2, "big") + payload


def crafted_grey_jpeg(
    dcs: list[int], ac1: list[int], dc_q: int = 1, cols: int = 2, zrls: list[int] | None = None
) -> bytes:
    """A baseline greyscale JPEG written by hand, one 8x8 block per DC (cols blocks a row): its DC
    values and its first AC coefficients as given, whatever baseline libjpeg would write (categories
    up to 15: a damaged or hostile file's); zrls: runs of 16 zeros written before each block's AC."""
    dc_codes = {s: (s, 5) for s in range(16)}  # 16 codes of 5 bits: 0..15
    ac_symbols = [0x00, *range(1, 16), 0xF0]  # EOB, run 0 size 1..15, ZRL: 17 codes of 5 bits
    ac_codes = {sym: (i, 5) for i, sym in enumerate(ac_symbols)}
    out = bytearray()
    acc, n = 0, 0

    def put(value: int, length: int) -> None:
        nonlocal acc, n
        acc, n = (acc << length) | value, n + length
        while n >= 8:
            byte = (acc >> (n - 8)) & 0xFF
            out.append(byte)
            if byte == 0xFF:
                out.append(0)
            n -= 8

    last = 0
    for dc, ac, zrl in zip(dcs, ac1, zrls or [0] * len(dcs), strict=True):
        size, bits = _bits_of(dc - last)
        last = dc
        put(*dc_codes[size])
        if size:
            put(bits, size)
        for _ in range(zrl):
            put(*ac_codes[0xF0])
        if ac:
            size, bits = _bits_of(ac)
            put(*ac_codes[size])
            put(bits, size)
        put(*ac_codes[0x00])
    if n:
        put((1 << (8 - n)) - 1, 8 - n)
    rows = -(-len(dcs) // cols)
    dqt = b"\x00" + bytes([dc_q] + [1] * 63)
    sof = b"\x08" + (8 * rows).to_bytes(2, "big") + (8 * cols).to_bytes(2, "big") + b"\x01\x01\x11\x00"
    dht = b"\x00" + bytes([0, 0, 0, 0, 16] + [0] * 11) + bytes(range(16))
    dht += b"\x10" + bytes([0, 0, 0, 0, 17] + [0] * 11) + bytes(ac_symbols)
    sos = b"\x01\x01\x00\x00\x3f\x00"
    return (b"\xff\xd8" + _segment(0xDB, dqt) + _segment(0xC0, sof) + _segment(0xC4, dht)
            + _segment(0xDA, sos) + bytes(out) + b"\xff\xd9")  # fmt: skip


def test_the_crafted_file_is_what_libjpeg_reads() -> None:
    """The hand-written file above decodes in libjpeg to its coefficients (the tests below rely on it)."""
    data = crafted_grey_jpeg([10, -20, 3, 0], [5, 0, -300, 0])
    blocks = jpeg_turbo.read_blocks(data)[0].reshape(-1, 64)
    assert blocks[:, 0].tolist() == [10, -20, 3, 0]
    assert blocks[:, 1].tolist() == [5, 0, -300, 0]
    ix = jpeg_scan.index(data)
    assert ix.dc[:, 0].tolist() == [10, -20, 3, 0]


@pytest.mark.parametrize("dc_q", [1, 2, 9])
def test_thumbnail_of_out_of_range_dcs_is_libjpegs(dc_q: int) -> None:
    """A damaged DC far outside the picture's range: libjpeg's 1/8 decode wraps it through its range
    table (a DC of 3000 at q 2 reads as black), and the thumbnail placement judges is that very one."""
    dcs = [3000, -3000, 1000, -1000, 2040, -2040, 500, 30000 // dc_q]
    data = crafted_grey_jpeg(dcs, [0] * len(dcs), dc_q=dc_q, cols=4)
    with Image.open(io.BytesIO(data)) as im:
        im.draft("L", (im.width // 8, im.height // 8))
        expected = np.asarray(im.convert("L"))
    assert expected.shape == (2, 4)
    got = jpeg_scan.luma_thumbnail(jpeg_scan.index(data))
    assert got.tolist() == expected.tolist()


@pytest.mark.parametrize("dcs, ac1", [([0, 0, 0, 0], [0, 1500, 0, 0]), ([3000, 0, 0, 0], [0, 0, 0, 0])])
def test_coefficients_no_baseline_table_codes_are_refused(dcs: list[int], ac1: list[int]) -> None:
    """An AC of 1500 or a DC step of 3000 (beyond what an 8-bit baseline encoder writes): the lossless
    crop cannot code it, so the bit-level path refuses (libjpeg's path judges the file) instead of
    raising a bare ValueError out of poison_file."""
    data = crafted_grey_jpeg(dcs, ac1)
    with pytest.raises(jpeg_scan.Unsupported):
        jpeg_scan.patch_in_place(data, lambda px: b"", (0, 0, 16, 8), lambda px, _part: px)


def _with_segment_payload(data: bytes, marker: int, edit: Callable[[bytes], bytes]) -> bytes:
    at = data.index(bytes((0xFF, marker)))
    length = int.from_bytes(data[at + 2 : at + 4], "big")
    payload = edit(data[at + 4 : at + 2 + length])
    return data[:at] + _segment(marker, payload) + data[at + 2 + length :]


@pytest.mark.parametrize(
    "marker, edit, reason",
    [
        (0xC4, lambda p: p + b"\x00\x01", "DHT"),  # bytes after the last table
        (0xC0, lambda p: p[:1] + b"\xff\xff" + p[3:], "size"),  # 65535 rows: beyond libjpeg's 65500
        (0xC0, lambda p: p + b"\x00", "length"),  # a frame header a byte too long
        (0xC0, lambda p: p[:7] + b"\x01" + p[8:], "sampling"),  # luma sampled 0x1
        (0xDA, lambda p: b"", "scan"),  # a scan header of no components
    ],
)
def test_headers_libjpeg_refuses_are_refused(
    marker: int, edit: Callable[[bytes], bytes], reason: str
) -> None:
    data = _with_segment_payload(crafted_grey_jpeg([1, 2, 3, 4], [0, 0, 0, 0]), marker, edit)
    with pytest.raises(jpeg_scan.Unsupported, match=reason):
        jpeg_scan.index(data)


OVERFLOW = textwrap.dedent(
    """
    import sys
    from poisoner import jpeg_scan
    data = bytes.fromhex(sys.argv[1])
    try:
        jpeg_scan.index(data)
    except jpeg_scan.Unsupported as exc:
        print("refused:", exc)
    else:
        print("indexed")
    """
)


@pytest.mark.parametrize("used", [False, True])
def test_a_table_with_more_short_codes_than_fit_is_refused_before_it_is_built(used: bool) -> None:
    """A Huffman table claiming 255 codes of one bit. ppd's C module wrote a table's lookahead before
    checking its codes (a heap overflow, found by review under AddressSanitizer) and built every
    table the file defines. Now, as libjpeg: a table the scan does not use is never built (the file
    is indexed), one it uses is refused, checked before a code is written. In a child process, as a
    heap overflow need not die at once."""
    data = crafted_grey_jpeg([1, 2, 3, 4], [0, 0, 0, 0])
    bad = bytes([0x00 if used else 0x13, 255] + [0] * 15) + bytes(255)  # DC 0 (the scan's) or AC 3
    data = _with_segment_payload(data, 0xC4, lambda p: p + bad)  # defined again: the later one holds
    done = subprocess.run([sys.executable, "-c", OVERFLOW, data.hex()], capture_output=True, text=True,
                          timeout=120, cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    if used:
        assert done.stdout.startswith("refused:") and "Huffman" in done.stdout, done.stdout
    else:
        assert done.stdout.strip() == "indexed", done.stdout


def test_a_run_past_the_blocks_end_is_refused(tmp_path: Path) -> None:
    """Four runs of 16 zeros carry a block past its 63rd coefficient: no encoder writes that, the index
    refuses it (the C module's index takes a run past the end as damage; decode_block, like libjpeg,
    reads it, and runs only on files the index accepted) and libjpeg's path patches the file."""
    cols, n = 16, 128
    fine = crafted_grey_jpeg([5] * n, [0] * n, cols=cols, zrls=[3 * (i == 9) for i in range(n)])
    assert jpeg_scan.index(fine).dc[:, 0].tolist() == [5] * n  # three runs end at 49: a fine block
    data = crafted_grey_jpeg([5] * n, [0] * n, cols=cols, zrls=[4 * (i == 9) for i in range(n)])
    with pytest.raises(jpeg_scan.Unsupported):
        jpeg_scan.index(data)
    (tmp_path / "a.jpg").write_bytes(data)
    poison_file(tmp_path / "a.jpg", tmp_path / "out.jpg", SPECS["bottom-right"])
    with Image.open(tmp_path / "out.jpg") as out, Image.open(tmp_path / "a.jpg") as src:
        assert out.size == src.size and np.asarray(out).tolist() != np.asarray(src).tolist()


# ---- the index's skip table (two AC symbols a look-up) against the one-symbol decoder --------------


def _random_blocks(rng: np.random.Generator, n: int) -> np.ndarray:
    """n blocks (natural order) of every shape a scan holds: empty, sparse with long zero runs
    (ZRLs), dense, a last coefficient at 63 (no end of block), only the 63rd; values up to the
    baseline's 10 bits (AC) and DC differences up to 11 bits."""
    blocks = np.zeros((n, 64), dtype=np.int16)
    zigzag = np.array(_zigzag())
    for i in range(n):
        kind = i % 6
        density = (0.0, 0.03, 0.2, 0.7, 1.0, 0.0)[kind]
        ac = np.where(rng.random(63) < density, rng.integers(1, 1024, 63) * rng.choice((-1, 1), 63), 0)
        if kind in (2, 3) and rng.random() < 0.5:
            ac[-1] = rng.integers(1, 1024)  # the block ends at 63: the next symbol is a DC
        if kind == 5:
            ac[-1] = rng.choice((-1, 1)) * rng.integers(1, 4)  # 62 zeros: three ZRLs, then run 14
        blocks[i, zigzag[1:]] = ac
        blocks[i, 0] = rng.integers(-1000, 1000)
    return blocks


def _zigzag() -> list[int]:
    """Natural index of each zigzag position (the C module's NATURAL)."""
    order = sorted((x + y, y if (x + y) % 2 else x, y * 8 + x) for y in range(8) for x in range(8))
    return [n for _, _, n in order]


def _shuffled_table(table: bytes, rng: np.random.Generator) -> bytes:
    """The same code lengths, the symbols dealt to them anew: frequent symbols get long codes and
    rare ones short, so the skip table's pairs, its single entries and the long-code path all run."""
    values = bytearray(table[16:])
    rng.shuffle(values)
    return table[:16] + bytes(values)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("case", ["grey", "420"])
def test_the_index_reads_what_the_one_symbol_decoder_reads(tmp_path: Path, seed: int, case: str) -> None:
    """Random blocks coded with the standard tables (seed 0) or shuffled ones: the index's DC values
    and MCU offsets (one look-up for two AC symbols where both fit in its 12 bits) let the
    one-symbol decoder read back every coefficient coded."""
    rng = np.random.default_rng(seed)
    codec = jpeg_scan._codec()
    coding, tables = jpeg_scan._standard_coding(jpeg_scan.parse(write_case(tmp_path / "a.jpg", case)))
    if seed:
        tables = tuple(_shuffled_table(t, rng) if i >= 4 and t else t for i, t in enumerate(tables))
    bpm = sum(h * v for h, v, _, _ in coding)
    n_mcus = 300
    coef = _random_blocks(rng, n_mcus * bpm).reshape(n_mcus, bpm, 64)
    scan = codec.encode(np.ascontiguousarray(coef), coding, tables) + b"\xff\xd9"
    clean, nbytes, _ = codec.unstuff(scan, 0)
    offsets = np.empty(n_mcus + 1, dtype=np.int64)
    dc = np.empty((n_mcus, bpm), dtype=np.int16)
    codec.index(clean, nbytes, coding, tables, n_mcus, offsets, dc)
    assert dc.tolist() == coef[:, :, 0].tolist()
    back = np.empty_like(coef)
    codec.decode(clean, nbytes, coding, tables, offsets, dc, np.arange(n_mcus, dtype=np.int64), back)
    assert back.tolist() == coef.tolist()
