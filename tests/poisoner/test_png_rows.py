"""PNG with the source's filtered rows re-used (poisoner.image.png_rows): the decoded file is the
patched picture exactly, every row outside the mark's band keeps its filtered bytes, every chunk
but IDAT is copied in its place, the deflate falls back when the fast one would grow the file, and
the files it does not take still go through the whole re-encode."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.blend import apply_patch
from poisoner.formats import plan_mark, poison_file
from poisoner.image import png_rows
from poisoner.image.png import png_chunks
from poisoner.ladder import default_spec
from poisoner.spec import PatchSpec

CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}


def _reference_filter(kind: int, row: bytes, above: bytes, bpp: int) -> bytes:
    """PNG's five filters, byte by byte, as the specification writes them (independent of numpy)."""
    out = bytearray()
    for i, x in enumerate(row):
        a = row[i - bpp] if i >= bpp else 0
        b = above[i]
        c = above[i - bpp] if i >= bpp else 0
        if kind == 0:
            pred = 0
        elif kind == 1:
            pred = a
        elif kind == 2:
            pred = b
        elif kind == 3:
            pred = (a + b) // 2
        else:
            p = a + b - c
            pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
            pred = a if pa <= pb and pa <= pc else b if pb <= pc else c
        out.append((x - pred) & 0xFF)
    return bytes(out)


def _chunk(ctype: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + ctype + body + struct.pack(">I", zlib.crc32(ctype + body))


def write_png(pixels: np.ndarray, colour: int, kinds: list[int], level: int = 9) -> bytes:
    """A PNG whose rows use exactly `kinds` as filter types, with text chunks before and after IDAT."""
    h, w = pixels.shape[:2]
    bpp = CHANNELS[colour]
    flat = pixels.reshape(h, w * bpp)
    raw = bytearray()
    above = bytes(w * bpp)
    for y in range(h):
        row = flat[y].tobytes()
        raw += bytes([kinds[y]]) + _reference_filter(kinds[y], row, above, bpp)
        above = row
    ihdr = struct.pack(">IIBBBBB", w, h, 8, colour, 0, 0, 0)
    idat = zlib.compress(bytes(raw), level)
    return b"".join([
        b"\x89PNG\r\n\x1a\n", _chunk(b"IHDR", ihdr), _chunk(b"tEXt", b"Title\x00before"),
        _chunk(b"IDAT", idat[: len(idat) // 2]), _chunk(b"IDAT", idat[len(idat) // 2 :]),
        _chunk(b"tEXt", b"Comment\x00after"), _chunk(b"IEND", b""),
    ])  # fmt: skip


def _rows(data: bytes) -> np.ndarray:
    ihdr = png_chunks(data)[0][1]
    w, h, colour = struct.unpack(">II", ihdr[:8]) + (ihdr[9],)
    raw = zlib.decompress(b"".join(b for t, b in png_chunks(data) if t == b"IDAT"))
    return np.frombuffer(raw, np.uint8).reshape(h, w * CHANNELS[colour] + 1)


def _picture(h: int, w: int, channels: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    smooth = np.linspace(0, 255, w, dtype=np.float64)[None, :, None] * np.ones((h, 1, channels))
    noise = rng.integers(-20, 21, size=(h, w, channels))
    pixels = np.clip(smooth + noise, 0, 255).astype(np.uint8)
    if channels in (2, 4):
        pixels[..., -1] = rng.integers(0, 256, size=(h, w), dtype=np.uint8)  # real transparency
    return pixels


@pytest.mark.parametrize("colour", sorted(CHANNELS))
@pytest.mark.parametrize("spec", ["product-default", "top-left"])
def test_the_patched_png_decodes_to_the_patched_picture_and_keeps_the_other_rows(
    tmp_path: Path, colour: int, spec: str
) -> None:
    h, w = 120, 160
    pixels = _picture(h, w, CHANNELS[colour], seed=colour)
    kinds = [int(k) for k in np.random.default_rng(7).integers(0, 5, size=h)]  # every filter type
    src, dst = tmp_path / "IMG_0004.png", tmp_path / "out.png"
    src.write_bytes(write_png(pixels if CHANNELS[colour] > 1 else pixels[..., 0], colour, kinds))
    chosen = default_spec() if spec == "product-default" else PatchSpec(patch_size=30, block_size=4)
    report = poison_file(src, dst, chosen)
    assert any("filtered again" in n for n in report.notes), report.notes
    out = dst.read_bytes()
    # the pixels: the blend of the placement on the decoded source (RGBA: opaque over white)
    with Image.open(src) as im:
        expected = apply_patch(np.asarray(im), report.placement)
    with Image.open(io.BytesIO(out)) as im:
        assert im.mode == {0: "L", 2: "RGB", 4: "LA", 6: "RGBA"}[colour]
        assert np.array_equal(np.asarray(im), expected)
    # rows outside the band (and the row below it): the source's filtered bytes
    x0, y0, x1, y1 = report.placement.box
    before, after = _rows(src.read_bytes()), _rows(out)
    outside = np.ones(h, dtype=bool)
    outside[y0 : min(h, y1 + 1)] = False
    assert outside.any() and np.array_equal(before[outside], after[outside])
    assert np.array_equal(before[:, 0], after[:, 0])  # each row keeps its filter type
    # every chunk but IDAT in its place, byte for byte
    kept = [(t, b) for t, b in png_chunks(out) if t != b"IDAT"]
    assert kept == [(t, b) for t, b in png_chunks(src.read_bytes()) if t != b"IDAT"]
    assert report.method == "png-lossless" and report.lossless


def test_filter_rows_matches_the_specification_for_every_type() -> None:
    rng = np.random.default_rng(3)
    for bpp in (1, 2, 3, 4):
        rows = rng.integers(0, 256, size=(5, 12 * bpp), dtype=np.uint8)
        above = rng.integers(0, 256, size=(5, 12 * bpp), dtype=np.uint8)
        kinds = np.array([0, 1, 2, 3, 4], dtype=np.uint8)
        got = png_rows.filter_rows(kinds, rows, above, bpp)
        for i in range(5):
            assert got[i].tobytes() == _reference_filter(i, rows[i].tobytes(), above[i].tobytes(), bpp)


def test_the_deflate_falls_back_when_the_fast_one_would_grow_the_file(tmp_path: Path) -> None:
    """A picture of one small tile repeated: LZ matches make level 9 far smaller than run-length
    coding, so the fast setting passes the bound and the stream is compressed at level 6."""
    tile = np.random.default_rng(1).integers(0, 256, size=(16, 16, 3), dtype=np.uint8)
    pixels = np.tile(tile, (10, 12, 1))
    src, dst = tmp_path / "IMG_0001.png", tmp_path / "out.png"
    src.write_bytes(write_png(pixels, 2, [0] * pixels.shape[0]))
    report = poison_file(src, dst, PatchSpec(patch_size=30, block_size=4))
    assert any("level 6" in n for n in report.notes), report.notes
    src_idat = sum(len(b) for t, b in png_chunks(src.read_bytes()) if t == b"IDAT")
    out_idat = sum(len(b) for t, b in png_chunks(dst.read_bytes()) if t == b"IDAT")
    level, strategy = png_rows.FAST
    deflate = zlib.compressobj(level, zlib.DEFLATED, 15, 9, strategy)
    fast = len(deflate.compress(_rows(dst.read_bytes()).tobytes()) + deflate.flush())
    assert fast > png_rows.SIZE_BOUND * src_idat and out_idat < fast
    with Image.open(src) as im:
        expected = apply_patch(np.asarray(im), report.placement)
    with Image.open(dst) as im:
        assert np.array_equal(np.asarray(im), expected)


def _repeating(h: int, w: int, seed: int) -> np.ndarray:
    """Shading under one small noise tile repeated (a pattern, a screen capture, bench_batch's
    synthetic camera pictures): LZ finds the repeats, run-length coding does not."""
    rng = np.random.default_rng(seed)
    tile = rng.integers(-12, 13, size=(32, 32, 3))
    shade = 128 + 60 * np.sin(np.arange(w) / 37.0)[None, :, None] * np.ones((h, 1, 3))
    return np.clip(shade + np.tile(tile, (h // 32 + 1, w // 32 + 1, 1))[:h, :w], 0, 255).astype(np.uint8)


def test_a_repeating_picture_takes_level_6_default_within_the_bound(tmp_path: Path) -> None:
    """Run-length coding grows such a picture far past the bound; zlib's default strategy at level 6
    keeps its size (and costs less CPU than Z_FILTERED), so that is what the file gets, lossless."""
    src, dst = tmp_path / "IMG_0003.png", tmp_path / "out.png"
    Image.fromarray(_repeating(480, 640, seed=4)).save(src)  # Pillow's own: level 6, adaptive filters
    rows = _rows(src.read_bytes()).tobytes()
    src_idat = sum(len(b) for t, b in png_chunks(src.read_bytes()) if t == b"IDAT")
    sizes = {}
    for setting in png_rows.SETTINGS:
        deflate = zlib.compressobj(setting[0], zlib.DEFLATED, 15, 9, setting[1])
        sizes[setting] = len(deflate.compress(rows) + deflate.flush())
    assert sizes[png_rows.FAST] > png_rows.SIZE_BOUND * src_idat >= sizes[png_rows.MIDDLE]
    report = poison_file(src, dst, default_spec())
    assert any("deflate level 6 (" in n for n in report.notes), report.notes
    out_idat = sum(len(b) for t, b in png_chunks(dst.read_bytes()) if t == b"IDAT")
    assert out_idat <= png_rows.SIZE_BOUND * src_idat
    with Image.open(src) as im:
        expected = apply_patch(np.asarray(im), report.placement)
    with Image.open(dst) as im:
        assert np.array_equal(np.asarray(im), expected)


def test_a_setting_past_the_bound_is_given_up_early(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The run-length try on such a picture stops within its first rows, not at the stream's end."""
    data = io.BytesIO()
    Image.fromarray(_repeating(2000, 400, seed=5)).save(data, "PNG")
    idat = b"".join(b for t, b in png_chunks(data.getvalue()) if t == b"IDAT")
    stride = 400 * 3
    fed: list[int] = []
    real = zlib.compressobj

    class Counting:
        def __init__(self, *args: object) -> None:
            self._inner = real(*args)  # type: ignore[arg-type]

        def compress(self, block: bytes) -> bytes:
            fed.append(len(block))
            return self._inner.compress(block)

        def flush(self) -> bytes:
            return self._inner.flush()

    monkeypatch.setattr(png_rows.zlib, "compressobj", Counting)
    band = (np.zeros((1, stride), np.uint8), np.zeros((1, stride), np.uint8))
    out = png_rows._restream(idat, 2000, 0, band, 3, png_rows.FAST, png_rows.SIZE_BOUND)
    assert out is None
    assert 0 < sum(fed) < 0.25 * 2000 * (stride + 1), sum(fed)  # most rows never deflated


@pytest.mark.parametrize("case", ["palette", "16-bit", "colour key"])
def test_the_files_it_does_not_take_are_re_encoded(tmp_path: Path, case: str) -> None:
    pixels = _picture(64, 80, 3, seed=2)
    src, dst = tmp_path / "IMG_0002.png", tmp_path / "out.png"
    im = Image.fromarray(pixels)
    if case == "palette":
        im.convert("P").save(src)
    elif case == "16-bit":
        Image.fromarray(pixels[..., 0].astype(np.uint16) * 257).save(src)
    else:
        im.save(src, transparency=(1, 2, 3))
    spec = PatchSpec(patch_size=20, block_size=4)
    with Image.open(src) as opened:
        opened.load()
        data = src.read_bytes()
        placement, _ = plan_mark(src.name, data, opened.size, spec)
        assert png_rows.poison_png_rows(opened, data, [placement]) is None
    report = poison_file(src, dst, spec)
    assert not any("filtered again" in n for n in report.notes)
    assert dst.read_bytes() != src.read_bytes()


def test_an_interlaced_png_is_not_taken(tmp_path: Path) -> None:
    """Adam7 rows are not picture rows: the IHDR's interlace flag alone sends the file elsewhere."""
    pixels = _picture(64, 80, 3, seed=2)
    data = write_png(pixels, 2, [0] * 64)
    ihdr = png_chunks(data)[0][1]
    interlaced = data.replace(_chunk(b"IHDR", ihdr), _chunk(b"IHDR", ihdr[:12] + b"\x01"))
    assert png_chunks(interlaced)[0][1][12] == 1
    placement = PatchSpec(patch_size=20, block_size=4).resolve(80, 64)
    assert png_rows.poison_png_rows(Image.fromarray(pixels), interlaced, [placement]) is None
    assert png_rows.poison_png_rows(Image.fromarray(pixels), data, [placement]) is not None


def test_the_inflated_rows_are_never_held_whole(tmp_path: Path) -> None:
    """Memory: the rows pass ROWS_PER_STEP at a time (Python's allocations during the call stay far
    under the inflated stream's size; holding it, or a copy, would pass it). The band's own
    filtering (a few int16 arrays of its rows) is what remains: a tall picture keeps it small."""
    import tracemalloc

    h, w = 6000, 300
    ramp = (np.arange(w, dtype=np.uint16)[None, :] * 255 // w).astype(np.uint8)
    pixels = np.repeat(np.repeat(ramp, h, axis=0)[..., None], 3, axis=2)
    data = write_png(pixels, 2, [1] * h, level=6)
    raw_size = h * (w * 3 + 1)
    im = Image.open(io.BytesIO(data))
    im.load()
    placement = PatchSpec(patch_size=60, block_size=4).resolve(w, h)
    tracemalloc.start()
    try:
        out = png_rows.poison_png_rows(im, data, [placement])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert out is not None
    assert peak < raw_size / 2, (peak, raw_size)  # holding the rows, or a copy of them: >= 1x


@pytest.mark.parametrize("damage", ["extra rows", "bad filter type", "rows missing"])
def test_a_stream_unlike_its_header_is_left_to_the_re_encode_untouched(damage: str) -> None:
    """The stream is checked as it is read again; a file that does not hold exactly its rows returns
    None, and the decoded picture it was given is unchanged (the re-encode then patches it once)."""
    h, w = 40, 50
    pixels = _picture(h, w, 3, seed=5)
    data = write_png(pixels, 2, [0] * h)
    raw = bytearray(zlib.decompress(b"".join(b for t, b in png_chunks(data) if t == b"IDAT")))
    if damage == "extra rows":
        raw += raw[: w * 3 + 1]
    elif damage == "bad filter type":
        raw[(w * 3 + 1) * 30] = 7
    else:
        del raw[-(w * 3 + 1) :]
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    bad = b"".join([b"\x89PNG\r\n\x1a\n", _chunk(b"IHDR", ihdr), _chunk(b"IDAT", zlib.compress(bytes(raw))),
                    _chunk(b"IEND", b"")])  # fmt: skip
    im = Image.fromarray(pixels)
    before = np.asarray(im).copy()
    assert png_rows.poison_png_rows(im, bad, [PatchSpec(patch_size=20, block_size=4).resolve(w, h)]) is None
    assert np.array_equal(np.asarray(im), before)
