"""What a viewer sees of a mark: a local perceptual difference (NVIDIA FLIP) at a stated display size.

Why FLIP, and why local figures: whole-image SSIM or a mean error averages a glaring local defect
over millions of untouched pixels (issue 14: ppd's old default patch has a lower FLIP *mean* than a
JPEG q85 re-encode, yet it is the only change a person notices). FLIP (Andersson et al., HPG 2020)
models what an observer at a given viewing distance perceives, per pixel; its high percentiles and
the area above 0.5 say whether *something* in the picture is noticeable. The `flip-evaluator`
wheel runs on the CPU with no downloads.

Viewing condition: both images are resized to `display_width` pixels (default 1920, a full-HD
screen showing the photo full width) and FLIP is evaluated at `ppd` pixels per degree of visual
angle (default 67.02, FLIP's own default: a 0.7 m wide 3840 px monitor seen from 0.7 m; at 1920 px
the photo then spans about 29 degrees of view). The budget is calibrated per image against a JPEG
q85 re-encode of the same original (`jpeg_p999`), which creators accept as invisible.

`visibility_report` is pure: arrays in, a `Visibility` out (the JPEG reference is encoded in
memory). `measure_pairs` is the verification's stage: a few (original, protected) files of a
dataset read from disk, each judged at min(1920, its width) px, and the worst figures over them
(a bounded cost: FLIP takes about a second per full-HD image on one core, twice with the JPEG
reference).
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from poisoner.errors import ExitStatus, PpdError

DISPLAY_WIDTH = 1920
FLIP_DEFAULT_PPD = 67.02064514160156  # flip-evaluator's default viewing condition
JPEG_REFERENCE_QUALITY = 85
VISIBLE_THRESHOLD = 0.5  # FLIP above this: a clearly visible difference at that pixel
FLIP_MARGIN_DEG = 0.5  # around a local change, FLIP is evaluated this many degrees of view further


class VisibilityError(PpdError, ValueError):
    """Images that cannot be compared (message = one clear line)."""

    exit_status = ExitStatus.USAGE


class Visibility(msgspec.Struct, frozen=True):
    """FLIP figures of one clean/changed pair at a stated viewing condition, and where pixels changed."""

    display_width: int
    ppd: float
    flip_mean: float
    flip_p99: float
    flip_p999: float
    flip_max: float
    area_above_half: float  # fraction of the displayed image with FLIP > 0.5
    changed_area: float  # fraction of the original's pixels that differ at all (full resolution)
    changed_box: tuple[int, int, int, int] | None  # (left, top, right, bottom) of changed pixels
    in_one_corner: bool | None  # every changed pixel inside one corner region (corner_region wide/high)
    corner_region: float
    touches_subject: bool | None  # None: no subject mask given
    jpeg_p999: float | None  # FLIP p99.9 of a JPEG q85 re-encode of the original (the budget)
    p999_vs_jpeg: float | None  # flip_p999 / jpeg_p999: <= 1 is within the JPEG budget

    def summary(self) -> str:
        """One line a creator reads: how the mark compares with a JPEG re-encode at this display size."""
        budget = ""
        if self.jpeg_p999 is not None and self.p999_vs_jpeg is not None:
            budget = f" (a JPEG q85 re-encode: {self.jpeg_p999:.2f}, so {self.p999_vs_jpeg:.1f}x that)"
        where = {True: "inside one corner", False: "not confined to a corner", None: "nothing changed"}[
            self.in_one_corner
        ]
        return (
            f"visibility at {self.display_width} px wide: FLIP p99.9 {self.flip_p999:.2f}{budget}; "
            f"{self.area_above_half:.2%} of the picture clearly visible (FLIP > 0.5); "
            f"{self.changed_area:.2%} of pixels changed, {where}"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready builtins (msgspec's encoding: the box becomes a list)."""
        return msgspec.to_builtins(self)


def _rgb8(pixels: np.ndarray, what: str) -> np.ndarray:
    """uint8 H x W x 3 (grey and RGBA accepted; RGBA composited over white as loaders do)."""
    a = np.asarray(pixels)
    if a.dtype == np.uint16:
        a = (a.astype(np.float64) / 257.0 + 0.5).astype(np.uint8)
    if a.dtype != np.uint8:
        raise VisibilityError(f"{what}: expected uint8 or uint16 pixels, got {a.dtype}")
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (1, 2, 3, 4):
        raise VisibilityError(f"{what}: expected an H x W (x C) image, got shape {a.shape}")
    if a.shape[2] in (2, 4):
        colour = a[..., :-1].astype(np.float64)
        alpha = a[..., -1:].astype(np.float64) / 255.0
        a = np.floor(colour * alpha + 255.0 * (1.0 - alpha) + 0.5).astype(np.uint8)
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return a


def to_display(rgb: np.ndarray, display_width: int) -> np.ndarray:
    """RGB uint8 resized (Lanczos) to display_width wide, as float32 in [0, 1] for FLIP."""
    from PIL import Image

    h, w = rgb.shape[:2]
    if w != display_width:
        height = max(1, round(h * display_width / w))
        rgb = np.asarray(Image.fromarray(rgb).resize((display_width, height), Image.Resampling.LANCZOS))
    return rgb.astype(np.float32) / 255.0


def flip_map(reference: np.ndarray, test: np.ndarray, ppd: float = FLIP_DEFAULT_PPD) -> np.ndarray:
    """FLIP error map (H x W, values in [0, 1]) of two float RGB images in [0, 1] (LDR, sRGB)."""
    import flip_evaluator

    error, _, _ = flip_evaluator.evaluate(
        np.ascontiguousarray(reference, dtype=np.float32),
        np.ascontiguousarray(test, dtype=np.float32),
        "LDR",
        applyMagma=False,
        computeMeanError=False,
        parameters={"ppd": float(ppd)},
    )
    return np.asarray(error, dtype=np.float64).reshape(reference.shape[:2])


def jpeg_reencode(rgb: np.ndarray, quality: int = JPEG_REFERENCE_QUALITY) -> np.ndarray:
    """The image after a JPEG re-encode at `quality` (in memory): the accepted-as-invisible yardstick."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, "JPEG", quality=quality)
    buf.seek(0)
    with Image.open(buf) as im:
        return np.asarray(im.convert("RGB"))


def _changed_box(changed: np.ndarray) -> tuple[int, int, int, int] | None:
    ys, xs = np.nonzero(changed)
    if len(xs) == 0:
        return None
    return (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)


def box_in_one_corner(box: tuple[int, int, int, int], width: int, height: int, region: float) -> bool:
    """Whether a box lies inside one corner region of region*width x region*height."""
    rw, rh = region * width, region * height
    left, top, right, bottom = box
    horizontal = right <= rw or left >= width - rw
    vertical = bottom <= rh or top >= height - rh
    return horizontal and vertical


Region = tuple[int, int, int, int]  # (x0, y0, x1, y1) in display pixels


def display_shape(height: int, width: int, display_width: int) -> tuple[int, int]:
    """(height, width) of a picture shown display_width wide (to_display's size)."""
    return (
        height if width == display_width else max(1, round(height * display_width / width)),
        display_width,
    )


def display_region(picture: Any, display_width: int, region: Region) -> np.ndarray:
    """to_display(rgb, display_width)[y0:y1, x0:x1] of a PIL picture, without resizing the rest
    of it (Pillow's box: the filter still reads the pixels around the region); the same pixels to
    one level of rounding in a few in ten thousand."""
    from PIL import Image

    x0, y0, x1, y1 = region
    w, h = picture.size
    if w == display_width:
        return np.asarray(picture.crop(region)).astype(np.float32) / 255.0
    dh, dw = display_shape(h, w, display_width)
    sx, sy = w / dw, h / dh
    part = picture.resize(
        (x1 - x0, y1 - y0), Image.Resampling.LANCZOS, box=(x0 * sx, y0 * sy, x1 * sx, y1 * sy)
    )
    return np.asarray(part).astype(np.float32) / 255.0


class _Cropped:
    """Part of a picture that display_region reads as if it were the whole (its size, and a box
    moved by the part's offset): what the resize filter needs around a region, not a copy of
    all of it."""

    def __init__(self, rgb: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> None:
        from PIL import Image

        self.size = (rgb.shape[1], rgb.shape[0])
        self._offset = (x0, y0)
        self._part = Image.fromarray(np.ascontiguousarray(rgb[y0:y1, x0:x1]))

    def resize(self, size: tuple[int, int], resample: Any, box: tuple[float, ...]) -> Any:
        ox, oy = self._offset
        return self._part.resize(size, resample, box=(box[0] - ox, box[1] - oy, box[2] - ox, box[3] - oy))

    def crop(self, region: Region) -> Any:
        ox, oy = self._offset
        return self._part.crop((region[0] - ox, region[1] - oy, region[2] - ox, region[3] - oy))


def _around(rgb: np.ndarray, region: Region, scale: float) -> _Cropped:
    """The full-resolution part of rgb that the display region (display px, `scale` display px
    per source px) and its resize filter read: Lanczos reaches 3 source px per display px."""
    h, w = rgb.shape[:2]
    reach = int(np.ceil(3 / min(scale, 1.0))) + 2
    x0, y0, x1, y1 = region
    sx0, sy0 = max(0, int(x0 / scale) - reach), max(0, int(y0 / scale) - reach)
    sx1, sy1 = min(w, int(np.ceil(x1 / scale)) + reach), min(h, int(np.ceil(y1 / scale)) + reach)
    return _Cropped(rgb, sx0, sy0, sx1, sy1)


def local_region(box: Region, width: int, shape: tuple[int, int], ppd: float) -> Region:
    """The display region FLIP must see around a change at `box` (full-resolution pixels of a
    picture `width` wide, shown at `shape`): FLIP_MARGIN_DEG degrees of view around it, plus the
    resize's reach."""
    h, w = shape
    scale = w / width
    margin = int(np.ceil(FLIP_MARGIN_DEG * ppd)) + int(np.ceil(4 / min(scale, 1.0)))
    left, top, right, bottom = box
    x0, y0 = max(0, int(left * scale) - margin), max(0, int(top * scale) - margin)
    x1, y1 = min(w, int(np.ceil(right * scale)) + margin), min(h, int(np.ceil(bottom * scale)) + margin)
    return x0, y0, x1, y1


def local_flip_map(
    ref: np.ndarray, test: np.ndarray, box: tuple[int, int, int, int], width: int, ppd: float
) -> np.ndarray:
    """flip_map of two display images that differ only near `box` (full-resolution pixels of an
    image `width` wide): FLIP evaluated on local_region, zero elsewhere. The same map as the
    whole-image evaluation (FLIP's filters reach well under a degree, and identical pixels beyond
    them give exactly 0; tests/verifier/test_visibility.py checks it), at a fraction of the cost: a mark
    in one corner is a few percent of a 12 MP photo (issue 28: `ppd preview` took 48 s)."""
    h, w = ref.shape[:2]
    x0, y0, x1, y1 = local_region(box, width, (h, w), ppd)
    if (x1 - x0) * (y1 - y0) >= 0.5 * w * h:  # most of the picture: the whole is as cheap
        return flip_map(ref, test, ppd)
    error = np.zeros((h, w), dtype=np.float64)
    error[y0:y1, x0:x1] = flip_map(ref[y0:y1, x0:x1], test[y0:y1, x0:x1], ppd)
    return error


SAMPLE_TILE = 128  # display px: the side of one sampled tile
TILE_MARGIN = 32  # display px evaluated around a tile and dropped: FLIP's filters reach ~20 px at 67 ppd


def tile_regions(shape: tuple[int, int], fraction: float) -> list[Region]:
    """About `fraction` of a display picture as SAMPLE_TILE px tiles on an even grid (every k-th
    in both directions, offset row by row; none within TILE_MARGIN of the border), each region
    with its TILE_MARGIN of context."""
    h, w = shape
    side = SAMPLE_TILE + 2 * TILE_MARGIN
    rows, cols = (h - 2 * TILE_MARGIN) // SAMPLE_TILE, (w - 2 * TILE_MARGIN) // SAMPLE_TILE
    stride = max(1, round((1.0 / max(fraction, 1e-3)) ** 0.5))
    return [
        (c * SAMPLE_TILE, r * SAMPLE_TILE, c * SAMPLE_TILE + side, r * SAMPLE_TILE + side)
        for r in range(0, rows, stride)
        for c in range((r // stride) % stride, cols, stride)
    ]


def mosaic_flip(pairs: Sequence[tuple[np.ndarray, np.ndarray]], ppd: float) -> np.ndarray:
    """FLIP of many (reference, test) tiles, each with TILE_MARGIN px of context, laid side by side
    into one mosaic evaluated at once (each FLIP call has a fixed cost); the values of the tiles
    without their context, so each is the whole picture's evaluation's."""
    side = SAMPLE_TILE + 2 * TILE_MARGIN
    per_row = int(np.ceil(np.sqrt(len(pairs))))
    shape = (-(-len(pairs) // per_row) * side, per_row * side, 3)
    mosaics = [np.zeros(shape, np.float32) for _ in range(2)]
    for i, pair in enumerate(pairs):
        my, mx = (i // per_row) * side, (i % per_row) * side
        for mosaic, tile in zip(mosaics, pair, strict=True):
            mosaic[my : my + side, mx : mx + side] = tile
    error = flip_map(mosaics[0], mosaics[1], ppd)
    values = []
    for i in range(len(pairs)):
        my, mx = (i // per_row) * side + TILE_MARGIN, (i % per_row) * side + TILE_MARGIN
        values.append(error[my : my + SAMPLE_TILE, mx : mx + SAMPLE_TILE].ravel())
    return np.concatenate(values)


def _quick_figures(
    a: np.ndarray, b: np.ndarray, box: Region | None, display_width: int, ppd: float, jpeg_sample: float,
    jpeg_reference: bool,
) -> tuple[tuple[float, float, float, float, float], float | None]:  # fmt: skip
    """visibility_report's FLIP figures resizing only what FLIP must see: the mark's local region
    (its figures are the whole picture's) and, for the JPEG budget, jpeg_sample of the picture
    in tiles (an estimate: within a few percent of the whole picture's on photos, lower on a
    picture that is mostly plain background). No full-size resize, one FLIP call each."""
    from PIL import Image

    h, w = a.shape[:2]
    shape = display_shape(h, w, display_width)
    original = Image.fromarray(a)  # once: each conversion copies the whole picture
    stats = (0.0, 0.0, 0.0, 0.0, 0.0)
    if box is not None:
        region = local_region(box, w, shape, ppd)
        x0, y0, x1, y1 = region
        error = np.zeros(shape, dtype=np.float64)
        changed = display_region(_around(b, region, shape[1] / w), display_width, region)
        error[y0:y1, x0:x1] = flip_map(display_region(original, display_width, region), changed, ppd)
        stats = _flip_stats(error)
    if not jpeg_reference:
        return stats, None
    tiles = tile_regions(shape, jpeg_sample)
    if not tiles:  # too small to sample: the whole picture
        ref, jpeg = to_display(a, display_width), to_display(jpeg_reencode(a), display_width)
        return stats, _flip_stats(flip_map(ref, jpeg, ppd))[2]
    buf = io.BytesIO()  # jpeg_reencode's re-encode, kept as a picture (no 12 MP array round trip)
    original.save(buf, "JPEG", quality=JPEG_REFERENCE_QUALITY)
    buf.seek(0)
    reencoded = Image.open(buf)
    reencoded.load()
    pairs = [
        (display_region(original, display_width, t), display_region(reencoded, display_width, t))
        for t in tiles
    ]
    return stats, float(np.percentile(mosaic_flip(pairs, ppd), 99.9))


def _flip_stats(error: np.ndarray) -> tuple[float, float, float, float, float]:
    p99, p999 = np.percentile(error, [99.0, 99.9])
    return (
        float(error.mean()),
        float(p99),
        float(p999),
        float(error.max()),
        float((error > VISIBLE_THRESHOLD).mean()),
    )


def visibility_report(
    original: np.ndarray,
    changed: np.ndarray,
    *,
    display_width: int = DISPLAY_WIDTH,
    ppd: float = FLIP_DEFAULT_PPD,
    subject_mask: np.ndarray | None = None,
    corner_region: float = 0.2,
    jpeg_reference: bool = True,
    jpeg_sample: float = 1.0,
) -> Visibility:
    """How visible `changed` is next to `original` on a display_width-wide screen at `ppd`.

    subject_mask (H x W, nonzero = subject) answers whether any changed pixel lies on the subject.
    jpeg_reference adds the budget: FLIP p99.9 of a JPEG q85 re-encode of the original (one more
    FLIP evaluation over the whole picture: the dearest part). jpeg_sample < 1 is the quick
    answer (`ppd preview`, _quick_figures): the mark's figures from its region alone, the budget
    estimated on that fraction of the picture; verification and auto mode use the whole picture.
    """
    a, b = _rgb8(original, "original"), _rgb8(changed, "changed")
    if a.shape != b.shape:
        raise VisibilityError(f"images differ in size: {a.shape[:2]} vs {b.shape[:2]}")
    if display_width < 8:
        raise VisibilityError(f"display width must be at least 8 px, got {display_width}")
    h, w = a.shape[:2]
    diff = np.any(a != b, axis=2)
    box = _changed_box(diff)
    touches = None
    if subject_mask is not None:
        m = np.asarray(subject_mask)
        if m.ndim == 3:
            m = m.max(axis=2)
        if m.shape != (h, w):
            raise VisibilityError(f"subject mask is {m.shape}, image is {(h, w)}")
        touches = bool(np.any(diff & (m > 0)))
    jpeg_p999 = ratio = None
    if jpeg_sample < 1.0:
        stats, jpeg_p999 = _quick_figures(a, b, box, display_width, ppd, jpeg_sample, jpeg_reference)
    else:
        ref = to_display(a, display_width)
        if box is None:
            stats = (0.0, 0.0, 0.0, 0.0, 0.0)  # identical images: FLIP is 0 everywhere by definition
        else:
            stats = _flip_stats(local_flip_map(ref, to_display(b, display_width), box, w, ppd))
        if jpeg_reference:
            jpeg = to_display(jpeg_reencode(a), display_width)
            jpeg_p999 = _flip_stats(flip_map(ref, jpeg, ppd))[2]
    if jpeg_p999 is not None:
        ratio = stats[2] / jpeg_p999 if jpeg_p999 > 0 else None
    return Visibility(
        display_width=display_width,
        ppd=float(ppd),
        flip_mean=stats[0],
        flip_p99=stats[1],
        flip_p999=stats[2],
        flip_max=stats[3],
        area_above_half=stats[4],
        changed_area=float(diff.mean()),
        changed_box=box,
        in_one_corner=None if box is None else box_in_one_corner(box, w, h, corner_region),
        corner_region=corner_region,
        touches_subject=touches,
        jpeg_p999=jpeg_p999,
        p999_vs_jpeg=ratio,
    )


# ---- the verification's stage: a few files of a dataset --------------------------------------
VISIBILITY_SAMPLE = 3  # images judged per verification (bounded cost; evenly spread over the set)


class ImageVisibility(msgspec.Struct, frozen=True):
    """One measured (original, protected) file."""

    name: str
    width: int
    height: int
    figures: Visibility


class DatasetVisibility(msgspec.Struct, frozen=True):
    """What a viewer sees of a dataset's protection: a few files measured, and the worst over them."""

    measured: int  # files judged
    total: int  # image files in the dataset (the others were not measured)
    subject_masks: bool  # whether subject masks were given for the measured files
    worst: Visibility  # per figure, the worst over the measured files
    images: list[ImageVisibility] = msgspec.field(default_factory=list)
    skipped: list[str] = msgspec.field(default_factory=list)  # "name: why" for files that could not be read

    def lines(self) -> list[str]:
        """What `ppd verify` prints and the report says, in plain words."""
        w = self.worst
        budget = (
            f", {w.p999_vs_jpeg:.1f}x a JPEG q85 re-encode's {w.jpeg_p999:.2f}"
            if w.p999_vs_jpeg is not None and w.jpeg_p999 is not None
            else ""
        )
        where = {
            True: "inside one corner region",
            False: "NOT confined to one corner",
            None: "no pixel changed",
        }
        subject = {
            True: "changed pixels touch the subject mask",
            False: "no changed pixel on the subject mask",
        }
        lines = [
            f"visibility (FLIP at min(1920, width) px, {w.ppd:.0f} px/deg; worst of {self.measured} of "
            f"{self.total} images): p99.9 {w.flip_p999:.2f}{budget}; max {w.flip_max:.2f}; "
            f"mean {w.flip_mean:.4f}",
            f"visibility: {w.area_above_half:.2%} of the picture clearly visible (FLIP > 0.5); "
            f"{w.changed_area:.2%} of pixels changed, {where[w.in_one_corner]}"
            + (f"; {subject[w.touches_subject]}" if w.touches_subject is not None else ""),
        ]
        lines += [f"visibility: not measured on {s}" for s in self.skipped]
        return lines


def sample_evenly(count: int, k: int) -> list[int]:
    """k indices spread over range(count) (first and last included when k >= 2)."""
    if count <= 0 or k <= 0:
        return []
    if k >= count:
        return list(range(count))
    if k == 1:
        return [0]
    return sorted({round(i * (count - 1) / (k - 1)) for i in range(k)})


def _load_rgb(path: Path) -> np.ndarray:
    from PIL import Image, ImageOps

    with Image.open(path) as opened:
        im = ImageOps.exif_transpose(opened)  # as a viewer sees it
        if im.mode in ("RGBA", "LA", "PA", "P"):
            return _rgb8(np.asarray(im.convert("RGBA")), str(path))
        return np.asarray(im.convert("RGB"))


def _worst(figures: Sequence[Visibility]) -> Visibility:
    """Per figure, the worst over several images (the mark is as visible as its most visible copy)."""
    first = figures[0]
    ratios = [f.p999_vs_jpeg for f in figures if f.p999_vs_jpeg is not None]
    corners = [f.in_one_corner for f in figures if f.in_one_corner is not None]
    touches = [f.touches_subject for f in figures if f.touches_subject is not None]
    worst_ratio = max(figures, key=lambda f: -1.0 if f.p999_vs_jpeg is None else f.p999_vs_jpeg)
    return Visibility(
        display_width=min(f.display_width for f in figures),
        ppd=first.ppd,
        flip_mean=max(f.flip_mean for f in figures),
        flip_p99=max(f.flip_p99 for f in figures),
        flip_p999=max(f.flip_p999 for f in figures),
        flip_max=max(f.flip_max for f in figures),
        area_above_half=max(f.area_above_half for f in figures),
        changed_area=max(f.changed_area for f in figures),
        changed_box=None,  # boxes of different images do not combine
        in_one_corner=all(corners) if corners else None,
        corner_region=first.corner_region,
        touches_subject=any(touches) if touches else None,
        jpeg_p999=worst_ratio.jpeg_p999 if ratios else None,
        p999_vs_jpeg=max(ratios) if ratios else None,
    )


def measure_pairs(
    pairs: Sequence[tuple[Path, Path]],
    *,
    sample: int = VISIBILITY_SAMPLE,
    subject_mask_dir: Path | None = None,
    corner_region: float = 0.2,
) -> DatasetVisibility | None:
    """FLIP figures of `sample` (original, protected) image pairs, each at min(1920, width) px.

    subject_mask_dir: a folder of subject masks (poisoner.subject.load_subject_mask finds each image's
    by name or frame number and reads it at the image's size): `touches_subject` is then measured.
    Files that cannot be read or compared are listed in `skipped`; None when no pair was measured."""
    from poisoner.errors import ImageFormatError
    from poisoner.subject import load_subject_mask

    chosen = [pairs[i] for i in sample_evenly(len(pairs), sample)]
    measured: list[ImageVisibility] = []
    skipped: list[str] = []
    for original, protected in chosen:
        try:
            a, b = _load_rgb(Path(original)), _load_rgb(Path(protected))
            name = Path(protected).name
            h, w = a.shape[:2]
            # at the size shown (mask sets such as DTU's carry no EXIF rotation)
            mask = load_subject_mask(subject_mask_dir, name, (w, h)) if subject_mask_dir else None
            figures = visibility_report(
                a, b, display_width=min(DISPLAY_WIDTH, w), subject_mask=mask, corner_region=corner_region
            )
        except (OSError, ValueError, ImageFormatError) as exc:
            skipped.append(f"{Path(protected).name}: {exc}")
            continue
        measured.append(ImageVisibility(Path(protected).name, w, h, figures))
    if not measured:
        return None
    return DatasetVisibility(
        measured=len(measured),
        total=len(pairs),
        subject_masks=any(m.figures.touches_subject is not None for m in measured),
        worst=_worst([m.figures for m in measured]),
        images=measured,
        skipped=skipped,
    )


def dataset_visibility_from_json(data: Any) -> DatasetVisibility | None:
    """A stored DatasetVisibility (a run folder's report.json or a Store row), None when absent."""
    if not data:
        return None
    return msgspec.convert(data, DatasetVisibility)
