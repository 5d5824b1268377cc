"""Generated photos: random-pixel frames (PNG or JPEG by suffix), a masked set whose subject leaves
one corner free (and the checks that a mark stayed in it), smooth textures with sharp chroma edges
for the JPEG splice, an EXIF block with a GPS position, and a writer that appends in bursts."""

from __future__ import annotations

import io
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
from PIL import Image


def texture(seed: int, size: int = 256) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (rng.random((size, size, 3)) * 255).astype(np.uint8)


def write_image(path: Path, seed: int, size: int = 256) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = "JPEG" if path.suffix.lower() in (".jpg", ".jpeg") else "PNG"
    Image.fromarray(texture(seed, size)).save(path, format=fmt)
    return path


def make_image(path: Path, seed: int, size: tuple[int, int] = (160, 120)) -> Path:
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)).save(path)
    return path


def make_shoot(folder: Path, n: int) -> Path:
    """folder with n small photos v0.png ... (make_image's, seeds 0 ... n-1): a shoot to patch."""
    for i in range(n):
        make_image(folder / f"v{i}.png", i)
    return folder


MASKED_SIZE = (320, 240)


def masked_shoot(images: Path, masks: Path, n: int = 5, size: tuple[int, int] = MASKED_SIZE) -> list[Path]:
    """n textured photos and their subject masks (DTU naming: `000.png` for `000000.png`): the subject
    fills the left and the top and reaches a little into the bottom-right corner region, so that corner
    is the freest and the mark must step around the subject inside it."""
    w, h = size
    masks.mkdir(parents=True, exist_ok=True)
    files = []
    for i in range(n):
        files.append(make_image(images / f"{i:06d}.png", 20 + i, size))
        m = np.zeros((h, w), np.uint8)
        m[:, : int(0.62 * w)] = 255
        m[: h // 4, :] = 255
        m[int(0.85 * h) :, : int(0.85 * w)] = 255  # a tongue into the bottom-right corner region
        Image.fromarray(m).save(masks / f"{i:03d}.png")
    return files


def changed_pixels(original: bytes | Path, patched: Path) -> np.ndarray:
    source = io.BytesIO(original) if isinstance(original, bytes) else original
    a = np.asarray(Image.open(source).convert("RGB"))
    return np.any(a != np.asarray(Image.open(patched).convert("RGB")), axis=2)


def assert_in_corner_off_subject(changed: np.ndarray, mask_file: Path | None, corner: str) -> None:
    """Something changed, every change inside that corner's 20% x 20% region, none on the subject."""
    h, w = changed.shape
    ys, xs = np.nonzero(changed)
    assert len(xs) > 50
    in_x = xs.min() >= 0.8 * w if corner.endswith("right") else xs.max() < 0.2 * w
    in_y = ys.min() >= 0.8 * h if corner.startswith("bottom") else ys.max() < 0.2 * h
    assert in_x and in_y, (corner, xs.min(), xs.max(), ys.min(), ys.max())
    if mask_file is not None:
        subject = np.asarray(Image.open(mask_file)) > 0
        assert not np.any(changed & subject)


def textured(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    base = np.stack([128 + 90 * np.sin(xx / 17.0), 100 + 80 * np.cos(yy / 13.0), 60 + 0.4 * xx], axis=-1)
    base += 40.0 * ((xx // 11 + yy // 7) % 2)[..., None]  # sharp chroma edges: upsampling matters
    return np.clip(base + rng.normal(0, 6, base.shape), 0, 255).astype(np.uint8)


def gps_exif() -> Image.Exif:
    exif = Image.Exif()
    exif[0x010F] = "ppd-cam"
    gps = exif.get_ifd(0x8825)
    gps[1], gps[2] = "N", (48.0, 51.0, 24.0)
    return exif


def burst_writer(path: Path, data: bytes, bursts: int, gap_s: float) -> None:
    """open(path, 'ab'), write a part, close; pause; again: how some uploaders and sync tools write."""
    step = -(-len(data) // bursts)
    for i in range(bursts):
        with open(path, "ab") as f:
            f.write(data[i * step : (i + 1) * step])
        if i < bursts - 1:
            time.sleep(gap_s)


def rate_in_place(photo: Path) -> None:
    """A rating and keywords written into a JPEG in place, as a photo tagger does: exiftool when
    installed, else an APP1 XMP packet added after SOI by hand (no pixel moves either way)."""
    if shutil.which("exiftool"):
        subprocess.run(["exiftool", "-q", "-overwrite_original", "-XMP:Rating=5", "-XMP:Subject=best shot",
                        "-IPTC:Keywords=client", str(photo)], check=True)  # fmt: skip
        return
    data = photo.read_bytes()
    xmp = b"http://ns.adobe.com/xap/1.0/\x00<x:xmpmeta xmlns:x='adobe:ns:meta/'><Rating>5</Rating>"
    xmp += b"</x:xmpmeta>"
    photo.write_bytes(data[:2] + b"\xff\xe1" + (len(xmp) + 2).to_bytes(2, "big") + xmp + data[2:])
