"""A cheap per-dataset hint: how much of the frame carries matchable texture, against what ppd's mark adds.

Why this predicts anything (docs/TEXTURED.md, bench/results/patch_votes.md): COLMAP's geometric
verification keeps the camera model with the most consistent matches. The mark wins that vote only
where the scene offers few matches of its own: around an object on a plain background the flat
pixels give SIFT nothing, and the mark (about 1% of the image) can outvote the subject; where
texture fills the frame, the scene's true matches outnumber the mark's 20-100 to 1 and no mark
within the visibility budget wins. A cell (2% of the width) is *textured* when it holds fine detail
that SIFT's detector fires on: a difference of Gaussians at the mark's own block scale reaching
COLMAP's peak threshold. Two figures follow, and the kind rests on them:
- the **edge band** (the outer 10% of each side, where the corner mark lives): a subject surrounded
  by plain background leaves it featureless; a textured support or floor runs out of the frame
  through it. Under one fifth textured: "plain";
- the **whole frame**: four fifths textured or more: "richly textured" (a façade, a room, a tree);
- otherwise "textured support" (an object on textured ground: dtu_scan37, protected at 800 px, not
  at 1600 px).
The cut points say what they mean (a fifth, four fifths); they are not fitted to a set
(bench/results/scene_hint.md shows the margins on the shared sets, crops, resizes and renders).
"Plain" is necessary, not sufficient: a richly textured subject on a plain floor can still outvote
the mark (bench/results/designs.md, the `object` render), which single images cannot tell.

The figures are measured at the mark's scale: the mark is a fraction of the width (patch 6%, blocks
0.5%), so the contest looks the same at any size; the frame is reduced to ANALYSIS_WIDTH (where the
mark's blocks are 4 px), never enlarged. The hint never claims protection: only `ppd verify` can.
"""

from __future__ import annotations

import functools
import logging
import statistics
from collections.abc import Sequence
from enum import StrEnum
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import msgspec

if TYPE_CHECKING:
    import numpy as np

    from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

# The mark's blocks are 0.5% of the width: 4 px here, SIFT's finest scale (spec.MIN_BLOCK_PX).
ANALYSIS_WIDTH = 800
CELL_FRACTION = 0.02  # a cell is 2% of the width (16 px at ANALYSIS_WIDTH), a third of the mark's side
MIN_CELL_PX = 8
# COLMAP's SIFT peak threshold (0.02 / 3 levels per octave), on grey levels in [0, 1].
PEAK_THRESHOLD = 0.02 / 3
DOG_SIGMAS = (1.0, 2.0)  # the band that a 4 px block pattern and fine scene texture both fill
# How far a pixel's DoG (the wider Gaussian's radius, int(4 sigma + 0.5), per pass of two) and its
# 3x3 maximum reach: a crop this much larger than the mark on every side counts its responses exactly.
MARK_CROP_REACH = 2 * int(4 * DOG_SIGMAS[1] + 0.5) + 2
# Sensor noise also reaches SIFT's threshold in this band, and its keypoints never match across views:
# a cell counts only above this many standard deviations of the image's own noise after the DoG.
NOISE_FLOOR_SIGMAS = 4.0
# Above this the finest detail is texture, not sensor noise (a photo reduced to 800 px is far below it;
# gravel, foliage or a noise-like pattern is not): without a cap such a frame would read as plain.
MAX_NOISE_SIGMA = 8 / 255
EDGE_BAND = 0.1  # the outer tenth of each side
PLAIN_EDGE_BELOW = 0.2  # at most a fifth of the edge band textured: a plain surround
RICH_FROM = 0.8  # texture covers four fifths of the frame or more
SAMPLE = 6  # images per dataset; a hint, not a measurement of every file
# The largest real photos (long side, px) a set held on in our tests (dtu_scan37 at its full 1600 px;
# upscaled to 6000 px, so no finer detail, it held in 28 of 30 profile-seed rows at the 10% bar). A
# box of real photo faces on a plain backdrop was NOT protected at 2048, 3200 and 6000 px, and at 1600
# px only at one COLMAP seed of three: SIFT sees the subject's fine texture and its true matches
# out-vote the mark (bench/results/protection_24mp.md). The figures above are taken at the mark's
# scale and cannot see that: the size is said apart.
HELD_UP_TO_PX = 1600


class SceneKind(StrEnum):
    PLAIN = "plain"
    TEXTURED_SUPPORT = "textured-support"
    RICHLY_TEXTURED = "richly-textured"


class ImageFigures(msgspec.Struct, frozen=True):
    """One image at the analysis size: its textured fraction and the detector's responses."""

    textured_fraction: float
    edge_textured_fraction: float
    responses: int
    width: int
    height: int


class SceneHint(msgspec.Struct, frozen=True):
    """The hint for one dataset and the figures it rests on (medians over the sampled images)."""

    dataset: str
    kind: SceneKind
    textured_fraction: float  # median over the sample
    textured_fraction_min: float
    textured_fraction_max: float
    edge_textured_fraction: float  # median over the sample: the outer tenth of each side
    scene_responses: int  # median detector responses per frame at the analysis size
    mark_responses: int  # what the mark carries on the same frame
    mark_area_fraction: float  # share of the frame the mark changes
    texture_per_mark: float  # textured area / mark area: mark-sized areas of texture against it
    images: int
    analysis_width: int
    sentence: str
    long_side: int = 0  # median long side of the sampled photos as stored, px


def classify(textured_fraction: float, edge_textured_fraction: float) -> SceneKind:
    if textured_fraction >= RICH_FROM:
        return SceneKind.RICHLY_TEXTURED
    if edge_textured_fraction < PLAIN_EDGE_BELOW:
        return SceneKind.PLAIN
    return SceneKind.TEXTURED_SUPPORT


def sentence(
    dataset: str, kind: SceneKind, textured_fraction: float, edge_textured_fraction: float, long_side: int = 0
) -> str:
    """One line for the user; it says what our tests found for sets like this, never 'protected'."""
    size = ""
    if long_side > HELD_UP_TO_PX:  # issue 30: no set held above 1600 px
        size = (f" At about {long_side} px on their long side these photos are larger than any real capture "
                f"the mark held on in our tests ({HELD_UP_TO_PX} px): a finely textured subject was NOT "
                "protected at 2048, 3200 "
                "and 6000 px; a soft one (a capture upscaled to 6000 px) mostly was.")  # fmt: skip
    if kind == SceneKind.PLAIN:
        return (f"{dataset}: plain background around the subject (frame edges {edge_textured_fraction:.0%} "
                "textured) — the kind of set ppd's mark protected in our tests, unless the subject itself is "
                f"richly textured.{size} `ppd verify` tells you for sure.")  # fmt: skip
    if kind == SceneKind.TEXTURED_SUPPORT:
        # Issue 25: this class holds sets we measured (an object on a textured stone: dtu_scan37, held
        # in most runs at 800 px) and sets we did not, or that failed (a façade under open sky; a box of
        # real photo faces filling 2/3 of the frame, testkit/fill_set.py: COLMAP's global mapper 100%,
        # bench/results/placement.md); one image cannot tell them apart, so the line claims nothing.
        return (f"{dataset}: texture reaches the frame's edges ({edge_textured_fraction:.0%} of them): an "
                "object on a textured support, a façade, or a subject filling the frame — ppd's mark held "
                "on one object-on-stone set in our tests and failed on façades and on a photo-textured box "
                "filling the frame; for the rest nothing is measured."
                f"{size} `ppd verify` tells you for sure.")  # fmt: skip
    return (f"{dataset}: richly textured everywhere ({textured_fraction:.0%} of the frame) — in our tests no "
            "mark within the visibility budget protected sets like this; `ppd verify` will say.")  # fmt: skip


def _dog(gray: np.ndarray) -> np.ndarray:
    return gaussian(gray, DOG_SIGMAS[0]) - gaussian(gray, DOG_SIGMAS[1])


_BAND_ROWS = 32  # rows of float64 filtered together (800 px wide: 200 KiB, an L2 cache's worth)


@functools.cache
def _gaussian_weights(sigma: float) -> tuple[float, ...]:
    """scipy.ndimage's kernel for gaussian_filter(sigma) (truncate 4: radius int(4 sigma + 0.5)),
    the same float64 values."""
    import numpy as np

    radius = int(4.0 * sigma + 0.5)
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / (sigma * sigma) * x**2)
    return tuple(float(w) for w in phi / phi.sum())


def gaussian(image: np.ndarray, sigma: float) -> np.ndarray:
    """scipy.ndimage.gaussian_filter(image, sigma) of a 2-D float32 image, the same float32 values
    without scipy, so `ppd poison`'s summary never imports it (0.45 s CPU per process, issue 30); in C
    where the package was built with it (poisoner/_scene_filter.c: 12 filters of the hint's 800 px
    frames 0.31 -> 0.05-0.07 s here), else in numpy. Each axis
    in turn (rows first), the borders mirrored ('reflect': d c b a | a b c d), every sum in float64
    in scipy's own order (the centre tap, then each symmetric pair from the outermost in:
    ni_filters.c's symmetric case), cast to float32 after each axis
    (tests/poisoner/test_scene.py compares both bit for bit)."""
    import numpy as np

    weights = _gaussian_weights(sigma)
    out = image.astype(np.float32, copy=False)
    if out.size == 0:
        return out.copy()
    if (compiled := _compiled_filter()) is not None and out.ndim == 2:
        src = np.ascontiguousarray(out)
        dst = np.empty_like(src)
        compiled.gaussian(src, dst, src.shape[0], src.shape[1], np.asarray(weights, dtype=np.float64))
        return dst
    return gaussian_numpy(out, sigma)


def gaussian_numpy(image: np.ndarray, sigma: float) -> np.ndarray:
    """gaussian in numpy alone (a band of rows at a time), the same values."""
    import numpy as np

    weights = _gaussian_weights(sigma)
    radius = len(weights) // 2
    out = image.astype(np.float32, copy=False)
    for axis in (0, 1):
        lines = np.ascontiguousarray(out.T if axis == 1 else out, dtype=np.float64)
        padded = np.pad(lines, ((radius, radius), (0, 0)), mode="symmetric")
        result = np.empty(lines.shape, dtype=np.float32)
        for top in range(0, lines.shape[0], _BAND_ROWS):  # a band of rows at a time: stays in cache
            n = min(_BAND_ROWS, lines.shape[0] - top)
            acc = padded[top + radius : top + radius + n] * weights[radius]
            pair = np.empty_like(acc)
            for j in range(radius, 0, -1):
                np.add(padded[top + radius - j : top + radius - j + n],
                       padded[top + radius + j : top + radius + j + n], out=pair)  # fmt: skip
                pair *= weights[radius - j]
                acc += pair
            result[top : top + n] = acc
        out = result.T if axis == 1 else result
    return np.ascontiguousarray(out)


@functools.cache
def _compiled_filter() -> ModuleType | None:
    """poisoner/_scene_filter.c (the same values as gaussian_numpy, several times faster), or
    None where the package was built without a C compiler."""
    try:
        from poisoner import _scene_filter  # type: ignore[attr-defined]
    except ImportError:
        return None
    return _scene_filter


def maximum3(image: np.ndarray) -> np.ndarray:
    """scipy.ndimage.maximum_filter(image, size=3) ('reflect' borders: the edge pixel repeated), in
    numpy: a maximum is exact whichever way it is taken."""
    import numpy as np

    padded = np.pad(image, 1, mode="edge")
    h, w = image.shape
    rows = np.maximum(np.maximum(padded[0:h], padded[1 : h + 1]), padded[2 : h + 2])
    return np.maximum(np.maximum(rows[:, 0:w], rows[:, 1 : w + 1]), rows[:, 2 : w + 2])


def noise_sigma(gray: np.ndarray) -> float:
    """The image's noise level (grey in [0, 1]): the median absolute finest diagonal Haar coefficient
    over 0.6745 (Donoho's estimator; texture moves it little, flat areas set it), at most
    MAX_NOISE_SIGMA."""
    import numpy as np

    g = gray[: gray.shape[0] // 2 * 2, : gray.shape[1] // 2 * 2]
    diagonal = (g[0::2, 0::2] - g[0::2, 1::2] - g[1::2, 0::2] + g[1::2, 1::2]) / 2
    if diagonal.size == 0:  # a picture one pixel wide or high: no diagonal, no noise measured
        return 0.0
    return min(MAX_NOISE_SIGMA, float(array_median(np.abs(diagonal))) / 0.6745)


def array_median(values: np.ndarray) -> np.floating:
    """np.median of a non-empty array without NaNs, the same value (its partition, then the mean of
    the middle one or two): np.median itself imports numpy.ma, 18 ms of every `ppd poison` (issue 30)."""
    import numpy as np

    flat = values.ravel()
    middle = flat.size // 2
    if flat.size % 2:
        return np.partition(flat, middle)[middle]
    part = np.partition(flat, (middle - 1, middle))
    return part[middle - 1 : middle + 1].mean()


@functools.cache  # a constant of the filter: computed once, not per image
def dog_noise_gain() -> float:
    """How much of a pixel noise's standard deviation the DoG passes (its kernel's L2 norm)."""
    import numpy as np

    delta = np.zeros((33, 33), dtype=np.float32)
    delta[16, 16] = 1.0
    return float(np.sqrt((_dog(delta) ** 2).sum()))


def image_figures(gray: np.ndarray) -> ImageFigures:
    """Textured fractions and response count of one grey frame (float in [0, 1], analysis size).

    A cell is textured when its strongest DoG magnitude reaches COLMAP's peak threshold (or the
    image's noise floor, when that is higher); a response is a local extremum of the DoG magnitude
    (3x3) at or above it, what SIFT's detector would start from.
    """
    import numpy as np

    height, width = gray.shape
    dog = np.abs(_dog(gray.astype(np.float32)))
    threshold = peak_threshold(gray)
    cell = max(MIN_CELL_PX, round(CELL_FRACTION * width))
    rows, cols = max(1, height // cell), max(1, width // cell)
    crop = dog[: rows * cell, : cols * cell]
    cells = crop.reshape(rows, min(cell, height), cols, min(cell, width)).max(axis=(1, 3)) >= threshold
    band_rows, band_cols = max(1, round(EDGE_BAND * rows)), max(1, round(EDGE_BAND * cols))
    edge = np.ones_like(cells)
    edge[band_rows : rows - band_rows, band_cols : cols - band_cols] = False
    return ImageFigures(round(float(cells.mean()), 4), round(float(cells[edge].mean()), 4),
                        responses(dog, threshold), width, height)  # fmt: skip


def peak_threshold(gray: np.ndarray) -> float:
    """The DoG magnitude a response must reach: COLMAP's peak threshold, or the image's noise floor."""
    return max(PEAK_THRESHOLD, NOISE_FLOOR_SIGMAS * dog_noise_gain() * noise_sigma(gray))


def responses(dog: np.ndarray, threshold: float) -> int:
    """Local maxima (3x3) of the DoG magnitude at or above threshold."""
    return int(((dog >= threshold) & (dog == maximum3(dog))).sum())


def load_gray(path: Path, width: int = ANALYSIS_WIDTH) -> np.ndarray:
    """The image as grey floats in [0, 1], reduced to `width` (never enlarged); transparency on white,
    as NeRF-style sets are reconstructed. JPEGs are decoded at a reduced scale, as luma (cheap). Opened as
    poisoning opens it (HEIC, the decompression-bomb limit): a file it cannot read raises
    ImageFormatError."""
    return load_gray_sized(path, width)[0]


def load_gray_sized(path: Path, width: int = ANALYSIS_WIDTH) -> tuple[np.ndarray, tuple[int, int]]:
    """load_gray's picture and the image's own size (w, h) before any reduction."""
    import numpy as np
    from PIL import Image

    from poisoner.image.read import eight_bit_grey, load_decoded, open_decoded

    im = open_decoded(path, Path(path).read_bytes(), load=False)
    stored = im.size
    if im.format == "JPEG":
        # libjpeg's luma (Y) straight from the scan: no chroma IDCT, upsampling or colour conversion
        # (6-7 ms of a 12 MP photo's 32); on photos the same grey as RGB -> L within one level
        # (saturated colours: within a few). CMYK keeps its mode and converts below.
        im.draft("L", (width, max(1, im.height * width // im.width)))
    load_decoded(path, im)
    if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
        rgba = im.convert("RGBA")
        im = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        im.alpha_composite(rgba)
    gray = eight_bit_grey(im).convert("L")
    if gray.width > width:
        size = (width, max(1, round(gray.height * width / gray.width)))
        gray = gray.resize(size, Image.Resampling.BILINEAR)
    return np.asarray(gray, dtype=np.float32) / 255.0, stored


def mark_figures(width: int, height: int, spec: PatchSpec) -> tuple[float, int]:
    """(area fraction, responses) of the spec's mark alone: drawn on a flat grey frame of this size."""
    import numpy as np

    from poisoner.blend import poison_array

    flat = np.full((height, width, 3), 128, dtype=np.uint8)
    marked, _ = poison_array(flat, spec, image_key="scene-hint.png")
    changed = (marked != flat).any(axis=2)
    gray = marked.astype(np.float32).mean(axis=2) / 255.0
    rows, cols = np.nonzero(changed.any(axis=1))[0], np.nonzero(changed.any(axis=0))[0]
    if rows.size == 0:  # nothing drawn: a flat frame's DoG is zero, under any threshold
        return 0.0, 0
    # Only around the mark: elsewhere the frame is flat and its DoG zero. A pixel within the DoG's
    # reach (plus the 3x3 maximum) of the mark sees the same pixels in the crop as in the whole frame,
    # so the count is the whole frame's (tests/poisoner/test_scene.py); an 800 px frame: 65 -> 5 ms.
    reach = MARK_CROP_REACH
    top, left = max(0, int(rows[0]) - reach), max(0, int(cols[0]) - reach)
    crop = gray[top : int(rows[-1]) + reach + 1, left : int(cols[-1]) + reach + 1]
    return float(changed.mean()), responses(np.abs(_dog(crop)), peak_threshold(gray))


def evenly_spaced(paths: Sequence[Path], count: int) -> list[Path]:
    ordered = sorted(paths)
    if len(ordered) <= count:
        return ordered
    step = len(ordered) / count
    return [ordered[int(i * step)] for i in range(count)]


def scene_hint(
    dataset: str, images: Sequence[Path], spec: PatchSpec | None = None, sample: int = SAMPLE
) -> SceneHint | None:
    """The hint for a dataset from up to `sample` of its images (evenly spaced by name); None when no
    image of the sample can be read (nothing to tell). `spec`: the mark to compare with (default:
    the ladder's default spec)."""
    from poisoner.ladder import default_spec

    figures, long_sides = [], []
    for path in evenly_spaced(images, sample):
        try:
            gray, stored = load_gray_sized(path)
            figures.append(image_figures(gray))
            long_sides.append(max(stored))
        except Exception as exc:  # unreadable, not an image, too large: a hint never stops a command
            why = f"{type(exc).__name__}: {exc}".splitlines()[0]
            log.info("scene hint: image skipped", extra={"file": str(path), "error": why})
            continue
    if not figures:
        return None
    fractions = [f.textured_fraction for f in figures]
    median = float(statistics.median(fractions))  # np.median's value; it would import numpy.ma
    edge = float(statistics.median([f.edge_textured_fraction for f in figures]))
    first = figures[0]
    try:
        mark_area, mark_responses = mark_figures(first.width, first.height, spec or default_spec())
    except ValueError:  # the spec does not fit a frame this small: no comparison, the kind still holds
        mark_area, mark_responses = 0.0, 0
    kind = classify(median, edge)
    long_side = int(statistics.median(long_sides))
    return SceneHint(
        dataset=dataset, kind=kind, textured_fraction=round(median, 3),
        textured_fraction_min=round(min(fractions), 3), textured_fraction_max=round(max(fractions), 3),
        edge_textured_fraction=round(edge, 3),
        scene_responses=int(statistics.median([f.responses for f in figures])), mark_responses=mark_responses,
        mark_area_fraction=round(mark_area, 5),
        texture_per_mark=round(median / mark_area, 1) if mark_area else 0.0,
        images=len(figures), analysis_width=first.width,
        sentence=sentence(dataset, kind, median, edge, long_side), long_side=long_side,
    )  # fmt: skip
