"""Reading an image: open and fully decode with Pillow (HEIC through pillow-heif), refusing
decompression bombs, multi-frame files and truncated data; every failure is one
ImageFormatError line. Nothing is written here."""

from __future__ import annotations

import contextlib
import io
import logging
import struct
import warnings
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from PIL import Image, ImageFile

from poisoner.errors import ImageFormatError, one_line

if TYPE_CHECKING:
    import numpy as np

log = logging.getLogger("poisoner.formats")


_heif_registered = False


def _register_heif() -> None:
    global _heif_registered
    if not _heif_registered:
        try:
            import pillow_heif

            pillow_heif.register_heif_opener()
        except ImportError:  # HEIC stays unsupported; everything else works
            log.warning("pillow-heif not installed: HEIC files are unsupported")
        _heif_registered = True


@contextlib.contextmanager
def decode_errors(src: Path) -> Iterator[None]:
    """Every failure of opening or decoding becomes one ImageFormatError line."""
    try:
        with warnings.catch_warnings():
            # Pillow only warns between MAX_IMAGE_PIXELS and twice that: refuse instead.
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            yield
    except ImageFormatError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ImageFormatError(f"{src.name}: decompression-bomb limit: {one_line(exc)}") from exc
    except Image.UnidentifiedImageError as exc:
        raise ImageFormatError(f"{src.name}: not a recognised image file") from exc
    except (OSError, SyntaxError, ValueError, struct.error, zlib.error, EOFError) as exc:
        raise ImageFormatError(f"{src.name}: cannot decode ({one_line(exc)})") from exc
    except (TypeError, KeyError, IndexError) as exc:
        # Pillow's TIFF reader raises these on corrupt tags ("Missing dimensions", a bytes
        # strip offset); found by the fuzz run. Confined to open/load, so not our bugs.
        raise ImageFormatError(f"{src.name}: cannot decode ({type(exc).__name__}: {one_line(exc)})") from exc


def open_decoded(src: Path, data: bytes, *, load: bool = True) -> Image.Image:
    """Open and (with load) fully decode; every failure becomes one ImageFormatError line.
    Without load only the header is read: the caller must decode (load_decoded) or have the
    whole file checked another way before writing anything."""
    if not data:
        raise ImageFormatError(f"{src.name}: empty file (0 bytes)")
    _register_heif()
    if data[:2] == b"\xff\xd8":  # arithmetic-coded: what ppd patches, the Huffman-coded copy (formats)
        from poisoner.image.jpeg_file import arithmetic_coding, huffman_coded

        if arithmetic_coding(data) is not None:
            data = huffman_coded(src, data)
    with decode_errors(src):
        im = as_jpeg(Image.open(io.BytesIO(data)), io.BytesIO(data))
        limit = Image.MAX_IMAGE_PIXELS
        if limit is not None and im.size[0] * im.size[1] > limit:
            raise ImageFormatError(
                f"{src.name}: {im.size[0]}x{im.size[1]} exceeds the {limit}-pixel decompression-bomb limit"
            )
        if (frames := getattr(im, "n_frames", 1)) > 1:
            raise ImageFormatError(
                f"{src.name}: {im.format} with {frames} frames/pages is not supported"
            )
        if ImageFile.LOAD_TRUNCATED_IMAGES:
            raise ImageFormatError("refusing to run with PIL LOAD_TRUNCATED_IMAGES enabled")
        if load:
            im.load()
    return im


def decoded_rgb(src: Path) -> tuple[np.ndarray, int | None]:
    """(stored RGB pixels as a numpy array, EXIF orientation or None) of the image at src, opened as
    `ppd poison` opens it (HEIC through pillow-heif, the bomb limit): what a preview shows. The
    orientation is read after the decode: Pillow turns a TIFF upright as it loads."""
    import numpy as np

    with open_decoded(src, Path(src).read_bytes()) as im:
        rgb = np.asarray(im.convert("RGB"))
        orientation = im.getexif().get(0x0112)
    return rgb, orientation if isinstance(orientation, int) else None


def as_jpeg(im: Image.Image, fp: Path | io.BytesIO) -> Image.Image:
    """A JPEG whose MPF segment indexes images appended after its picture (Pillow opens it as MPO:
    a phone's Ultra HDR gain map, a camera's preview) opened again as the JPEG it is: its own picture,
    what ppd patches (the appended images and the MPF segment are never written,
    poisoner.image.jpeg_file.without_mpf). Any other image is returned as it is."""
    if im.format != "MPO":
        return im
    from PIL import JpegImagePlugin

    im.close()
    return JpegImagePlugin.JpegImageFile(fp)


# What each writer takes (poisoner.image.png, poisoner.image.tiff, poisoner.formats' JPEG path).
PNG_MODES = ("1", "L", "LA", "P", "RGB", "RGBA", "I;16")
TIFF_MODES = ("L", "LA", "RGB", "RGBA", "I;16", "I;16B", "P", "1")


def format_refusal(im: Image.Image) -> str | None:
    """Why ppd cannot write this opened image (header only: nothing decoded) in its own format, or
    None: what the writers refuse, said before anything reaches the vault (daemon.protect.stages
    check_complete) and before a dry run or a preview claims it would be patched."""
    mode = im.mode
    if im.format == "JPEG" and mode not in ("L", "RGB"):
        return f"{mode} JPEG is not supported"
    if im.format == "TIFF":
        if mode not in TIFF_MODES:
            return f"TIFF mode {mode} is not supported"
        bits = getattr(im, "tag_v2", {}).get(258)
        if mode in ("RGB", "RGBA") and bits and max(bits) > 8:
            return "16-bit colour TIFF is not supported (Pillow reads it as 8-bit)"
    if im.format == "PNG":
        tile = getattr(im, "tile", None) or []  # an opened file's (ImageFile), read lazily
        if tile and tile[0].args == "LA;16B":  # Pillow opens it as 8-bit RGBA
            return "16-bit grey+alpha PNG is not supported (Pillow reads it as 8-bit)"
        if mode not in PNG_MODES:
            return f"PNG mode {mode} is not supported"
    return None


def check_writable_image(path: Path, name: str, max_pixels: int | None = None) -> tuple[int, int]:
    """ImageFormatError (one line naming the file) when the image at path cannot be protected in its
    own format (format_refusal) or is not an image ppd reads; only its header is read. max_pixels: the
    user's [limits] (the caller checked the size against it): Pillow's own bomb limit is raised to it,
    as the poisoner raises it, or a photo the user allowed is refused here. Returns its (width,
    height) as a viewer sees it (EXIF orientation applied), where the mark is placed."""
    from poisoner.orientation import display_size, orientation_of

    _register_heif()
    raise_bomb_limit(max_pixels)
    with decode_errors(Path(name)), Image.open(path) as opened, as_jpeg(opened, path) as im:
        if (frames := getattr(im, "n_frames", 1)) > 1:
            raise ImageFormatError(f"{name}: {im.format} with {frames} frames/pages is not supported")
        why = format_refusal(im)
        jpeg = im.format == "JPEG"
        shown = display_size(*im.size, orientation_of(_header_exif(im).get(0x0112)))
    if why is not None:
        raise ImageFormatError(f"{name}: {why}")
    if jpeg and _arithmetic_frame(path):  # coding that neither jpegtran (absent) nor Pillow reads
        from poisoner.image.jpeg_file import arithmetic_coding, check_arithmetic

        data = Path(path).read_bytes()  # the whole file only for such a JPEG (a review: every one)
        if arithmetic_coding(data) is None:
            check_arithmetic(Path(name), data)
    return shown


def _header_exif(im: Image.Image) -> Image.Exif:
    """The EXIF an opened picture's header holds, nothing decoded: Pillow's PNG getexif() decodes the
    whole picture to look for an eXIf chunk after the image data (then: none, orientation 1)."""
    if im.format != "PNG":
        return im.getexif()
    exif = Image.Exif()
    if raw := im.info.get("exif"):
        exif.load(raw)
    return exif


ARITHMETIC_SOF = frozenset({0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})  # SOF9-11, SOF13-15


def _arithmetic_frame(path: Path) -> bool:
    """Whether a JPEG's frame header (its SOF marker, before the first scan) says arithmetic coding;
    read segment by segment up to it, not the whole file."""
    with open(path, "rb") as f:
        if f.read(2) != b"\xff\xd8":
            return False
        while (byte := f.read(1)) == b"\xff" or byte:
            if byte != b"\xff":
                continue  # not a marker's start: resync
            code = f.read(1)
            while code == b"\xff":  # fill bytes
                code = f.read(1)
            if not code or code[0] in (0xDA, 0xD9):  # a scan or the end before any frame header
                return False
            if 0xC0 <= code[0] <= 0xCF and code[0] not in (0xC4, 0xC8, 0xCC):
                return code[0] in ARITHMETIC_SOF
            if 0xD0 <= code[0] <= 0xD7 or code[0] == 0x01:
                continue  # markers without a length
            size = f.read(2)
            if len(size) < 2:
                return False
            f.seek(int.from_bytes(size, "big") - 2, 1)
    return False


def raise_bomb_limit(max_pixels: int | None) -> None:
    """Pillow's decompression-bomb limit raised (never lowered) to the user's [limits] max_pixels."""
    if max_pixels is not None and (Image.MAX_IMAGE_PIXELS or 0) < max_pixels:
        Image.MAX_IMAGE_PIXELS = max_pixels


def load_decoded(src: Path, im: Image.Image) -> Image.Image:
    with decode_errors(src):
        im.load()
    return im


def eight_bit_grey(im: Image.Image) -> Image.Image:
    """16-bit grey (a PNG's I;16, or I) as the 8-bit grey a display shows: its top byte. Pillow
    serves it badly: its reduce (a thumbnail of a photo 4x the size) refuses the mode, and its
    conversion to L clips every level over 255 to white, a flat picture with no detail anywhere."""
    import numpy as np

    if not (im.mode.startswith("I;16") or im.mode == "I"):
        return im
    levels = np.clip(np.asarray(im), 0, 65535)
    if im.mode == "I" and levels.max(initial=0) <= 255:  # 32-bit integers holding 8-bit levels
        return Image.fromarray(levels.astype(np.uint8))
    return Image.fromarray((levels >> 8).astype(np.uint8))
