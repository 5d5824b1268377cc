"""A creator's shoot at full size (issue 30): N photos of W x H (6000 x 4000: 24 MP), made fast.

What the photos are: verifier.synthetic's scene geometry and cameras (a 2 x 2 x 2 box on a floor in
front of a wall, cameras on a 120 degree arc looking at it: an object on a plain backdrop, the shoot
ppd's mark is meant for) with **real photographs as the box's textures**: 2048 x 2048 crops of
fountain-P11's 3072 x 2048 photos (real fine detail at about one texture pixel per image pixel on
a 6000 px view). Each plane is drawn with PIL's perspective transform (bilinear) back to front (wall,
floor, then the box's faces that face the camera); floor and wall are plain, and every photo gets
its own sensor noise (sigma 1.5). Written as a camera would: JPEG quality 92. Real texture,
synthetic geometry and lighting: not a real photo shoot. The poisoned copies go through ppd's own
file path (`poisoner.formats.poison_file`, the default mark placed per photo, JPEG written as ppd
writes it). Ground truth: the cameras, as verifier.synthetic writes them (`gt.json`, beside the
folders).

Made in worker processes (one per core): about 3 s of CPU per 24 MP photo, where the ray-cast
renderer of verifier.synthetic took about a minute. `python -m testkit.creator_set OUT --views 40`.
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from verifier.shared_data import shared_root
from verifier.synthetic import SyntheticOptions, camera_poses, write_ground_truth

if TYPE_CHECKING:  # PIL loads in the workers only
    from PIL import Image

# The box's four faces a camera on the arc can see: (origin, edge_u, edge_v, outward normal, shade).
_A = np.array
BOX_FACES = (
    (_A([-1.0, -1.0, 2.0]), _A([2.0, 0, 0]), _A([0, 0, -2.0]), _A([0, -1.0, 0]), 1.0),  # y = -1
    (_A([-1.0, 1.0, 2.0]), _A([0, -2.0, 0]), _A([0, 0, -2.0]), _A([-1.0, 0, 0]), 0.85),  # x = -1
    (_A([1.0, -1.0, 2.0]), _A([0, 2.0, 0]), _A([0, 0, -2.0]), _A([1.0, 0, 0]), 0.75),  # x = +1
    (_A([-1.0, 1.0, 2.0]), _A([2.0, 0, 0]), _A([0, -2.0, 0]), _A([0, 0, 1.0]), 0.95),  # top
)
# Plain planes, drawn first (never in front of the box): wall y = 5, then the floor z = 0.
WALL = (_A([-5.0, 5.0, 0.0]), _A([10.0, 0, 0]), _A([0, 0, 5.0]), (236, 236, 232))
FLOOR = (_A([-5.0, -4.0, 0.0]), _A([10.0, 0, 0]), _A([0, 9.0, 0]), (214, 212, 206))
TEXTURE_SIZE = 2048
NOISE_SIGMA = 1.5
JPEG_QUALITY = 92


@dataclass(frozen=True)
class View:
    """One photo to make: its camera and where it goes."""

    index: int
    rot: np.ndarray
    trans: np.ndarray
    options: SyntheticOptions
    textures: tuple[Path, ...]
    out: Path


def intrinsics(options: SyntheticOptions) -> np.ndarray:
    w, h, f = options.width, options.height, options.focal
    return np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])


def plane_homography(
    k: np.ndarray, rot: np.ndarray, trans: np.ndarray, origin: np.ndarray, eu: np.ndarray, ev: np.ndarray,
    size: tuple[int, int],
) -> np.ndarray:  # fmt: skip
    """Texture pixel (j, i) of a size = (w, h) texture on the plane -> image pixel, as a 3 x 3 matrix."""
    tw, th = size
    return k @ np.column_stack([rot @ eu / tw, rot @ ev / th, rot @ origin + trans])


def project(k: np.ndarray, rot: np.ndarray, trans: np.ndarray, points: np.ndarray) -> np.ndarray:
    cam = points @ rot.T + trans
    if np.any(cam[:, 2] <= 0.05):
        raise ValueError("a plane corner is behind a camera: shrink the plane")
    pix = cam @ k.T
    return pix[:, :2] / pix[:, 2:]


def corners(origin: np.ndarray, eu: np.ndarray, ev: np.ndarray) -> np.ndarray:
    return np.stack([origin, origin + eu, origin + eu + ev, origin + ev])


def render(view: View) -> np.ndarray:
    """The photo, H x W x 3 uint8."""
    from PIL import Image, ImageDraw

    o = view.options
    k, rot, trans = intrinsics(o), view.rot, view.trans
    canvas = Image.new("RGB", (o.width, o.height), WALL[3])  # a studio backdrop beyond the wall
    draw = ImageDraw.Draw(canvas)
    for origin, eu, ev, colour in (WALL, FLOOR):
        quad = project(k, rot, trans, corners(origin, eu, ev))
        draw.polygon([tuple(p) for p in quad], fill=colour)
    centre = -rot.T @ trans
    for (origin, eu, ev, normal, shade), texture in zip(BOX_FACES, view.textures, strict=True):
        face_mid = origin + (eu + ev) / 2
        if float((centre - face_mid) @ normal) <= 0:  # faces away from this camera
            continue
        with Image.open(texture) as im:
            tex = _crop(im.convert("RGB"), TEXTURE_SIZE)
        if shade != 1.0:
            tex = Image.eval(tex, lambda v, s=shade: int(v * s))
        hom = plane_homography(k, rot, trans, origin, eu, ev, tex.size)
        inv = np.linalg.inv(hom)
        inv = inv / inv[2, 2]
        warped = tex.transform(canvas.size, Image.Transform.PERSPECTIVE, tuple(inv.flatten()[:8]),
                               Image.Resampling.BILINEAR)  # fmt: skip
        mask = Image.new("L", canvas.size, 0)
        quad = project(k, rot, trans, corners(origin, eu, ev))
        ImageDraw.Draw(mask).polygon([tuple(p) for p in quad], fill=255)
        canvas.paste(warped, mask=mask)
    arr = np.asarray(canvas, dtype=np.int16)
    noise = np.random.default_rng(1000 + view.index).normal(0, NOISE_SIGMA, arr.shape)
    return np.clip(arr + np.rint(noise).astype(np.int16), 0, 255).astype(np.uint8)


def _crop(im: Image.Image, size: int) -> Image.Image:
    """The centre size x size of a photo (fountain's are 3072 x 2048: its full height)."""
    w, h = im.size
    side = min(size, w, h)
    left, top = (w - side) // 2, (h - side) // 2
    return im.crop((left, top, left + side, top + side))


def make_view(view: View) -> str:
    from PIL import Image

    Image.fromarray(render(view)).save(view.out, quality=JPEG_QUALITY, subsampling=2)
    return view.out.name


def poison_view(args: tuple[Path, Path]) -> str:
    from poisoner.formats import poison_file
    from poisoner.ladder import default_spec

    src, dst = args
    poison_file(src, dst, default_spec())
    return dst.name


def make_creator_set(
    root: Path, views: int = 40, width: int = 6000, height: int = 4000, workers: int | None = None
) -> tuple[Path, Path, Path]:
    """(clean folder, poisoned folder, ground truth) under root, made once (a `.done` marks it)."""
    clean, poisoned, gt = root / "clean", root / "poisoned", root / "gt.json"
    if (poisoned / ".done").exists():
        return clean, poisoned, gt
    clean.mkdir(parents=True, exist_ok=True)
    poisoned.mkdir(exist_ok=True)
    options = SyntheticOptions(
        num_views=views, width=width, height=height, focal=1.2 * width, backdrop="plain"
    )
    fountain = sorted((shared_root() / "fountain_P11" / "images").glob("*.jpg"))
    textures = tuple(fountain[i % len(fountain)] for i in (1, 4, 7, 9))
    jobs = [
        View(i, rot, trans, options, textures, clean / f"IMG_{i:04d}.jpg")
        for i, (rot, trans) in enumerate(camera_poses(options))
    ]
    poses = {f"IMG_{v.index:04d}.jpg": (v.rot, v.trans) for v in jobs}
    with ProcessPoolExecutor(workers or os.cpu_count() or 1) as pool:
        list(pool.map(make_view, jobs))
        list(pool.map(poison_view, [(clean / n, poisoned / n) for n in poses]))
    write_ground_truth(gt, poses, options)
    (poisoned / ".done").touch()  # a dot-file: no image reader lists it
    return clean, poisoned, gt


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--width", type=int, default=6000)
    ap.add_argument("--height", type=int, default=4000)
    ap.add_argument("--workers", type=int, default=0)
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    clean, poisoned, _ = make_creator_set(args.out, args.views, args.width, args.height, args.workers or None)
    took = time.monotonic() - t0
    print(f"{args.views} views of {args.width}x{args.height} in {took:.0f} s: {clean}, {poisoned}")


if __name__ == "__main__":
    main()
