"""The hostile input corpus dropped into a watched outbox (tests/reliability/test_reliability_hostile.py):
truncated, corrupt and empty media, decompression bombs, odd modes and layouts, huge metadata,
non-media under media names, hostile file names, links out of the outbox, a FIFO and a folder;
each with what ppd must do with it. Generated, never downloaded (docs/RELIABILITY.md)."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import PIL.Image
import PIL.PngImagePlugin

from testkit.photos import texture
from testkit.reliability import make_video


@dataclass(frozen=True)
class HostileInput:
    path: Path  # where it sits (in the outbox)
    what: str  # what is hostile about it
    expect: str  # 'protected', 'refused' (failed row, one-line error, file untouched),
    # 'either' (protected or refused), 'left' (no row, nothing touched: links, FIFOs)


def _png_chunk(ctype: bytes, body: bytes) -> bytes:
    import zlib

    return len(body).to_bytes(4, "big") + ctype + body + zlib.crc32(ctype + body).to_bytes(4, "big")


def _header_bomb_png(width: int, height: int) -> bytes:
    """A valid-looking PNG whose header claims width x height 8-bit grey (a few bytes of IDAT)."""
    import zlib

    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr)
            + _png_chunk(b"IDAT", zlib.compress(b"\x00" * 1024)) + _png_chunk(b"IEND", b""))  # fmt: skip


def _image_bytes(im: PIL.Image.Image, fmt: str, **kw: object) -> bytes:
    import io

    buf = io.BytesIO()
    im.save(buf, format=fmt, **kw)
    return buf.getvalue()


def _flip_middle(data: bytes, count: int = 64) -> bytes:
    mid = len(data) // 2
    return data[:mid] + bytes(b ^ 0x5A for b in data[mid : mid + count]) + data[mid + count :]


_Put = Callable[[str | bytes, bytes, str, str], None]


def _putter(dest: Path, items: list[HostileInput]) -> _Put:
    """A writer of one hostile file into dest that records what it is and what ppd must do with it."""

    def put(name: str | bytes, data: bytes, what: str, expect: str) -> None:
        path = Path(os.fsdecode(os.path.join(os.fsencode(dest), os.fsencode(name))))
        path.write_bytes(data)
        items.append(HostileInput(path, what, expect))

    return put


def _put_broken_media(put: _Put, good: dict[str, bytes], outside: Path) -> None:
    """Truncated, corrupted and empty copies of every image format and of a video."""
    suffix = {"JPEG": ".jpg", "PNG": ".png", "WEBP": ".webp", "TIFF": ".tif"}
    clip = make_video(outside / "clip-src.mp4", seed=1).read_bytes()
    for fmt, data in [*good.items(), ("MP4", clip)]:
        ext = suffix.get(fmt, ".mp4")
        put(f"truncated-half{ext}", data[: len(data) // 2], f"truncated {fmt} (half)", "refused")
        put(f"truncated-header{ext}", data[:40], f"truncated {fmt} (40 bytes)", "refused")
        put(f"corrupt-middle{ext}", _flip_middle(data), f"corrupt {fmt} (64 bytes flipped)", "either")
        put(f"zero-byte{ext}", b"", f"zero-byte {fmt} name", "refused")


def _put_odd_images(put: _Put, rgb: PIL.Image.Image) -> None:
    """Decompression bombs and valid images in modes and layouts ppd must handle or refuse."""
    import numpy as np

    put("bomb-header.png", _header_bomb_png(100_000, 100_000), "PNG header claiming 10^10 pixels", "refused")
    grey = PIL.Image.fromarray(np.zeros((10_000, 9_500), dtype=np.uint8))
    put("bomb-zlib.png", _image_bytes(grey, "PNG", compress_level=9), "95 Mpx of zeros in ~100 KB", "refused")
    del grey
    grey16 = PIL.Image.fromarray(np.arange(96 * 96, dtype=np.uint16).reshape(96, 96) * 7)
    put("grey16.png", _image_bytes(grey16, "PNG"), "16-bit grey PNG", "protected")
    put("grey16.tif", _image_bytes(grey16, "TIFF"), "16-bit grey TIFF", "protected")
    put("cmyk.jpg", _image_bytes(rgb.convert("CMYK"), "JPEG"), "CMYK JPEG", "either")
    put("cmyk.tif", _image_bytes(rgb.convert("CMYK"), "TIFF"), "CMYK TIFF", "either")
    put("palette.png", _image_bytes(rgb.convert("P"), "PNG"), "palette PNG", "protected")
    put("palette-transparent.png", _image_bytes(rgb.convert("P"), "PNG", transparency=0),
        "palette PNG with tRNS", "protected")  # fmt: skip
    put("la.png", _image_bytes(rgb.convert("LA"), "PNG"), "grey+alpha PNG", "protected")
    frames = [rgb, rgb.transpose(PIL.Image.Transpose.FLIP_LEFT_RIGHT)]
    put("animated.png", _image_bytes(frames[0], "PNG", save_all=True, append_images=frames[1:]),
        "animated PNG (2 frames)", "refused")  # fmt: skip
    put("animated.webp", _image_bytes(frames[0], "WEBP", save_all=True, append_images=frames[1:]),
        "animated WebP (2 frames)", "refused")  # fmt: skip
    put("multipage.tif", _image_bytes(frames[0], "TIFF", save_all=True, append_images=frames[1:]),
        "multi-page TIFF", "refused")  # fmt: skip


def _put_metadata_impostors_and_names(put: _Put, rgb: PIL.Image.Image, good: dict[str, bytes]) -> None:
    """Huge metadata, non-media content under media names, and hostile file names."""
    exif = rgb.getexif()
    exif[0x9286] = b"ASCII\x00\x00\x00" + b"x" * 60_000  # UserComment: APP1 near its 64 KB limit
    put("huge-exif.jpg", _image_bytes(rgb, "JPEG", exif=exif.tobytes()), "60 KB EXIF", "protected")
    info = PIL.PngImagePlugin.PngInfo()
    info.add_text("Comment", "z" * 5_000_000, zip=False)
    put("huge-text.png", _image_bytes(rgb, "PNG", pnginfo=info), "5 MB tEXt chunk", "protected")
    put("text.jpg", b"just some notes, not a photo\n" * 10, "text file named .jpg", "refused")
    put("html.png", b"<!doctype html><html><body>hi</body></html>", "HTML named .png", "refused")
    put("elf.tif", Path(sys.executable).read_bytes()[:65536], "ELF binary named .tif", "refused")
    put("pdf.webp", b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n1 0 obj\n<<>>\nendobj\n", "PDF named .webp", "refused")
    put("text.mp4", b"not a video at all\n" * 50, "text named .mp4", "refused")
    put("jpeg-named.png", good["JPEG"], "JPEG content under a .png name", "protected")
    put("line\nbreak.png", good["PNG"], "newline in the name", "protected")
    put("bad\nname.jpg", b"not a photo", "non-image with a newline in its name", "refused")
    put(b"caf\xe9-latin1.png", good["PNG"], "non-UTF-8 name (refused: the store holds UTF-8)", "left")
    put("東京 🗼 space.jpg", good["JPEG"], "non-ASCII and spaces in the name", "protected")
    put("-rf.png", good["PNG"], "leading dash in the name", "protected")
    put("x" * 240 + ".jpg", good["JPEG"], "244-byte name", "protected")


def _put_links_and_specials(
    dest: Path, outside: Path, good: dict[str, bytes], items: list[HostileInput]
) -> None:
    """Links never followed out of the outbox (their targets must stay byte-identical), a FIFO, a folder."""
    secret = outside / "secret.png"
    secret.write_bytes(good["PNG"])
    (dest / "link-out.png").symlink_to(secret)
    items.append(HostileInput(dest / "link-out.png", "symlink to a file outside the outbox", "left"))
    (dest / "dangling.png").symlink_to(outside / "does-not-exist.png")
    items.append(HostileInput(dest / "dangling.png", "dangling symlink", "left"))
    (dest / "loop.png").symlink_to(dest / "loop.png")
    items.append(HostileInput(dest / "loop.png", "symlink to itself", "left"))
    outside_dir = outside / "album"
    outside_dir.mkdir(exist_ok=True)
    (outside_dir / "inside-linked-dir.png").write_bytes(good["PNG"])
    (dest / "linked-dir").symlink_to(outside_dir, target_is_directory=True)
    items.append(HostileInput(dest / "linked-dir" / "inside-linked-dir.png",
                              "file reached through a symlinked folder", "left"))  # fmt: skip
    hard_target = outside / "hardlinked.jpg"
    hard_target.write_bytes(good["JPEG"])
    os.link(hard_target, dest / "hardlink-out.jpg")
    items.append(HostileInput(dest / "hardlink-out.jpg", "hard link to a file outside", "protected"))
    os.mkfifo(dest / "fifo.jpg")
    items.append(HostileInput(dest / "fifo.jpg", "FIFO named .jpg (opening it would block)", "left"))
    (dest / "folder.png").mkdir()
    items.append(HostileInput(dest / "folder.png", "folder named .png", "left"))


def build_hostile_corpus(dest: Path, outside: Path) -> list[HostileInput]:
    """Write the hostile inputs into dest (an outbox dataset folder); `outside` receives the
    targets of the link tricks (it must be outside the outbox). Generated, never downloaded."""
    dest.mkdir(parents=True, exist_ok=True)
    outside.mkdir(parents=True, exist_ok=True)
    rgb = PIL.Image.fromarray(texture(5, 96))
    good = {fmt: _image_bytes(rgb, fmt) for fmt in ("JPEG", "PNG", "WEBP", "TIFF")}
    items: list[HostileInput] = []
    put = _putter(dest, items)
    _put_broken_media(put, good, outside)
    _put_odd_images(put, rgb)
    _put_metadata_impostors_and_names(put, rgb, good)
    _put_links_and_specials(dest, outside, good, items)
    return items
