"""poison_file(..., keep_out=): every format, real files. A keep-out mask (a subject mask) over half of
the mark: the masked pixels are left as they were, the other half carries the mark, nothing outside
the mark's box changes. JPEG keeps whole MCUs (and their coefficients) near a kept-out pixel."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner import jpeg as jpeg_codec
from poisoner import jpeg_turbo
from poisoner.blend import patch_coverage
from poisoner.formats import ImageFormatError, poison_file, poison_in_place
from poisoner.image.keep_out import grow
from poisoner.spec import PatchSpec

W, H = 160, 128
# A 64 px mark at (16, 16)..(80, 80): MCU-aligned on every sampling, so the halves are exact.
SPEC = PatchSpec(patch_size=64, block_size=8, offset=(16, 16))
MARK = (16, 16, 80, 80)
SPLIT = 48  # keep_out covers x < SPLIT: the mark's left half


def photo(h: int = H, w: int = W, channels: int = 3, seed: int = 0) -> np.ndarray:
    """A smooth, photo-like picture (JPEG codes it like a photo, not like noise)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(40, 216, size=(h // 8 + 1, w // 8 + 1, channels)).astype(np.uint8)
    big = Image.fromarray(small if channels > 1 else small[..., 0]).resize((w, h), Image.Resampling.BICUBIC)
    return np.asarray(big)


def left_half_mask(h: int = H, w: int = W) -> np.ndarray:
    mask = np.zeros((h, w), dtype=np.uint8)
    mask[:, :SPLIT] = 255  # the subject fills the left of the picture, the mark's left half included
    return mask


def pixels(path: Path, mode: str | None = None) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert(mode) if mode else im).astype(np.int64)


def halves(diff: np.ndarray, ring: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(masked half of the mark, unmasked half of the mark, everything outside the mark's box grown
    by `ring` px)."""
    x0, y0, x1, y1 = MARK
    outside = np.ones(diff.shape[:2], dtype=bool)
    outside[y0 - ring : y1 + ring, x0 - ring : x1 + ring] = False
    return diff[y0:y1, x0:SPLIT], diff[y0:y1, SPLIT:x1], diff[outside]


def assert_exact_halves(src: np.ndarray, out: np.ndarray, written_from: int = SPLIT, ring: int = 0) -> None:
    """Lossless writers: masked half identical, unmasked half carries the mark, outside identical
    (a JPEG: outside the one-pixel ring that chroma upsampling reaches)."""
    diff = np.abs(out.astype(np.int64) - src.astype(np.int64))
    masked, unmasked, outside = halves(diff, ring)
    assert masked.max() == 0
    assert outside.max() == 0
    written = diff[MARK[1] : MARK[3], written_from : MARK[2]]
    assert (written.reshape(written.shape[0], written.shape[1], -1).max(axis=-1) > 0).mean() > 0.5
    assert unmasked.max() > 0


def assert_lossy_halves(src: np.ndarray, out: np.ndarray) -> None:
    """Re-encoded writers: the masked half only carries the codec's noise, the other half the mark."""
    diff = np.abs(out.astype(np.int64) - src.astype(np.int64))
    masked, unmasked, _ = halves(diff)
    assert masked.mean() < 6, masked.mean()
    assert unmasked.mean() > 40, unmasked.mean()


# ---- lossless writers -----------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["L", "RGB", "RGBA", "I;16", "P"])
def test_png_keep_out_half(tmp_path: Path, mode: str) -> None:
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    base = photo()
    im = Image.fromarray(base)
    if mode == "RGBA":
        im = Image.fromarray(np.dstack([base, np.full((H, W), 255, np.uint8)]))
    elif mode == "I;16":
        im = Image.fromarray(base[..., 0].astype(np.uint16) * 257)
    elif mode != "RGB":
        im = im.convert(mode)
    im.save(src)
    report = poison_file(src, dst, SPEC, keep_out=left_half_mask())
    assert "keep-out mask: 50% of the mark's pixels left unwritten" in report.notes
    as_mode = "RGB" if mode == "P" else None
    assert_exact_halves(pixels(src, as_mode), pixels(dst, as_mode))


@pytest.mark.parametrize("channels", [3, 4])
def test_png_16bit_colour_keep_out_half(tmp_path: Path, channels: int) -> None:
    from poisoner.image.png import _decode_png16_colour, _encode_png16_colour

    base = photo(channels=channels).astype(np.uint16) * 257
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    src.write_bytes(_encode_png16_colour(base))
    poison_file(src, dst, SPEC, keep_out=left_half_mask())
    out = _decode_png16_colour(dst.read_bytes(), 2 if channels == 3 else 6)
    assert_exact_halves(base, out)


@pytest.mark.parametrize(("mode", "compression"), [("RGB", "tiff_lzw"), ("RGB", "raw"), ("I;16", "raw")])
def test_tiff_keep_out_half(tmp_path: Path, mode: str, compression: str) -> None:
    src, dst = tmp_path / "a.tif", tmp_path / "out.tif"
    base = photo()
    im = Image.fromarray(base) if mode == "RGB" else Image.fromarray(base[..., 0].astype(np.uint16) * 257)
    im.save(src, "TIFF", compression=compression)
    poison_file(src, dst, SPEC, keep_out=left_half_mask())
    assert_exact_halves(pixels(src), pixels(dst))


def test_webp_lossless_keep_out_half(tmp_path: Path) -> None:
    src, dst = tmp_path / "a.webp", tmp_path / "out.webp"
    Image.fromarray(photo()).save(src, "WEBP", lossless=True)
    poison_file(src, dst, SPEC, keep_out=left_half_mask())
    assert_exact_halves(pixels(src, "RGB"), pixels(dst, "RGB"))


# ---- re-encoding writers --------------------------------------------------------------------------
@pytest.mark.parametrize(("fmt", "suffix"), [("WEBP", ".webp"), ("HEIF", ".heic"), ("AVIF", ".avif")])
def test_lossy_keep_out_half(tmp_path: Path, fmt: str, suffix: str) -> None:
    import pillow_heif

    pillow_heif.register_heif_opener()
    src, dst = tmp_path / f"a{suffix}", tmp_path / f"out{suffix}"
    Image.fromarray(photo()).save(src, fmt, quality=90)
    poison_file(src, dst, SPEC, keep_out=left_half_mask())
    assert_lossy_halves(pixels(src, "RGB"), pixels(dst, "RGB"))


# ---- JPEG -----------------------------------------------------------------------------------------
needs_jpegtran = pytest.mark.skipif(
    jpeg_codec.jpegtran_binary() is None, reason="jpegtran not installed (libjpeg-turbo-progs)"
)
needs_turbo = pytest.mark.skipif(jpeg_codec.turbo_available() is not None, reason="no libturbojpeg here")

JPEG_CASES = {
    "420": {"subsampling": 2},
    "444": {"subsampling": 0},
    "422": {"subsampling": 1},
    "grey": {"grey": True},
    "progressive": {"subsampling": 2, "progressive": True},
    "restart": {"subsampling": 2, "restart_marker_blocks": 4},  # tjTransform refuses it: jpegtran path
}


def write_jpeg(path: Path, case: str, h: int = H, w: int = W) -> np.ndarray:
    opts = dict(JPEG_CASES[case])
    im = Image.fromarray(photo(h, w))
    if opts.pop("grey", False):
        im = im.convert("L")
    im.save(path, "JPEG", quality=90, **opts)
    return pixels(path)


def blocks(path_or_bytes: Path | bytes) -> list[np.ndarray]:
    data = path_or_bytes.read_bytes() if isinstance(path_or_bytes, Path) else path_or_bytes
    return jpeg_turbo.read_blocks(data)


@needs_jpegtran
@pytest.mark.parametrize("case", sorted(JPEG_CASES))
def test_jpeg_splice_keep_out_half(tmp_path: Path, case: str) -> None:
    """Masked MCUs (and those within the chroma upsampling's reach of the mask) are not written:
    the masked half decodes to the very same pixels; the splice re-encodes only MCUs the mark writes."""
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    before = write_jpeg(src, case)
    report = poison_file(src, dst, SPEC, keep_out=left_half_mask())
    assert report.method == "jpeg-dct-splice"
    layout = jpeg_codec.read_layout(src.read_bytes())
    mw = layout.mcu_size[0]
    # the first MCU column the mark may write: past the mask, plus one MCU when chroma is upsampled
    first = SPLIT + (mw if mw > 8 and layout.components == 3 else 0)
    after = pixels(dst)
    assert_exact_halves(before, after, written_from=first, ring=1)
    assert f"({first}, 16, 80, 80)" in " ".join(report.notes)  # the splice box starts past the mask


@needs_jpegtran
@needs_turbo
def test_jpeg_splice_keeps_the_coefficients_of_masked_mcus(tmp_path: Path) -> None:
    """'Only the box's MCUs change' still holds with a mask, and the box shrinks to the MCUs written."""
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    write_jpeg(src, "420")
    poison_file(src, dst, SPEC, keep_out=left_half_mask())
    for ci, (a, b) in enumerate(zip(blocks(src), blocks(dst), strict=True)):
        px = 8 if ci == 0 else 16  # 4:2:0: a luma block covers 8 px, a chroma block 16
        ys, xs = np.nonzero((a != b).any(axis=-1))  # changed blocks (rows, columns)
        assert ys.size, f"component {ci} unchanged"
        # only the MCUs the mark writes: x 64..80 (past the mask and its upsampling reach), y 16..80
        assert xs.min() * px >= 64 and (xs.max() + 1) * px <= 80
        assert ys.min() * px >= 16 and (ys.max() + 1) * px <= 80


def diagonal_mask(h: int = H, w: int = W) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    return (xx + yy < 110).astype(np.uint8)  # the subject reaches diagonally into the mark's box


@needs_jpegtran
@needs_turbo
@pytest.mark.parametrize("case", ["420", "444", "progressive"])
def test_jpeg_diagonal_mask_exact_in_process(tmp_path: Path, case: str) -> None:
    """A mask that leaves MCUs inside the splice box unwritten: the in-process pass copies their
    coefficients, so every masked pixel decodes exactly as before."""
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    before = write_jpeg(src, case)
    mask = diagonal_mask()
    report = poison_file(src, dst, SPEC, keep_out=mask)
    after = pixels(dst)
    diff = np.abs(after - before).reshape(H, W, -1).max(axis=-1)
    assert diff[mask > 0].max() == 0
    assert any("coefficients copied" in n for n in report.notes)
    x0, y0, x1, y1 = MARK
    free = np.zeros((H, W), dtype=bool)
    free[y0:y1, x0:x1] = True
    free &= ~grow(mask > 0, 17, 17)
    assert (diff[free] > 0).mean() > 0.5  # far from the mask the mark is there
    outside = np.ones((H, W), dtype=bool)
    outside[y0:y1, x0:x1] = False
    assert diff[outside & ~_ring(MARK)].max() == 0


@needs_jpegtran
@needs_turbo
@pytest.mark.parametrize("size", [(165, 133), (171, 140)])
@pytest.mark.parametrize("subsampling", [0, 1, 2])
def test_jpeg_diagonal_mask_at_a_partial_mcu_edge(
    tmp_path: Path, size: tuple[int, int], subsampling: int
) -> None:
    """A bottom-right mark on a picture whose size is no multiple of the MCU, a mask cutting across
    it: the partial MCUs at the edge keep their coefficients like any other masked MCU."""
    w, h = size
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    Image.fromarray(photo(h, w)).save(src, quality=90, subsampling=subsampling)
    yy, xx = np.mgrid[0:h, 0:w]
    mask = (xx + yy > w + h - 70) & (xx - yy > w - h - 20)
    spec = PatchSpec(patch_size=60, block_size=6, position="bottom-right")
    report = poison_file(src, dst, spec, keep_out=mask)
    diff = np.abs(pixels(dst) - pixels(src)).max(axis=-1)
    assert diff[mask].max() == 0
    assert (diff > 0).sum() > 1000
    assert any("coefficients copied" in n for n in report.notes)


def _ring(box: tuple[int, int, int, int], by: int = 1) -> np.ndarray:
    """The one-pixel ring around a box that fancy upsampling may touch."""
    x0, y0, x1, y1 = box
    ring = np.zeros((H, W), dtype=bool)
    ring[max(0, y0 - by) : y1 + by, max(0, x0 - by) : x1 + by] = True
    ring[y0:y1, x0:x1] = False
    return ring


@needs_jpegtran
@needs_turbo
@pytest.mark.parametrize("route", ["restart", "optimised", "whole-decode"])
def test_jpeg_diagonal_mask_exact_through_jpegtran(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, route: str
) -> None:
    """Sources the in-process pass refuses (restart markers, optimised Huffman tables) and the
    whole-decode route go through jpegtran's drop: the masked MCUs inside the box still keep the
    source's coefficients (the drop file gets them back before the drop)."""
    import poisoner.formats as formats

    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    im = Image.fromarray(photo())
    if route == "restart":
        im.save(src, "JPEG", quality=90, restart_marker_blocks=4)
    else:
        im.save(src, "JPEG", quality=90, optimize=route == "optimised")
    if route == "whole-decode":
        monkeypatch.setattr(formats, "JPEG_REGION_DECODE", False)
    before = pixels(src)
    mask = diagonal_mask()
    report = poison_file(src, dst, SPEC, keep_out=mask)
    assert report.method == "jpeg-dct-splice"
    assert any("coefficients copied" in n for n in report.notes)
    diff = np.abs(pixels(dst) - before).max(axis=-1)
    assert diff[mask > 0].max() == 0
    assert diff[MARK[1] : MARK[3], MARK[0] : MARK[2]].max() > 100


@needs_jpegtran
@needs_turbo
@pytest.mark.parametrize("case", ["420", "progressive"])
def test_jpeg_masked_splice_same_bytes_either_way(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """With masked MCUs inside the box, the in-process pass and jpegtran's drop still write one file."""
    src = tmp_path / "a.jpg"
    write_jpeg(src, case)
    poison_file(src, tmp_path / "one-pass.jpg", SPEC, keep_out=diagonal_mask())

    def refuse(*_args: object, **_kw: object) -> bytes:
        raise jpeg_codec.SpliceUnavailable("test: in-process pass off")

    monkeypatch.setattr(jpeg_codec, "patch_in_one_pass", refuse)
    poison_file(src, tmp_path / "jpegtran.jpg", SPEC, keep_out=diagonal_mask())
    one_pass, dropped = (tmp_path / "one-pass.jpg").read_bytes(), (tmp_path / "jpegtran.jpg").read_bytes()
    assert one_pass == dropped != src.read_bytes()


@needs_jpegtran
def test_jpeg_diagonal_mask_jpegtran_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without the in-process pass, unwritten MCUs inside the box are re-encoded from their own
    pixels: the masked pixels move by the codec's rounding only, never by the mark."""
    monkeypatch.setenv(jpeg_turbo.TURBOJPEG_ENV, "")
    monkeypatch.setenv("PPD_JPEG_SCAN", "")  # nor the bit-level splice
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    before = write_jpeg(src, "420")
    mask = diagonal_mask()
    report = poison_file(src, dst, SPEC, keep_out=mask)
    assert report.method == "jpeg-dct-splice"
    assert any("re-encoded from their own pixels" in n for n in report.notes)
    diff = np.abs(pixels(dst) - before).max(axis=-1)
    assert diff[mask > 0].max() <= 8
    x0, y0, x1, y1 = MARK
    assert diff[y0:y1, x0:x1].max() > 100  # the mark is there off the mask


@pytest.mark.parametrize("case", ["420", "grey"])
def test_jpeg_reencode_fallback_keeps_the_mask(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """No splice at all (PPD_JPEGTRAN=""): the whole picture is re-encoded, the mark still off the mask."""
    monkeypatch.setenv(jpeg_codec.JPEGTRAN_ENV, "")
    src, dst = tmp_path / "a.jpg", tmp_path / "out.jpg"
    before = write_jpeg(src, case)
    report = poison_file(src, dst, SPEC, keep_out=left_half_mask())
    assert report.method == "jpeg-reencode-same-tables"
    assert_lossy_halves(before, pixels(dst))


@pytest.mark.parametrize("name", ["a.jpg", "a.png"])
def test_mask_over_the_whole_mark_is_a_failure_not_a_patched_file(tmp_path: Path, name: str) -> None:
    """Issue 25: a mark the mask erases whole would leave the file unprotected; that is a failure
    (one line, nothing written), never a "patched" file identical to its original."""
    from poisoner.errors import MarkNotWritten

    src, dst = tmp_path / name, tmp_path / f"out{Path(name).suffix}"
    if name.endswith(".jpg"):
        write_jpeg(src, "420")
    else:
        Image.fromarray(photo()).save(src)
    full = np.ones((H, W), dtype=bool)
    with pytest.raises(MarkNotWritten, match="no pixel would change: not patched"):
        poison_file(src, dst, SPEC, keep_out=full, keep_location=True)
    assert not dst.exists()


@pytest.mark.parametrize("size", [(40, 30), (64, 48)])
def test_a_mark_that_matches_the_photo_is_a_failure_not_a_patched_file(
    tmp_path: Path, size: tuple[int, int]
) -> None:
    """Found on an installed ppd: a small photo, black where the default mark went, whose one-block
    squares were black too, came out pixel-identical and was called "patched". No mask is involved:
    the mark would change no pixel, so the file fails (one line) and nothing is written."""
    from poisoner.errors import MarkNotWritten
    from poisoner.ladder import default_spec

    src, dst = tmp_path / "black.png", tmp_path / "out.png"
    Image.fromarray(np.zeros((size[1], size[0], 3), dtype=np.uint8)).save(src)
    with pytest.raises(MarkNotWritten, match="match the photo's pixels .* no pixel would change"):
        poison_file(src, dst, default_spec())
    assert not dst.exists()
    Image.fromarray(np.full((size[1], size[0], 3), 128, dtype=np.uint8)).save(src)  # grey: it shows
    report = poison_file(src, dst, default_spec())
    assert (np.asarray(Image.open(dst)) != 128).any() and report.written > 0


def test_a_jpeg_whose_mark_changes_no_coefficient_is_a_failure_not_a_patched_file(tmp_path: Path) -> None:
    """A black-box review: `ppd poison --alpha 0.001` on a JPEG said "patched" with the coded picture
    byte for byte the source's (a PNG already failed). The splice's scan is compared with the source's."""
    from poisoner.errors import MarkNotWritten
    from poisoner.ladder import default_spec

    src, dst = tmp_path / "white.jpg", tmp_path / "out.jpg"
    Image.new("RGB", (640, 480), (255, 255, 255)).save(src, quality=90)
    with pytest.raises(MarkNotWritten, match="too faint to change any pixel"):
        poison_file(src, dst, default_spec().replace(alpha=0.001))
    assert not dst.exists()
    report = poison_file(src, dst, default_spec())  # the default's alpha: it shows
    assert (np.asarray(Image.open(dst)) != np.asarray(Image.open(src))).any() and report.written > 0
    trailed = tmp_path / "trailer.jpg"  # bytes after the picture's end, which ppd does not write
    trailed.write_bytes(src.read_bytes() + b"SAMSUNG-TRAILER" * 8)
    with pytest.raises(MarkNotWritten, match="too faint to change any pixel"):
        poison_file(trailed, tmp_path / "out2.jpg", default_spec().replace(alpha=0.001))


def test_changes_a_pixel_is_false_only_where_the_mark_is_already_there() -> None:
    """The check behind the failure above: a photo that already holds the mark's exact pixels in the
    square's box changes nowhere; the photo itself does, and a mask over the changed pixels hides it."""
    from poisoner.blend import apply_patch_at
    from poisoner.image.write import changes_a_pixel

    square = SPEC.resolve(W, H)
    before = photo()
    painted = apply_patch_at(before, square, (0, 0))
    assert changes_a_pixel(Image.fromarray(before), [square], None)
    assert not changes_a_pixel(Image.fromarray(painted), [square], None)
    changed = (painted != before).any(axis=2)
    assert changed.any()
    assert not changes_a_pixel(Image.fromarray(before), [square], changed)


def test_mask_reaching_every_mcu_of_the_mark_is_a_failure(tmp_path: Path) -> None:
    """A JPEG mask that leaves mark pixels free but touches every MCU of the mark: still no pixel
    changes (whole MCUs near the mask are kept), so still a failure."""
    from poisoner.errors import MarkNotWritten

    src = tmp_path / "a.jpg"
    write_jpeg(src, "420")
    grid = np.zeros((H, W), dtype=bool)
    grid[::8, ::8] = True  # one pixel in every 8x8 block
    with pytest.raises(MarkNotWritten):
        poison_file(src, tmp_path / "out.jpg", SPEC, keep_out=grid)
    assert not (tmp_path / "out.jpg").exists()


@needs_jpegtran
def test_no_mask_gives_the_same_bytes_as_an_empty_mask_splice_box(tmp_path: Path) -> None:
    """An all-clear mask changes nothing: the same file as without one (JPEG and PNG)."""
    write_jpeg(tmp_path / "a.jpg", "420")
    Image.fromarray(photo()).save(tmp_path / "a.png")
    for name in ("a.jpg", "a.png"):
        src = tmp_path / name
        poison_file(src, tmp_path / f"none-{name}", SPEC)
        poison_file(src, tmp_path / f"clear-{name}", SPEC, keep_out=np.zeros((H, W), dtype=bool))
        assert (tmp_path / f"none-{name}").read_bytes() == (tmp_path / f"clear-{name}").read_bytes()


@needs_jpegtran
def test_turned_mark_with_mask_on_a_camera_sized_jpeg(tmp_path: Path) -> None:
    """A corner mark that turns (tumble), a mask across it, an MCU box that is not at the origin."""
    spec = PatchSpec(patch_size=0.05, block_size=4, motion="tumble", position="bottom-right")
    h, w = 600, 800
    src, dst = tmp_path / "IMG_0007.jpg", tmp_path / "out.jpg"
    before = write_jpeg(src, "420", h, w)
    placement = spec.resolve(w, h, image_key=src.name)
    x0, y0, x1, y1 = placement.box
    mask = np.zeros((h, w), dtype=bool)
    mask[:, : (x0 + x1) // 2] = True  # the subject reaches to the mark's middle
    poison_file(src, dst, spec, keep_out=mask)
    diff = np.abs(pixels(dst) - before).max(axis=-1)
    assert diff[mask].max() == 0
    assert diff[y0:y1, (x0 + x1) // 2 + 17 : x1].max() > 100


# ---- errors and options ---------------------------------------------------------------------------
@pytest.mark.parametrize("shape", [(H, W + 1), (H - 8, W), (W, H), (H, W, 3), (H,)])
def test_wrong_sized_mask_is_one_line_and_writes_nothing(tmp_path: Path, shape: tuple[int, ...]) -> None:
    src, dst = tmp_path / "a.png", tmp_path / "out.png"
    Image.fromarray(photo()).save(src)
    with pytest.raises(ImageFormatError) as err:
        poison_file(src, dst, SPEC, keep_out=np.zeros(shape, dtype=bool))
    assert "\n" not in str(err.value) and "keep-out mask" in str(err.value) and "160x128" in str(err.value)
    assert not dst.exists()


def test_poison_in_place_passes_keep_out_on(tmp_path: Path) -> None:
    path = tmp_path / "a.png"
    Image.fromarray(photo()).save(path)
    original = pixels(path)
    kept = tmp_path / "copy.png"
    shutil.copy(path, kept)
    poison_in_place(path, SPEC, keep_out=left_half_mask())
    assert_exact_halves(original, pixels(path))
    with pytest.raises(ImageFormatError):
        poison_in_place(kept, SPEC, keep_out=np.zeros((3, 3), dtype=bool))
    assert np.array_equal(pixels(kept), original)  # the failed call left the file as it was


# ---- real data: dtu_scan37 with its subject masks, through the file path ----------------------------
@needs_jpegtran
@pytest.mark.parametrize("suffix", [".png", ".jpg"])
@pytest.mark.parametrize(("corner", "view"), [("chosen", 6), ("top-right", 2)])
def test_dtu_photo_mark_stays_off_its_subject(
    shared_dir: Path, tmp_path: Path, suffix: str, corner: str, view: int
) -> None:
    """A real photo and its real mask, the lanes watermark: in the corner chosen from the set's masks,
    and in the top-right, where view 2's subject covers about half of the mark. No changed pixel on
    the subject; every change inside the one corner region."""
    from poisoner.corner import corner_box
    from poisoner.ladder import WATERMARK_LANES_SPEC
    from poisoner.subject import dataset_corner, load_subject_mask

    root = shared_dir / "datasets" / "dtu_scan37"
    if not root.is_dir():
        pytest.skip("dtu_scan37 not in the shared datasets")
    images = sorted((root / "images").glob("*.png"))
    if corner == "chosen":
        corner = dataset_corner(images, root / "mask").corner
    spec = WATERMARK_LANES_SPEC.replace(position=corner)
    src = tmp_path / f"{images[view].stem}{suffix}"
    with Image.open(images[view]) as im:
        im.convert("RGB").save(src, **({"quality": 92} if suffix == ".jpg" else {}))
        w, h = im.size
    mask = load_subject_mask(root / "mask", images[view].name, (w, h))
    assert mask is not None and mask.any()
    if view == 2:  # without the mask the mark would cover the subject here
        placement = spec.resolve(w, h, image_key=src.name)
        bx0, by0, bx1, by1 = placement.box
        assert (patch_coverage(placement) & mask[by0:by1, bx0:bx1]).mean() > 0.1
    dst = tmp_path / f"out{suffix}"
    poison_file(src, dst, spec, keep_out=mask)
    changed = (pixels(dst) != pixels(src)).any(axis=-1)
    assert changed.sum() > 0.001 * changed.size  # the mark is there
    assert not (changed & mask).any()
    x0, y0, x1, y1 = corner_box(corner, w, h, 0.2)
    ring = 1 if suffix == ".jpg" else 0  # chroma upsampling's one-pixel reach
    changed[max(0, y0 - ring) : y1 + ring, max(0, x0 - ring) : x1 + ring] = False
    assert not changed.any()
