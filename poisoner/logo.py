"""A creator's own text or logo as the shape of the mark (issue 14).

Pure functions: text or a logo file plus a size in, a boolean size x size shape out (True = the
mark's pixel). The blend fills the shape with the spec's high-frequency texture and leaves every
pixel outside it untouched, so the mark reads as the creator's signature while its blocks still give
SIFT the corners it needs.

Why strokes are thickened: the texture's blocks are MIN_BLOCK_PX (4 px) or more; a glyph stroke
thinner than about two blocks holds no block corner, only its own edges. The text is rendered with
Pillow's built-in scalable font (`ImageFont.load_default(size=...)`, Pillow >= 10.1, no download)
with a stroke of a sixteenth of the font size (bold, still legible).

numpy and PIL are imported inside the functions: poisoner.spec imports this module to check a spec's
mark, and start-up paths must not pay for numpy or PIL (issue 19).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

from poisoner.errors import ExitStatus, PpdError

if TYPE_CHECKING:
    import numpy as np


class LogoError(PpdError, ValueError):
    """Text that cannot be rendered or a logo file that cannot be read as a mark."""

    exit_status = ExitStatus.USAGE


def _lines_for(words: list[str], n_lines: int) -> list[str]:
    """Words split into n_lines lines of about equal length (greedy by characters)."""
    total = sum(len(w) for w in words) + len(words) - 1
    target = total / n_lines
    lines: list[str] = []
    current: list[str] = []
    for w in words:
        if current and len(" ".join(current + [w])) > target and len(lines) < n_lines - 1:
            lines.append(" ".join(current))
            current = []
        current.append(w)
    lines.append(" ".join(current))
    return lines


def _render(lines: list[str], font_px: int) -> np.ndarray:
    """The lines rendered at font_px with a thickening stroke, cropped to their ink."""
    import numpy as np
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default(size=font_px)
    stroke = max(1, font_px // 16)
    text = "\n".join(lines)
    probe = ImageDraw.Draw(Image.new("L", (1, 1)))
    box = probe.multiline_textbbox(
        (0, 0), text, font=font, stroke_width=stroke, align="center", spacing=stroke
    )
    left, top, right, bottom = (int(round(v)) for v in box)
    canvas = Image.new("L", (right - left + 2, bottom - top + 2), 0)
    ImageDraw.Draw(canvas).multiline_text(
        (1 - left, 1 - top), text, font=font, fill=255, stroke_width=stroke, stroke_fill=255,
        align="center", spacing=stroke,
    )
    ink = np.asarray(canvas) > 127
    ys, xs = np.nonzero(ink)
    if len(xs) == 0:
        raise LogoError(f"text {' '.join(lines)!r} renders to nothing")
    return ink[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]


def _fit(ink: np.ndarray, size: int) -> np.ndarray:
    """ink scaled (nearest) to fit a size x size square, centred; aspect ratio kept."""
    import numpy as np
    from PIL import Image

    h, w = ink.shape
    k = size / max(h, w)
    nh, nw = max(1, min(size, round(h * k))), max(1, min(size, round(w * k)))
    small = Image.fromarray(ink.astype(np.uint8) * 255).resize((nw, nh), Image.Resampling.NEAREST)
    out = np.zeros((size, size), dtype=bool)
    y0, x0 = (size - nh) // 2, (size - nw) // 2
    out[y0 : y0 + nh, x0 : x0 + nw] = np.asarray(small) > 127
    return out


@lru_cache(maxsize=64)
def text_shape(text: str, size: int) -> np.ndarray:
    """Boolean size x size shape of `text`: bold glyphs, wrapped onto the number of lines that
    fills the square best (a signature "© Ana 2026" becomes two lines, a single word one line).
    """
    words = text.split()
    if not words:
        raise LogoError("mark text is empty")
    if size < 8:
        raise LogoError(f"a text mark needs at least 8 px, got {size}")
    font_px = max(12, size)  # rendered large, then scaled down: crisp at every mark size
    best: np.ndarray | None = None
    for n in range(1, min(len(words), 4) + 1):
        shape = _fit(_render(_lines_for(words, n), font_px), size)
        if best is None or shape.sum() > best.sum():
            best = shape
    assert best is not None
    best.setflags(write=False)  # cached: callers must not change it
    return best


@lru_cache(maxsize=16)
def _image_shape(path: str, size: int, mtime_ns: int) -> np.ndarray:
    import numpy as np
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            if "A" in im.getbands():
                ink = np.asarray(im.getchannel("A")) > 127
            else:  # no alpha: dark pixels are the logo
                ink = np.asarray(im.convert("L")) < 128
    except (OSError, UnidentifiedImageError) as exc:
        raise LogoError(f"cannot read logo {path}: {exc}") from exc
    ys, xs = np.nonzero(ink)
    if len(xs) == 0:
        raise LogoError(f"logo {path} has no opaque (or dark) pixel")
    shape = _fit(ink[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1], size)
    shape.setflags(write=False)
    return shape


def image_shape(path: str | Path, size: int) -> np.ndarray:
    """Boolean size x size shape of a logo file: its alpha > 127 (or, without alpha, its dark
    pixels), cropped to the logo and scaled to fit the square."""
    p = Path(path)
    try:
        mtime = p.stat().st_mtime_ns
    except OSError as exc:
        raise LogoError(f"cannot read logo {p}: {exc.strerror}") from exc
    return _image_shape(str(p), size, mtime)


def mark_shape(mark_text: str, mark_image: str, size: int) -> np.ndarray | None:
    """The mark's shape for a spec's mark_text / mark_image, None for the plain square."""
    if mark_text:
        return text_shape(mark_text, size)
    if mark_image:
        return image_shape(mark_image, size)
    return None
