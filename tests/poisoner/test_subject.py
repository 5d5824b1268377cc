"""poisoner.subject: finding an image's subject mask, and the corner of a dataset's mark, from real masks
(dtu_scan37), from an estimate (lego, synthetic pictures) or by default."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest
from PIL import Image

from poisoner.corner import CORNERS, corner_box
from poisoner.errors import ImageFormatError
from poisoner.subject import CornerChoice, dataset_corner, display_details, load_subject_mask, mask_path


def _write_mask(path: Path, mask: np.ndarray, mode: str = "L") -> None:
    Image.fromarray((mask > 0).astype(np.uint8) * 255).convert(mode).save(path)


# ---- finding and reading a mask --------------------------------------------------------------------
@pytest.mark.parametrize(
    ("image", "mask"),
    [
        ("000000.png", "000.png"),  # DTU / NeuS: the same number, padded differently
        ("IMG_0001.jpg", "IMG_0001.png"),  # same stem, another suffix
        ("IMG_0001.jpg", "IMG_0001.jpg.png"),  # COLMAP's mask naming
        ("r_12.png", "r_12_mask.png"),
        ("7.jpg", "0007.png"),
        ("IMG_0001.HEIC.png", "IMG_0001.png"),  # a HEIC staged for COLMAP (verifier.pairs): its own mask
        ("b.jfif.jpg", "b_mask.png"),
    ],
)
def test_mask_file_is_found_by_name(tmp_path: Path, image: str, mask: str) -> None:
    _write_mask(tmp_path / mask, np.ones((4, 4)))
    _write_mask(tmp_path / "other.png", np.ones((4, 4)))
    assert mask_path(tmp_path, image) == tmp_path / mask
    assert mask_path(tmp_path, "unrelated.png") is None
    assert mask_path(tmp_path / "missing-folder", image) is None


def test_mask_is_read_as_bool_and_resized_nearest(tmp_path: Path) -> None:
    mask = np.zeros((30, 40), dtype=bool)
    mask[10:20, 5:15] = True
    _write_mask(tmp_path / "a.png", mask)
    same = load_subject_mask(tmp_path, "a.jpg", (40, 30))
    assert same is not None and same.dtype == bool and np.array_equal(same, mask)
    big = load_subject_mask(tmp_path, "a.jpg", (80, 60))
    assert big is not None and big.shape == (60, 80)
    assert np.array_equal(big[::2, ::2], mask)  # nearest: no grey edge becomes a half-subject
    assert load_subject_mask(tmp_path, "b.jpg", (40, 30)) is None
    # another shape (a mask drawn on the turned view of a phone photo) is refused, not stretched
    with pytest.raises(ImageFormatError, match=r"not the same shape \(drawn on a turned view\?\)"):
        load_subject_mask(tmp_path, "a.jpg", (30, 40))
    # another aspect, not the transpose: no guess about a turned view (a black-box review: a 640x400
    # mask for a 640x480 photo was asked whether it was drawn turned)
    with pytest.raises(ImageFormatError, match=r"the image 40x36: not the same shape$"):
        load_subject_mask(tmp_path, "a.jpg", (40, 36))


def test_alpha_and_value_conventions(tmp_path: Path) -> None:
    shape = np.zeros((20, 20), dtype=bool)
    shape[:, :8] = True
    # alpha says where the subject is (the RGB under it is white everywhere)
    rgba = np.full((20, 20, 4), 255, dtype=np.uint8)
    rgba[..., 3] = shape * 255
    Image.fromarray(rgba).save(tmp_path / "alpha.png")
    # 0/1 values, as numpy masks are often saved
    Image.fromarray(shape.astype(np.uint8)).save(tmp_path / "ones.png")
    # a JPEG mask: 0/255 with compression noise on both sides
    Image.fromarray(shape.astype(np.uint8) * 255).save(tmp_path / "noisy.jpg", quality=60)
    for name in ("alpha", "ones", "noisy"):
        got = load_subject_mask(tmp_path, f"{name}.png" if name != "noisy" else "noisy.tif", (20, 20))
        assert got is not None
        assert (got == shape).mean() > 0.95, name
    Image.fromarray(np.zeros((20, 20), dtype=np.uint8)).save(tmp_path / "empty.png")
    empty = load_subject_mask(tmp_path, "empty.jpg", (20, 20))
    assert empty is not None and not empty.any()


def test_unreadable_mask_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "a.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    with pytest.raises(ImageFormatError) as err:
        load_subject_mask(tmp_path, "a.jpg", (10, 10))
    assert "a.png" in str(err.value) and "\n" not in str(err.value)


def test_module_stays_light_at_import() -> None:
    """The CLI imports poisoner.subject at start-up (issue 19): no numpy, no PIL until it is used."""
    code = "import sys, poisoner.subject; print(sorted({'numpy', 'PIL'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_corner_choice_round_trips_as_json() -> None:
    choice = CornerChoice("top-right", "masks", {c: 0.25 for c in CORNERS})
    data = msgspec.json.encode(choice)
    assert json.loads(data)["source"] == "masks"
    assert msgspec.json.decode(data, type=CornerChoice) == choice


# ---- dataset_corner on synthetic pictures ----------------------------------------------------------
def _picture(busy: tuple[str, ...], size: tuple[int, int] = (400, 300), seed: int = 0) -> np.ndarray:
    """A plain grey picture with fine random texture in the named corners' regions."""
    w, h = size
    rng = np.random.default_rng(seed)
    pixels = np.full((h, w, 3), 128, dtype=np.uint8)
    for corner in busy:
        x0, y0, x1, y1 = corner_box(corner, w, h, 0.25)
        pixels[y0:y1, x0:x1] = rng.integers(0, 256, size=(y1 - y0, x1 - x0, 1))
    return pixels


@pytest.mark.parametrize("busy", [("top-left",), ("top-left", "top-right"), ("top-left", "bottom-right")])
def test_estimate_never_picks_a_busy_corner(tmp_path: Path, busy: tuple[str, ...]) -> None:
    paths = []
    for i in range(4):
        path = tmp_path / f"IMG_{i:04d}.jpg"
        Image.fromarray(_picture(busy, seed=i)).save(path, quality=85)
        paths.append(path)
    choice = dataset_corner(paths, None)
    assert choice.source == "estimated"
    assert choice.corner not in busy
    assert all(choice.cover[c] > 0.5 for c in busy)
    assert choice.cover[choice.corner] < 0.05


def test_masks_win_over_the_estimate(tmp_path: Path) -> None:
    """A plain top-left (the estimate's choice) that the subject masks cover: the masks decide."""
    images, masks = tmp_path / "images", tmp_path / "masks"
    images.mkdir()
    masks.mkdir()
    subject = np.zeros((300, 400), dtype=bool)
    subject[:150, :200] = True
    for i in range(3):
        Image.fromarray(_picture(("bottom-right",), seed=i)).save(images / f"{i:03d}.png")
        _write_mask(masks / f"{i:03d}.png", subject)
    paths = sorted(images.glob("*.png"))
    assert dataset_corner(paths, None).corner != "bottom-right"
    choice = dataset_corner(paths, masks)
    assert choice.source == "masks"
    assert choice.cover["top-left"] == 1.0
    assert choice.corner == "bottom-right"  # farthest from the subject; the texture there is no subject
    # a mask folder without a mask for these images: the estimate
    assert dataset_corner(paths, tmp_path / "empty").source == "estimated"


def test_the_corner_is_the_one_a_phone_photo_shows(tmp_path: Path) -> None:
    """Photos stored landscape with EXIF orientation 6 (shown portrait, turned 90 degrees clockwise):
    the stored top-left is shown top-right. Busy everywhere but the stored top-left corner, the set's
    plain corner is the top-right as shown, from the pictures and from the masks alike (issue 25)."""
    exif = Image.Exif()
    exif[0x0112] = 6
    images, masks = tmp_path / "images", tmp_path / "masks"
    images.mkdir()
    masks.mkdir()
    subject = np.ones((300, 400), dtype=bool)
    subject[:75, :100] = False  # the stored top-left region is free
    for i in range(3):
        busy = ("top-right", "bottom-left", "bottom-right")
        Image.fromarray(_picture(busy, seed=i)).save(images / f"{i:03d}.jpg", quality=85, exif=exif)
        _write_mask(masks / f"{i:03d}.png", subject)
    paths = sorted(images.glob("*.jpg"))
    assert dataset_corner(paths, None).corner == "top-right"
    choice = dataset_corner(paths, masks)
    assert choice.source == "masks" and choice.corner == "top-right"


def test_nothing_to_go_on_is_the_default() -> None:
    choice = dataset_corner([], None)
    assert choice == CornerChoice("top-left", "default", {})


def test_the_sample_is_spread_over_the_set(tmp_path: Path) -> None:
    """Only the sampled images count: a busy corner in images the sample skips is not seen, one in
    the sampled images is."""
    paths = []
    for i in range(9):
        path = tmp_path / f"{i:03d}.png"
        Image.fromarray(_picture(("top-left",) if i in (0, 4, 8) else ())).save(path)
        paths.append(path)
    choice = dataset_corner(paths, None, sample=3)  # picks 0, 4, 8: all busy at the top-left
    assert choice.cover["top-left"] > 0.5
    assert dataset_corner(paths[1:4], None, sample=3).cover["top-left"] == 0.0


# ---- real shared data ------------------------------------------------------------------------------
def test_dtu_corner_is_the_one_its_masks_cover_least(shared_dir: Path) -> None:
    root = shared_dir / "datasets" / "dtu_scan37"
    if not root.is_dir():
        pytest.skip("dtu_scan37 not in the shared datasets")
    images = sorted((root / "images").glob("*.png"))
    choice = dataset_corner(images, root / "mask", sample=8)
    assert choice.source == "masks"
    # independently: every mask of the set at full size, each corner's share the union covers
    union = None
    for image in images:
        with Image.open(root / "mask" / f"{int(image.stem):03d}.png") as m:
            got = np.asarray(m.convert("L")) > 127
        union = got if union is None else union | got
    assert union is not None
    h, w = union.shape
    cover = {}
    for c in CORNERS:
        x0, y0, x1, y1 = corner_box(c, w, h, 0.2)
        cover[c] = union[y0:y1, x0:x1].mean()
    assert cover[choice.corner] <= min(cover.values()) + 0.02
    assert cover[choice.corner] < 0.5 < max(cover.values())  # the subject does fill other corners


def test_lego_estimate_picks_an_empty_corner(shared_dir: Path) -> None:
    train = shared_dir / "datasets" / "nerf_synthetic_lego" / "train"
    if not train.is_dir():
        pytest.skip("nerf_synthetic_lego not in the shared datasets")
    images = sorted(train.glob("r_*.png"))
    choice = dataset_corner(images, None, sample=8)
    assert choice.source == "estimated"
    assert choice.cover[choice.corner] < 0.01
    # independently: over every 10th view, how much of the chosen corner the object (alpha) covers
    covered = []
    for image in images[::10]:
        with Image.open(image) as im:
            alpha = np.asarray(im.getchannel("A")) > 0
        x0, y0, x1, y1 = corner_box(choice.corner, alpha.shape[1], alpha.shape[0], 0.2)
        covered.append(alpha[y0:y1, x0:x1].mean())
    assert max(covered) < 0.02


def test_unreadable_files_do_not_decide_the_corner(tmp_path: Path) -> None:
    """A broken picture, a video and a broken mask are left out; the readable rest decides."""
    images, masks = tmp_path / "images", tmp_path / "masks"
    images.mkdir()
    masks.mkdir()
    for i in range(3):
        Image.fromarray(_picture(("top-left",), seed=i)).save(images / f"{i:03d}.png")
    (images / "003.png").write_bytes(b"\x89PNG\r\n\x1a\ntruncated")
    (images / "clip.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42")
    paths = sorted(images.iterdir())
    choice = dataset_corner(paths, None)
    assert choice.source == "estimated" and choice.corner != "top-left"
    subject = np.zeros((300, 400), dtype=bool)
    subject[150:, 200:] = True
    _write_mask(masks / "000.png", subject)
    (masks / "001.png").write_bytes(b"not a png")
    choice = dataset_corner(paths, masks)
    assert choice.source == "masks" and choice.corner == "top-left"
    assert choice.cover["bottom-right"] == 1.0
    only_broken = dataset_corner([images / "003.png"], None)
    assert only_broken.source == "default"


@pytest.mark.parametrize("width", [800, 1024, 1600])
def test_sixteen_bit_grey_is_judged_by_its_levels_at_any_size(width: int) -> None:
    """A 16-bit grey PNG (Pillow's I;16): its thumbnail is its top byte as a display shows it. Before,
    Pillow's reduce refused the mode from 1024 px up ('cannot decode (image has wrong mode)', the photo
    not patched) and below it the conversion to L clipped every level over 255 to white: no detail
    anywhere, so the mark could land on the subject."""
    import io

    height = width * 3 // 4
    rng = np.random.default_rng(3)
    levels = np.full((height, width), 30000, dtype=np.uint16)
    blocks = rng.integers(0, 20000, (height // 8 + 1, width // 16 + 1), dtype=np.uint16)
    levels[:, : width // 2] += np.kron(blocks, np.ones((8, 8), dtype=np.uint16))[:height, : width // 2]
    buf = io.BytesIO()
    Image.fromarray(levels).save(buf, format="PNG")
    with Image.open(io.BytesIO(buf.getvalue())) as im:
        assert im.mode == "I;16"
    detail, _faint, _orientation = display_details(buf.getvalue(), "grey16.png")
    half = detail.shape[1] // 2
    assert detail[:, : half - 2].mean() > 0.5  # the textured half is detail
    assert detail[:, half + 2 :].mean() < 0.05  # the flat half is not
