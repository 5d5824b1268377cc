"""Where a dataset's subject is, so a corner mark stays off it (issue 14).

Two sources, best first:
- subject masks: one file per image in a mask folder (white / nonzero / opaque = subject), the DTU,
  NeuS and IDR convention. `load_subject_mask` finds an image's mask by name and reads it at the
  image's size; `dataset_corner` picks the corner the union of a sample of the set's masks covers
  least (poisoner.corner.choose_corner).
- no masks: a cheap estimate. A subject carries the picture's detail; a plain backdrop, sky, floor
  or table does not. On a ~256 px thumbnail of up to `sample` images, each corner region's share of
  pixels with visible detail (gradient above DETAIL_LEVEL levels per thumbnail pixel) is averaged
  over the images; the corner with the least detail wins (ties: the lower mean gradient).

numpy and PIL are imported inside the functions: the CLI imports this module at start-up.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec

from poisoner.errors import ImageFormatError
from poisoner.media import IMAGE_SUFFIXES, SFM_SUFFIXES

if TYPE_CHECKING:
    import numpy as np
    from PIL import Image

log = logging.getLogger(__name__)

THUMBNAIL_PX = 256  # longest side of the picture the estimate looks at
DETAIL_LEVEL = 6.0  # gradient magnitude (8-bit levels per thumbnail pixel) that counts as detail
# Issue 25, round 7: faint detail (a photo of pavement on a subject's face, beside real pavement), what
# per-photo placement checks a plain place against (poisoner.placement.FAINT_DOUBT), never what it
# calls detail
FAINT_LEVEL = 3.0
MASK_GRID = (256, 256)  # (w, h): masks of differently sized images compared on one grid
# what a mask file may be: any image ppd or COLMAP reads (COLMAP's own masks are PNG: tried first)
_MASK_SUFFIXES = (".png", *sorted((IMAGE_SUFFIXES | SFM_SUFFIXES) - {".png"}))


class CornerChoice(msgspec.Struct, frozen=True):
    """The corner of a dataset's mark and why: `source` is "masks" (the set's subject masks),
    "estimated" (least image detail) or "default" (nothing to go on). `cover`: each corner's share
    covered by the subject (masks) or holding detail (estimated), 0..1."""

    corner: str
    source: str
    cover: dict[str, float] = msgspec.field(default_factory=dict)


def mask_path(mask_dir: Path, image_name: str) -> Path | None:
    """The mask file for an image: the same stem with any image suffix (`a.jpg` -> `a.png`), COLMAP's
    `<name>.png` (`a.jpg.png`), `<stem>_mask.*`, or, for a numbered name, the same number however
    zero-padded (DTU: `mask/000.png` for `image/000000.png`). None when there is none. A name the
    verification staged with a suffix added (`a.heic.png`, `a.jfif.jpg`: verifier.pairs) finds the
    photo's own mask (`a.png`) too."""
    stem = Path(image_name).stem
    candidates = [mask_dir / f"{image_name}.png"]
    photo = Path(stem).stem if Path(stem).suffix.lower() in IMAGE_SUFFIXES else stem
    for base in dict.fromkeys((stem, f"{stem}_mask", photo, f"{photo}_mask")):
        candidates += [mask_dir / f"{base}{suffix}" for suffix in _MASK_SUFFIXES]
    for path in candidates:
        if path.is_file():
            return path
    if stem.isdigit() and mask_dir.is_dir():
        return _numbered_masks(str(mask_dir), mask_dir.stat().st_mtime_ns).get(int(stem))
    return None


@functools.lru_cache(maxsize=8)
def _numbered_masks(mask_dir: str, _mtime_ns: int) -> dict[int, Path]:
    """Number -> mask file of a folder's numbered masks (first by name wins), listed once per
    folder state (the folder's mtime is part of the key), not once per image."""
    found: dict[int, Path] = {}
    for path in sorted(Path(mask_dir).iterdir()):
        if path.suffix.lower() in _MASK_SUFFIXES and path.stem.isdigit():
            found.setdefault(int(path.stem), path)
    return found


def load_subject_mask(
    mask_dir: Path, image_name: str, size: tuple[int, int], *, same_shape: bool = True
) -> np.ndarray | None:
    """The subject mask of `image_name` as a bool H x W array at `size` (w, h): True = subject.

    Read from the alpha channel where the file has transparency, else from its grey levels; a pixel
    is subject above half the file's largest value (0/1, 0/255 and a JPEG's noisy 0/255 alike).
    Resized nearest-neighbour when its size differs (a different shape is refused unless not
    same_shape, e.g. for a common comparison grid). None when no mask file exists; a file that
    cannot be read: poisoner.errors.ImageFormatError (one line)."""
    path = mask_path(Path(mask_dir), image_name)
    if path is None:
        return None
    import numpy as np
    from PIL import Image

    from poisoner.image.read import decode_errors

    wanted = (size[0], size[1])  # a list from JSON compares as this tuple
    with decode_errors(path), Image.open(path) as im:
        im.load()
        mask: Image.Image = im
        if im.size != wanted:
            if same_shape:
                _check_same_shape(path, im.size, size)
            mask = im.resize(wanted, Image.Resampling.NEAREST)
        values = _mask_values(mask)
    top = values.max() if values.size else 0
    return values > top / 2 if top > 0 else np.zeros(values.shape, dtype=bool)


def _check_same_shape(path: Path, mask: tuple[int, int], image: tuple[int, int]) -> None:
    """A mask may be another size (DTU's full-size masks for a resized set), never another shape: a
    mask drawn on a phone photo's turned view (EXIF orientation) is its transpose, and stretching it
    would put the subject elsewhere."""
    if abs(mask[0] * image[1] - mask[1] * image[0]) > 0.02 * mask[0] * image[1]:
        turned = abs(mask[0] * image[0] - mask[1] * image[1]) <= 0.02 * mask[0] * image[0]
        why = " (drawn on a turned view?); masks are in the file's stored pixels" if turned else ""
        raise ImageFormatError(
            f"{path.name}: the mask is {mask[0]}x{mask[1]}, the image {image[0]}x{image[1]}: not the same "
            f"shape{why}"
        )


def _mask_values(im: Image.Image) -> np.ndarray:
    import numpy as np

    if im.mode == "P":
        im = im.convert("RGBA" if "transparency" in im.info else "RGB")
    if im.mode in ("RGBA", "LA", "PA"):
        alpha = np.asarray(im.getchannel("A"))
        if alpha.min() < alpha.max():  # transparency says where the subject is
            return alpha
    if im.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
        return np.asarray(im).astype(np.float64)
    return np.asarray(im.convert("L"))


def _sampled(paths: Sequence[Path], sample: int) -> list[Path]:
    """Up to `sample` paths spread evenly over the set (the views of a capture differ most end to end)."""
    if sample <= 0 or not paths:
        return []
    if len(paths) <= sample:
        return list(paths)
    step = (len(paths) - 1) / max(1, sample - 1)
    return [paths[round(i * step)] for i in range(sample)]


def dataset_corner(
    image_paths: Sequence[Path], mask_dir: Path | None, region: float = 0.2, sample: int = 8
) -> CornerChoice:
    """The corner for a dataset's mark: with a mask folder, the corner a sample of the set's subject
    masks covers least (poisoner.corner.choose_corner on their union); without one (or with no mask for any
    sampled image), the corner with the least image detail over a sample of the images; with
    neither, the default corner."""
    from poisoner.corner import CORNERS
    from poisoner.media import is_photo

    paths = sorted(Path(p) for p in image_paths if is_photo(p))
    picked = _sampled(paths, sample)
    if mask_dir is not None:
        choice = _corner_from_masks(picked, Path(mask_dir), region)
        if choice is not None:
            return choice
    if picked:
        return _corner_from_detail(picked, region)
    return CornerChoice(CORNERS[0], "default", {})


def _corner_from_masks(paths: Sequence[Path], mask_dir: Path, region: float) -> CornerChoice | None:
    from poisoner.corner import choose_corner, corner_cover
    from poisoner.orientation import orient_array

    present = []
    for path in paths:
        try:
            mask = load_subject_mask(mask_dir, path.name, MASK_GRID, same_shape=False)
            if mask is not None:  # the corners as the photo shows them (its EXIF orientation)
                present.append(orient_array(mask, shown_orientation(path)))
        except (ImageFormatError, OSError) as exc:  # one bad mask or photo does not decide the corner
            log.warning("subject mask unreadable", extra={"path": str(path), "reason": str(exc)})
    if not present:
        return None
    import numpy as np

    union = np.any(np.stack(present), axis=0)
    cover = corner_cover(union, region)
    return CornerChoice(choose_corner(present, region=region), "masks", cover)


def _corner_from_detail(paths: Sequence[Path], region: float) -> CornerChoice:
    from poisoner.corner import CORNERS, corner_box

    shares: dict[str, list[float]] = {c: [] for c in CORNERS}
    means: dict[str, list[float]] = {c: [] for c in CORNERS}
    for path in paths:
        try:
            grad = detail_map(path)
        except ImageFormatError as exc:  # the pipeline reports the file; the others still count
            log.warning("%s: unreadable, left out of the corner choice (%s)", Path(path).name, exc,
                        extra={"path": str(path)})  # fmt: skip
            continue
        h, w = grad.shape
        for corner in CORNERS:
            x0, y0, x1, y1 = corner_box(corner, w, h, region)
            cell = grad[y0:y1, x0:x1]
            shares[corner].append(float((cell > DETAIL_LEVEL).mean()))
            means[corner].append(float(cell.mean()))
    if not shares[CORNERS[0]]:
        return CornerChoice(CORNERS[0], "default", {})
    cover = {c: sum(v) / len(v) for c, v in shares.items()}
    mean = {c: sum(v) / len(v) for c, v in means.items()}
    corner = min(CORNERS, key=lambda c: (round(cover[c], 2), mean[c], CORNERS.index(c)))
    return CornerChoice(corner, "estimated", cover)


def detail_map(path: Path) -> np.ndarray:
    """Gradient magnitude (8-bit levels per pixel) of a grey thumbnail of the image as a viewer shows
    it (EXIF orientation applied: a corner is the corner the photo shows), at most THUMBNAIL_PX on
    its longest side; transparent pixels read as white (what loaders show)."""
    from PIL import Image

    from poisoner.image.read import decode_errors
    from poisoner.orientation import orient_array, orientation_of

    with decode_errors(path), Image.open(path) as im:
        grad = _gradient(_grey_thumbnail(im))
        return orient_array(grad, orientation_of(im.getexif().get(0x0112)))  # read once decoded: TIFF


def shown_orientation(source: bytes | Path, decoded: Image.Image | None = None) -> int:
    """The EXIF orientation a viewer applies to the stored pixels (of the encoded bytes, a file, or
    the same bytes already decoded). Read after decoding where Pillow turns the picture as it loads
    it (a TIFF: upright, its tag dropped)."""
    import io

    from PIL import Image

    from poisoner.orientation import orientation_of

    if decoded is not None:
        return orientation_of(decoded.getexif().get(0x0112))
    with Image.open(io.BytesIO(source) if isinstance(source, bytes) else source) as im:
        if im.format == "TIFF":
            im.load()
        return orientation_of(im.getexif().get(0x0112))


def _grey_thumbnail(im: Image.Image) -> np.ndarray:
    import numpy as np
    from PIL import Image

    from poisoner.image.read import eight_bit_grey

    # JPEG: a scaled DCT decode of the luma alone, much cheaper; at 1/8 it is the luma blocks' DC
    # values, which _jpeg_dc_thumbnail reads without Pillow (the same pixels).
    im.draft("L", (THUMBNAIL_PX, THUMBNAIL_PX))
    im = eight_bit_grey(im)
    im.thumbnail((THUMBNAIL_PX, THUMBNAIL_PX), Image.Resampling.BOX)
    if "A" in im.getbands() or "transparency" in im.info:
        rgba = im.convert("RGBA")
        white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        im = Image.alpha_composite(white, rgba)
    return np.asarray(im.convert("L"), dtype=np.float64)


def _gradient(grey: np.ndarray) -> np.ndarray:
    import numpy as np

    gy, gx = np.gradient(grey)
    return np.hypot(gx, gy)


def display_detail(
    data: bytes, name: str = "image", decoded: Image.Image | None = None
) -> tuple[np.ndarray, int]:
    """(detail, orientation): display_details without its faint map."""
    detail, _, orientation = display_details(data, name, decoded)
    return detail, orientation


def display_details(
    data: bytes, name: str = "image", decoded: Image.Image | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """(detail, faint, orientation) of an encoded image: detail is True where a THUMBNAIL_PX
    thumbnail, as a viewer shows it (EXIF orientation applied), has visible detail (gradient above
    DETAIL_LEVEL), faint where it is above FAINT_LEVEL: what per-photo placement judges
    (poisoner.placement.place_on_photo). Decoded from the bytes alone, so ppd poison and ppd
    preview judge exactly the same thumbnail. `decoded`: the same bytes already opened and loaded
    by the caller; used instead of a second decode only where that gives the same thumbnail
    (reuses_decode), else ignored."""
    import io

    from PIL import Image

    from poisoner.image.read import decode_errors
    from poisoner.orientation import orient_array, orientation_of

    # The orientation is read once the pixels are decoded: Pillow turns a TIFF upright as it loads
    # it and drops its orientation tag (read from the header, the thumbnail was turned twice).
    with decode_errors(Path(name)):
        if decoded is not None and reuses_decode(decoded):
            grad = _gradient(_grey_thumbnail(decoded.copy()))  # thumbnail() resizes in place
            orientation = orientation_of(decoded.getexif().get(0x0112))
        else:
            with Image.open(io.BytesIO(data)) as im:
                grey = _jpeg_dc_thumbnail(data, im.size) if im.format == "JPEG" else None
                grad = _gradient(_grey_thumbnail(im) if grey is None else grey)
                orientation = orientation_of(im.getexif().get(0x0112))
    faint = orient_array(grad > FAINT_LEVEL, orientation)
    return orient_array(grad > DETAIL_LEVEL, orientation), faint, orientation


def _jpeg_dc_thumbnail(data: bytes, size: tuple[int, int]) -> np.ndarray | None:
    """_grey_thumbnail of a JPEG that Pillow would decode at 1/8, from the luma DC values of the
    bit-level index (poisoner/jpeg_scan.py), which the splice then reuses: one Huffman decode of the
    picture for both. None where that path cannot take the file (Pillow's decode then)."""
    import numpy as np
    from PIL import Image

    from poisoner import jpeg_scan

    if jpeg_scan.thumbnail_scale(*size, THUMBNAIL_PX) != jpeg_scan.THUMBNAIL_SCALE:
        return None
    try:
        grey = Image.fromarray(jpeg_scan.luma_thumbnail(jpeg_scan.index(data)))
    except jpeg_scan.Unsupported:
        return None
    grey.thumbnail((THUMBNAIL_PX, THUMBNAIL_PX), Image.Resampling.BOX)
    return np.asarray(grey, dtype=np.float64)


def reuses_decode(im: Image.Image) -> bool:
    """Whether a (loaded) image gives display_detail the thumbnail its bytes give: when its format
    decodes the same pixels at any requested size (no scaled decode: `draft` is Pillow's no-op; a
    JPEG's draft decodes at 1/8 and differs from the full decode). Issue 30: a PNG was decoded twice
    per file (once to poison, once here), 24 ms of an 800 px view's ~150 ms."""
    from PIL import Image

    return type(im).draft is Image.Image.draft


def frame_detail(rgb: np.ndarray) -> np.ndarray:
    """display_detail for a decoded frame (H x W x 3 uint8, as shown): True = visible detail."""
    from PIL import Image

    return _gradient(_grey_thumbnail(Image.fromarray(rgb))) > DETAIL_LEVEL


def display_subject(keep_out: np.ndarray, orientation: int, shape: tuple[int, int]) -> np.ndarray:
    """A stored-pixel subject mask (H x W, True = subject) as shown, on a thumbnail grid of `shape`
    (h, w): a cell is subject when any pixel in it is."""
    import numpy as np
    from PIL import Image

    from poisoner.orientation import orient_array

    shown = np.ascontiguousarray(orient_array(np.asarray(keep_out) > 0, orientation)).astype(np.uint8) * 255
    small = Image.fromarray(shown).resize((shape[1], shape[0]), Image.Resampling.BOX)
    return np.asarray(small) > 0
