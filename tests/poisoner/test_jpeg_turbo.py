"""JPEG in one in-process coefficient pass (libturbojpeg): the same bytes as the jpegtran path,
every DCT block outside the patch's MCU box unchanged, and a clear refusal (the caller falls back)
where the library is missing or cannot write the file like its source."""

from __future__ import annotations

import dataclasses
import io
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner import jpeg as jpeg_codec
from poisoner import jpeg_scan, jpeg_turbo
from poisoner.blend import apply_patch
from poisoner.ladder import default_spec
from poisoner.spec import PatchSpec
from testkit.photos import gps_exif, textured

pytestmark = pytest.mark.skipif(
    jpeg_codec.turbo_available() is not None, reason=f"libturbojpeg: {jpeg_codec.turbo_available()}"
)
needs_jpegtran = pytest.mark.skipif(shutil.which("jpegtran") is None, reason="jpegtran not installed")

# (size, save options): every sampling, greyscale, progressive, odd sizes.
CASES = {
    "444": ((331, 250), {"subsampling": 0}),
    "422": ((320, 241), {"subsampling": 1}),
    "420": ((333, 247), {"subsampling": 2}),
    "420-progressive": ((320, 240), {"subsampling": 2, "progressive": True}),
    "grey": ((250, 190), {"grey": True}),
    "grey-progressive": ((251, 191), {"grey": True, "progressive": True}),
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


def write_case(path: Path, case: str, seed: int = 0, **extra: object) -> bytes:
    (w, h), opts = CASES[case]
    opts = {**opts, **extra}
    pixels = textured(h, w, seed)
    im = Image.fromarray(pixels).convert("L") if opts.pop("grey", False) else Image.fromarray(pixels)
    im.save(path, "JPEG", quality=90, exif=gps_exif(), comment=b"turbo test", **opts)
    return path.read_bytes()


def write_cmyk(path: Path) -> bytes:
    Image.fromarray(textured(64, 64)).convert("CMYK").save(path, "JPEG")
    return path.read_bytes()


def box_and_patch(data: bytes, spec: PatchSpec, name: str = "a.jpg"):
    im = Image.open(io.BytesIO(data))
    layout = jpeg_codec.read_layout(data)
    placement = spec.resolve(*im.size, image_key=name)
    box = jpeg_codec.mcu_box(placement.box, layout)
    local = dataclasses.replace(placement, x=placement.x - box[0], y=placement.y - box[1])
    return im, layout, box, (lambda px: apply_patch(px, local))


def blocks_outside_equal(a: bytes, b: bytes, layout: jpeg_codec.JpegLayout, box) -> None:
    """Every DCT block of every component outside the box is the same in a and b; inside differs."""
    offsets = jpeg_codec._component_offsets(layout, box)
    mw, mh = layout.mcu_size
    inside_changed = False
    for ci, (ba, bb) in enumerate(zip(jpeg_turbo.read_blocks(a), jpeg_turbo.read_blocks(b), strict=True)):
        assert ba.shape == bb.shape
        h, v = (1, 1) if layout.components == 1 else layout.sampling[ci]
        bw = -(-(box[2] - box[0]) * h // mw) if layout.components > 1 else -(-(box[2] - box[0]) // 8)
        bh = -(-(box[3] - box[1]) * v // mh) if layout.components > 1 else -(-(box[3] - box[1]) // 8)
        col0, row0 = offsets[ci]
        mask = np.ones(ba.shape[:2], dtype=bool)
        mask[row0 : row0 + bh, col0 : col0 + bw] = False
        assert np.array_equal(ba[mask], bb[mask]), ci
        inside_changed |= not np.array_equal(ba[~mask], bb[~mask])
    assert inside_changed


@needs_jpegtran
@pytest.mark.parametrize("spec_name", sorted(SPECS))
@pytest.mark.parametrize("case", sorted(CASES))
def test_one_pass_gives_the_jpegtran_bytes(tmp_path: Path, case: str, spec_name: str) -> None:
    src = tmp_path / "IMG_0001.jpg"
    data = write_case(src, case)
    im, layout, box, patch = box_and_patch(data, SPECS[spec_name], src.name)
    new = jpeg_codec.patch_in_one_pass(data, im, layout, box, patch)
    old = jpeg_codec.splice_patch(src, im, layout, patch(jpeg_codec.decode_box(src, im, layout, box)), box)
    assert new == old


@pytest.mark.parametrize("case", sorted(CASES))
def test_nothing_outside_the_mcu_box_changes(tmp_path: Path, case: str) -> None:
    data = write_case(tmp_path / "a.jpg", case, seed=5)
    im, layout, box, patch = box_and_patch(data, SPECS["center"])
    out = jpeg_codec.patch_in_one_pass(data, im, layout, box, patch)
    blocks_outside_equal(data, out, layout, box)
    assert jpeg_codec.read_layout(out).segments == layout.segments  # EXIF, comment: all kept
    assert Image.open(io.BytesIO(out)).quantization == im.quantization
    assert jpeg_codec.read_layout(out).progressive == layout.progressive
    if case.startswith("grey"):  # no chroma upsampling: the decoded pixels outside the box too
        a, b = np.asarray(Image.open(io.BytesIO(data))), np.asarray(Image.open(io.BytesIO(out)))
        mask = np.ones(a.shape, dtype=bool)
        mask[box[1] : box[3], box[0] : box[2]] = False
        assert np.array_equal(a[mask], b[mask])


def test_box_pixels_are_the_whole_decode_patched(tmp_path: Path) -> None:
    """The patch is applied to the box's pixels as a whole-picture decode gives them (the ring)."""
    data = write_case(tmp_path / "a.jpg", "420", seed=2)
    im, layout, box, patch = box_and_patch(data, SPECS["center"])
    seen: list[np.ndarray] = []
    jpeg_codec.patch_in_one_pass(data, im, layout, box, lambda px: seen.append(px.copy()) or patch(px))
    whole = np.asarray(Image.open(io.BytesIO(data)))
    assert np.array_equal(seen[0], whole[box[1] : box[3], box[0] : box[2]])


@pytest.mark.parametrize(
    ("make", "reason"),
    [
        (lambda p: write_case(p, "420", restart_marker_blocks=3), "restart"),
        (lambda p: write_case(p, "420", optimize=True), "optimised Huffman"),
        (lambda p: write_cmyk(p), "CMYK"),
    ],
)
def test_files_it_cannot_write_like_the_source_are_refused(tmp_path: Path, make, reason: str) -> None:
    data = make(tmp_path / "a.jpg")
    im, layout = Image.open(io.BytesIO(data)), jpeg_codec.read_layout(data)
    box = jpeg_codec.mcu_box((8, 8, 24, 24), layout)
    with pytest.raises(jpeg_codec.SpliceUnavailable, match=reason):
        jpeg_codec.patch_in_one_pass(data, im, layout, box, lambda px: px)


@pytest.mark.parametrize("setting", ["", "/nonexistent/libturbojpeg.so.0"])
def test_library_switched_off_or_missing_is_refused_with_a_reason(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, setting: str
) -> None:
    monkeypatch.setenv(jpeg_turbo.TURBOJPEG_ENV, setting)
    assert jpeg_codec.turbo_available() is not None
    data = write_case(tmp_path / "a.jpg", "420")
    im, layout, box, patch = box_and_patch(data, SPECS["center"])
    with pytest.raises(jpeg_codec.SpliceUnavailable, match="PPD_TURBOJPEG|libturbojpeg"):
        jpeg_codec.patch_in_one_pass(data, im, layout, box, patch)
    monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "")
    assert jpeg_codec.splice_available() is False


def test_truncated_file_is_refused(tmp_path: Path) -> None:
    data = write_case(tmp_path / "a.jpg", "420")
    cut = data[: len(data) * 3 // 4]
    im, layout, box, patch = box_and_patch(data, SPECS["top-left"])
    with pytest.raises(jpeg_codec.SpliceUnavailable, match="libturbojpeg"):
        jpeg_codec.patch_in_one_pass(cut, im, layout, box, patch)


def test_an_error_in_the_patch_is_raised_as_it_was(tmp_path: Path) -> None:
    data = write_case(tmp_path / "a.jpg", "444")
    im, layout, box, _ = box_and_patch(data, SPECS["center"])

    def broken(px: np.ndarray) -> np.ndarray:
        raise ZeroDivisionError("patch failed")

    with pytest.raises(ZeroDivisionError, match="patch failed"):
        jpeg_codec.patch_in_one_pass(data, im, layout, box, broken)


@needs_jpegtran
@pytest.mark.parametrize("spec", ["top-left", "center"])
def test_poison_file_same_bytes_with_the_library_switched_off(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, spec: str
) -> None:
    """PPD_TURBOJPEG="" takes the jpegtran path through poison_file: the same file is written (a
    one-square mark, which writes in every MCU of its box; MCUs a mark of two squares leaves idle
    keep their coefficients only where libturbojpeg is there: the next test)."""
    from poisoner.formats import poison_file

    src = tmp_path / "IMG_0002.jpg"
    write_case(src, "420")
    outs = {}
    for setting in ("on", ""):
        if setting:
            monkeypatch.delenv(jpeg_turbo.TURBOJPEG_ENV, raising=False)
        else:
            monkeypatch.setenv(jpeg_turbo.TURBOJPEG_ENV, "")
        report = poison_file(src, tmp_path / f"out-{setting}.jpg", SPECS[spec])
        assert report.method == "jpeg-dct-splice"
        outs[setting] = (tmp_path / f"out-{setting}.jpg").read_bytes()
    assert outs["on"] == outs[""] != src.read_bytes()


@pytest.mark.parametrize("case", ["420", "444", "grey"])
def test_mcus_the_two_squares_leave_idle_keep_their_coefficients(tmp_path: Path, case: str) -> None:
    """The product's mark is two squares: in its MCU box, every MCU in which it writes no pixel
    keeps the source's DCT blocks exactly (not re-encoded from pixels), and every MCU it writes in
    changes (luma)."""
    from poisoner.formats import _idle_mcus, poison_file

    src, out = tmp_path / "IMG_0002.jpg", tmp_path / "out.jpg"
    data = write_case(src, case)
    report = poison_file(src, out, SPECS["product-default"])
    layout = jpeg_codec.read_layout(data)
    box = jpeg_codec.mcu_box(report.placement.box, layout)
    idle = _idle_mcus(report.placement, None, box, box, layout)
    assert idle is not None and idle.any() and not idle.all()  # the test needs both kinds
    factors = [(1, 1)] if layout.components == 1 else list(layout.sampling)
    offsets = jpeg_codec._component_offsets(layout, box)
    written = ~idle
    pairs = zip(jpeg_turbo.read_blocks(data), jpeg_turbo.read_blocks(out.read_bytes()), strict=True)
    for ci, (before, after) in enumerate(pairs):
        h, v = factors[ci] if layout.components > 1 else (1, 1)
        col0, row0 = offsets[ci]
        per_block = np.repeat(np.repeat(idle, v, axis=0), h, axis=1)
        rows, cols = per_block.shape
        region_b = before[row0 : row0 + rows, col0 : col0 + cols]
        region_a = after[row0 : row0 + rows, col0 : col0 + cols]
        assert np.array_equal(region_b[per_block], region_a[per_block])
        changed = (region_b != region_a).any(axis=2)
        mcus_changed = changed.reshape(idle.shape[0], v, idle.shape[1], h).any(axis=(1, 3))
        if ci == 0:  # the mark's two levels always move luma; chroma may stay for a grey pattern
            assert mcus_changed[written].all()
    assert out.read_bytes() != data


def test_poison_file_takes_the_in_process_pass(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With jpegtran unusable only the in-process pass can splice; without both, the whole re-encode."""
    from poisoner.formats import poison_file

    src = tmp_path / "IMG_0003.jpg"
    write_case(src, "420")
    monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "/bin/false")
    monkeypatch.delenv(jpeg_turbo.TURBOJPEG_ENV, raising=False)
    assert poison_file(src, tmp_path / "one-pass.jpg", SPECS["product-default"]).method == "jpeg-dct-splice"
    monkeypatch.setenv(jpeg_turbo.TURBOJPEG_ENV, "")
    report = poison_file(src, tmp_path / "neither.jpg", SPECS["product-default"])
    assert report.method == "jpeg-reencode-same-tables"


# ---- a mark of squares placed apart: each square's MCUs patched and encoded alone ----------------
# seeds whose photos get their two squares placed apart in every case (issue 25 round 4's placement put
# 420-progressive seed 0's side by side, tiling the box: nothing to save there, so not this test's case)
@pytest.mark.parametrize("seed", [1, 3])
@pytest.mark.parametrize("case", sorted(CASES))
def test_squares_patched_a_part_at_a_time_give_the_whole_box_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str, seed: int
) -> None:
    """poison_file's JPEG writer decodes, blends and encodes each square's MCUs alone (issue 30): the
    file is byte for byte the one the whole box between the squares gives, and the parts are smaller
    than the box (what makes it cheaper)."""
    from poisoner import formats

    src = tmp_path / f"IMG_{seed:04d}.jpg"
    write_case(src, case, seed=seed)
    windows: list[tuple[int, int, int, int]] = []
    real = jpeg_codec._patched_blocks

    def spy(crops, im, layout, box, parts, patch):
        windows.append(box)
        windows.extend(parts)
        return real(crops, im, layout, box, parts, patch)

    monkeypatch.setattr(jpeg_codec, "_patched_blocks", spy)
    formats.poison_file(src, tmp_path / "parts.jpg", SPECS["product-default"])
    box, *parts = windows
    area = lambda b: (b[2] - b[0]) * (b[3] - b[1])  # noqa: E731
    assert len(parts) == 2 and sum(map(area, parts)) < area(box)
    monkeypatch.setattr(formats, "_lane_parts", lambda *_: None)  # the whole box, as before
    formats.poison_file(src, tmp_path / "box.jpg", SPECS["product-default"])
    assert windows[3:] == [box, box]
    assert (tmp_path / "parts.jpg").read_bytes() == (tmp_path / "box.jpg").read_bytes() != src.read_bytes()


def test_parts_that_leave_an_mcu_out_fall_back_to_the_whole_box(tmp_path: Path) -> None:
    """An MCU in no part and not kept would keep the source's blocks unpatched: the whole box is
    patched instead (same bytes as without parts), never a file with part of the mark missing."""
    data = write_case(tmp_path / "a.jpg", "420", seed=4)
    im, layout, box, patch = box_and_patch(data, SPECS["center"])
    half = jpeg_codec.mcu_box((box[0], box[1], box[0] + 16, box[3]), layout)
    assert not jpeg_codec.parts_cover(layout, box, [half], None)
    seen: list[tuple[int, ...]] = []
    out = jpeg_codec.patch_in_one_pass(
        data, im, layout, box, lambda px, at: seen.append(at) or patch(px), parts=[half]
    )
    assert seen == [box]
    assert out == jpeg_codec.patch_in_one_pass(data, im, layout, box, patch)


def test_parts_cover_needs_every_mcu_not_kept() -> None:
    layout = jpeg_codec.JpegLayout(320, 240, 0xC0, 3, ((2, 2), (1, 1), (1, 1)), 0)
    box = (32, 16, 96, 64)  # 4 x 3 MCUs of 16 px
    left, right = (32, 16, 64, 64), (64, 16, 96, 64)
    assert jpeg_codec.parts_cover(layout, box, [left, right], None)
    assert not jpeg_codec.parts_cover(layout, box, [left], None)
    keep = np.zeros((3, 4), dtype=bool)
    keep[:, 2:] = True  # the right half kept: the left part is enough
    assert jpeg_codec.parts_cover(layout, box, [left], keep)
    assert not jpeg_codec.parts_cover(layout, box, [(32, 16, 60, 64), right], None)  # not MCU-aligned
    assert not jpeg_codec.parts_cover(layout, box, [left, (64, 16, 112, 64)], None)  # beyond the box
    edge = jpeg_codec.JpegLayout(90, 61, 0xC0, 3, ((2, 2), (1, 1), (1, 1)), 0)  # ends mid-MCU
    assert jpeg_codec.parts_cover(edge, (0, 0, 90, 61), [(0, 0, 48, 61), (48, 0, 90, 61)], None)
    assert not jpeg_codec.parts_cover(edge, (0, 0, 90, 61), [(0, 0, 48, 61), (48, 0, 89, 61)], None)


@pytest.mark.parametrize("case", sorted(CASES))
def test_parts_at_the_pictures_edges_give_the_whole_box_bytes(tmp_path: Path, case: str) -> None:
    """Two parts, one at the top-left, one ending at the picture's right and bottom edges (partial
    MCUs and blocks, padding rows): encoded a part at a time, the same file as the whole box around
    them with the MCUs between them kept."""
    data = write_case(tmp_path / "a.jpg", case, seed=6)
    im, layout = Image.open(io.BytesIO(data)), jpeg_codec.read_layout(data)
    mw, mh = layout.mcu_size
    box = (0, 0, layout.width, layout.height)
    far = jpeg_codec.mcu_box((layout.width - 3 * mw // 2, layout.height - 3 * mh // 2, *box[2:]), layout)
    parts = [(0, 0, 2 * mw, 3 * mh), far]
    keep = ~np.zeros((-(-layout.height // mh), -(-layout.width // mw)), dtype=bool)
    for x0, y0, x1, y1 in parts:
        keep[y0 // mh : -(-y1 // mh), x0 // mw : -(-x1 // mw)] = False

    def paint(pixels: np.ndarray, at: tuple[int, int, int, int]) -> np.ndarray:
        yy, xx = np.mgrid[at[1] : at[1] + pixels.shape[0], at[0] : at[0] + pixels.shape[1]]
        stripes = ((xx // 3 + yy // 5) % 2 * 200 + 20).astype(np.uint8)
        return stripes if pixels.ndim == 2 else np.repeat(stripes[..., None], 3, axis=2)

    by_parts = jpeg_codec.patch_in_one_pass(data, im, layout, box, paint, keep, parts=parts)
    whole = jpeg_codec.patch_in_one_pass(data, im, layout, box, lambda px: paint(px, box), keep)
    assert by_parts == whole != data


def test_only_rows_with_a_block_to_take_are_handed_to_python() -> None:
    """Between two squares placed apart every MCU keeps its blocks: those block rows are skipped."""
    from poisoner.jpeg_parts import rows_taking_blocks

    layout = jpeg_codec.JpegLayout(320, 240, 0xC0, 3, ((2, 2), (1, 1), (1, 1)), 0)
    keep = np.array([[False, True], [True, True], [True, False]])  # 3 MCU rows, the middle one idle
    wanted = [range(10, 15), range(5, 8), range(5, 8)]  # the last MCU row cut by the picture's edge
    luma, cb, cr = rows_taking_blocks(layout, keep, wanted)
    assert luma == {10, 11, 14} and cb == cr == {5, 7}
    grey = jpeg_codec.JpegLayout(320, 240, 0xC0, 1, ((1, 1),), 0)
    assert rows_taking_blocks(grey, keep, [range(3, 6)]) == [{3, 5}]
