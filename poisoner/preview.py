"""A before/after picture for humans (pure: arrays in, array out).

Layout (RGB uint8):

    | label           | label           |   captions (when labels are given)
    +-----------------+-----------------+
    |    original     |    poisoned     |   the whole picture, patch box outlined in red
    +-----------------+-----------------+
    | original zoom   | poisoned zoom   |   the patch region (plus a margin), nearest-neighbour;
    +-----------------+-----------------+   with a subject mask, its edge drawn in cyan

Large pictures are shown subsampled (every k-th pixel) so the preview stays under max_width;
the zoom row is always taken from the full-resolution arrays, so the pattern's blocks stay sharp.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from poisoner.spec import PatchPlacement, PatchSpec

GAP = 4  # pixels of dark grey between panels
OUTLINE = np.array([255, 0, 0], dtype=np.uint8)
SUBJECT_EDGE = np.array([0, 255, 255], dtype=np.uint8)
BACKGROUND = 32


def to_rgb8(pixels: np.ndarray) -> np.ndarray:
    """Any H x W (x 1..4) uint8/uint16 picture as RGB uint8; alpha composited over white."""
    arr = np.asarray(pixels)
    if arr.dtype == np.uint8 and arr.ndim == 3 and arr.shape[2] == 3:
        return arr  # already RGB uint8: a 12 MP photo is not copied through float64 twice
    if arr.dtype == np.uint16:
        arr = (arr.astype(np.uint32) * 255 + 32767) // 65535
    elif arr.dtype != np.uint8:
        raise TypeError(f"expected uint8 or uint16 pixels, got {arr.dtype}")
    arr = arr.astype(np.float64)
    if arr.ndim == 2:
        arr = arr[..., None]
    channels = arr.shape[2]
    if channels in (2, 4):
        alpha = arr[..., -1:] / 255.0
        arr = arr[..., :-1] * alpha + 255.0 * (1.0 - alpha)
    if arr.shape[2] == 1:
        arr = np.repeat(arr, 3, axis=2)
    return np.floor(arr + 0.5).astype(np.uint8)


def _outline(img: np.ndarray, box: tuple[int, int, int, int], width: int = 2) -> None:
    x0, y0, x1, y1 = box
    h, w = img.shape[:2]
    x0, y0 = max(0, x0), max(0, y0)
    x1, y1 = min(w, max(x1, x0 + 1)), min(h, max(y1, y0 + 1))
    img[y0 : min(h, y0 + width), x0:x1] = OUTLINE
    img[max(0, y1 - width) : y1, x0:x1] = OUTLINE
    img[y0:y1, x0 : min(w, x0 + width)] = OUTLINE
    img[y0:y1, max(0, x1 - width) : x1] = OUTLINE


def _hstack(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    h = max(left.shape[0], right.shape[0])
    out = np.full((h, left.shape[1] + GAP + right.shape[1], 3), BACKGROUND, dtype=np.uint8)
    out[: left.shape[0], : left.shape[1]] = left
    out[: right.shape[0], left.shape[1] + GAP :] = right
    return out


def zoom_box(placement: PatchPlacement, width: int, height: int) -> tuple[int, int, int, int]:
    """The patch box grown by a quarter of the patch on each side, clipped to the picture."""
    margin = max(2, placement.size // 4)
    x0, y0, x1, y1 = placement.box
    return (max(0, x0 - margin), max(0, y0 - margin), min(width, x1 + margin), min(height, y1 + margin))


def render_preview(
    original: np.ndarray,
    poisoned: np.ndarray,
    placement: PatchPlacement,
    *,
    max_width: int = 1600,
    labels: tuple[str, str] | None = None,
    subject: np.ndarray | None = None,
    squares: Sequence[tuple[int, int, int, int]] = (),
) -> np.ndarray:
    """Original | poisoned side by side, with a nearest-neighbour zoom of the patch region below;
    with labels, each panel gets its caption in a strip above it. subject (H x W, nonzero = the
    subject, the keep_out the poisoned picture was made with): its edge is drawn on the zooms, so
    a viewer sees the mark stop at it. squares: the mark's squares where they went to places of their
    own (MarkPlace.squares): each outlined and zoomed on its own row (their common box can be most of
    the picture, no zoom at all: a black-box review)."""
    a, b = to_rgb8(original), to_rgb8(poisoned)
    if a.shape != b.shape:
        raise ValueError(f"original {a.shape} and poisoned {b.shape} differ in size")
    if subject is not None and subject.shape[:2] != a.shape[:2]:
        raise ValueError(f"subject mask {subject.shape[:2]} does not match the picture {a.shape[:2]}")
    h, w = a.shape[:2]
    step = max(1, -(-(2 * w + GAP) // max_width))  # subsample so both panels fit max_width
    boxes = list(squares) or [placement.box]
    panels = []
    for img in (a, b):
        small = img[::step, ::step].copy()
        for x0, y0, x1, y1 in boxes:
            _outline(small, (x0 // step, y0 // step, -(-x1 // step), -(-y1 // step)))
        panels.append(small)
    rows = [_hstack(panels[0], panels[1])]
    # Each zoom is exactly as wide as the panel above it (nearest neighbour, so the blocks stay
    # sharp): the zooms fill the bottom row instead of leaving part of the canvas empty.
    panel_width = panels[0].shape[1]
    for box in boxes:
        side = box[2] - box[0]
        zx0, zy0, zx1, zy1 = zoom_box(dataclasses.replace(placement, x=box[0], y=box[1], size=side), w, h)
        zoom_size = (panel_width, max(1, round(panel_width * (zy1 - zy0) / max(1, zx1 - zx0))))
        crops = [img[zy0:zy1, zx0:zx1].copy() for img in (a, b)]
        if subject is not None:
            edge = _mask_edge(subject[zy0:zy1, zx0:zx1] > 0)
            for crop in crops:
                crop[edge] = SUBJECT_EDGE
        zooms = [_nearest(crop, zoom_size) for crop in crops]
        rows.append(_hstack(zooms[0], zooms[1]))
    width = max(r.shape[1] for r in rows)
    height = sum(r.shape[0] for r in rows) + GAP * (len(rows) - 1)
    out = np.full((height, width, 3), BACKGROUND, dtype=np.uint8)
    tops, y = [], 0
    for r in rows:
        out[y : y + r.shape[0], : r.shape[1]] = r
        tops.append(y)
        y += r.shape[0] + GAP
    if labels is None:
        return out
    left, right = labels
    panel = panel_width + GAP
    out = _caption(out, [(0, left), (panel, right)])
    for k, top in enumerate(tops[1:]):
        said = "zoom on the patch" if len(boxes) == 1 else f"zoom on square {k + 1}"
        _write(out, LABEL_HEIGHT + top, [(0, said), (panel, said)])
    return out


LABEL_HEIGHT = 18


def _mask_edge(mask: np.ndarray) -> np.ndarray:
    """The mask's pixels with a 4-neighbour outside it (its one-pixel edge)."""
    inner = mask.copy()
    inner[1:] &= mask[:-1]
    inner[:-1] &= mask[1:]
    inner[:, 1:] &= mask[:, :-1]
    inner[:, :-1] &= mask[:, 1:]
    return mask & ~inner


def _nearest(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """img resized to size (width, height) by nearest neighbour."""
    from PIL import Image

    return np.asarray(Image.fromarray(img).resize(size, Image.Resampling.NEAREST))


def _write(img: np.ndarray, y: int, texts: list[tuple[int, str]]) -> None:
    """White text with a dark box at (x, y) for each (x, text), drawn into img in place."""
    from PIL import Image, ImageDraw

    pil = Image.fromarray(img)
    draw = ImageDraw.Draw(pil)
    for x, text in texts:
        box = draw.textbbox((x + 4, y + 3), text)
        draw.rectangle((box[0] - 3, box[1] - 2, box[2] + 3, box[3] + 2), fill=(BACKGROUND,) * 3)
        draw.text((x + 4, y + 3), text, fill=(255, 255, 255))
    img[:] = np.asarray(pil)


def _caption(img: np.ndarray, texts: list[tuple[int, str]]) -> np.ndarray:
    """img with a LABEL_HEIGHT strip on top holding the texts."""
    out = np.full((img.shape[0] + LABEL_HEIGHT, img.shape[1], 3), BACKGROUND, dtype=np.uint8)
    out[LABEL_HEIGHT:] = img
    _write(out, 0, texts)
    return out


# ---- EXIF orientation: the preview shows what a viewer shows ---------------------------------
# PIL's transpose for each EXIF orientation value (as ImageOps.exif_transpose applies it).
_TRANSPOSE = {2: "FLIP_LEFT_RIGHT", 3: "ROTATE_180", 4: "FLIP_TOP_BOTTOM", 5: "TRANSPOSE",
              6: "ROTATE_270", 7: "TRANSVERSE", 8: "ROTATE_90"}  # fmt: skip


def orient(pixels: np.ndarray, orientation: int | None) -> np.ndarray:
    """Stored pixels as displayed under an EXIF orientation (1..8; anything else: unchanged)."""
    method = _TRANSPOSE.get(orientation or 1)
    if method is None:
        return pixels
    from PIL import Image

    return np.asarray(Image.fromarray(to_rgb8(pixels)).transpose(getattr(Image.Transpose, method)))


def oriented_placement(
    placement: PatchPlacement, orientation: int | None, width: int, height: int
) -> PatchPlacement:
    """The patch box of a stored width x height picture, where it shows once oriented.
    ppd places the patch in the stored pixels (poisoner.formats), so a phone photo's patch sits
    in another corner of what the viewer shows."""
    import dataclasses

    from poisoner.orientation import turn_square

    new = turn_square(placement.x, placement.y, placement.size, orientation or 1, width, height)
    return dataclasses.replace(placement, x=new[0], y=new[1])


# ---- where the mark goes (issue 25): the same answer as poison_file's ------------------------------
def planned_mark(
    path: Path, spec: PatchSpec, keep_out: np.ndarray | None = None, name: str | None = None
) -> Any:
    """(placement in stored pixels, MarkPlace or None) that poison_file gives the file at path (named
    `name`, default its own: a vault copy is judged under its dataset name), from the same bytes."""
    from PIL import Image

    from poisoner.formats import plan_mark
    from poisoner.image.keep_out import checked_keep_out

    data = Path(path).read_bytes()
    with Image.open(path) as im:
        size = im.size
    label = name or Path(path).name
    return plan_mark(label, data, size, spec, checked_keep_out(label, keep_out, size))


def shown_placement(
    placement: PatchPlacement, place: Any, orientation: int | None, width: int, height: int
) -> Any:
    """The box to outline on the shown picture: a per-photo mark's own (MarkPlace.box), else the
    stored placement turned as the picture is shown (oriented_placement)."""
    import dataclasses

    if place is not None:
        return dataclasses.replace(placement, x=place.box[0], y=place.box[1])
    return oriented_placement(placement, orientation, width, height)


def mark_line(placement: PatchPlacement, place: Any, orientation: int | None, width: int, height: int) -> str:
    """`mark at the top-centre, pixels (x0,y0)-(x1,y1) as shown (why)` for any spec."""
    if place is not None:
        return str(place.line())
    from poisoner.orientation import display_size, orientation_of, position_words

    shown = oriented_placement(placement, orientation, width, height)
    w, h = display_size(width, height, orientation_of(orientation))
    x0, y0, x1, y1 = shown.box
    words = position_words(shown.box, w, h)
    return f"mark at the {words}, within pixels ({x0},{y0})-({x1},{y1}) as shown (the spec's position)"
