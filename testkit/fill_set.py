"""A subject-filling capture with a real textured surrounding and exact masks (issue 25, round 4).

Issue 25's held-out capture: 25 views, the subject about 2/3 of the frame, a real surrounding (not a
plain studio backdrop). Made here from the shared datasets at run time, deterministically:
verifier.synthetic's scene geometry (a 2 x 2 x 2 box on a floor in front of a wall) seen from close
by (cameras on a 60 degree arc, 3.9 units from the box's centre, so the box fills about 2/3 of an
800 x 800 frame), every plane textured with a real photograph from fountain-P11:
- the box's faces (the subject): 2048 px centre crops of four views, the carved fountain (rich detail);
- the wall behind it: the brick wall, scaffold and white plaster of view 0000's right part, between
  two mirror images of itself;
- the floor: the pavement strip along view 0005's bottom edge.
Ray-cast (nearest hit, 2 x 2 supersampled), sensor noise sigma 1.5, PNG (lossless). The mask is
exact: a pixel is subject where any of its four samples hits the box (what a touch judge needs).
Real texture, synthetic geometry: not a real photo shoot (say so where it is measured).

`python -m testkit.fill_set OUT` writes OUT/images/*.png and OUT/masks/*.png (white = subject).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from verifier.shared_data import shared_root
from verifier.synthetic import Rect, SyntheticOptions, camera_poses

SIDE = 800
SUPER = 2  # samples per pixel side
NOISE_SIGMA = 1.5
OPTIONS = SyntheticOptions(
    num_views=25, width=SIDE, height=SIDE, focal=1.2 * SIDE, radius=3.9, elevation_deg=22.0,
    elevation_jitter_deg=8.0, arc_deg=60.0,
)  # fmt: skip
# (photo, crop box in its 3072 x 2048 pixels): real photographs as the planes' textures
BOX_TEXTURES = (("0001.jpg", None), ("0004.jpg", None), ("0007.jpg", None), ("0009.jpg", None))
WALL_TEXTURE = ("0000.jpg", (1820, 0, 3072, 1200))  # brick, scaffold, white plaster; mirrored beside itself
FLOOR_TEXTURE = ("0005.jpg", (1700, 1780, 3072, 2048))  # pavement and moss, right of the marker


# a scene plane: verifier.synthetic's Rect (its texture H x W here, rows along edge_v, columns along
# edge_u) and whether it is the subject
Plane = tuple[Rect, bool]


def _texture(name: str, box: tuple[int, int, int, int] | None, size: tuple[int, int]) -> np.ndarray:
    """A photo's crop (the centre 2048 x 2048 when box is None) resized to size (w, h), LANCZOS:
    about as many texture pixels as the plane covers on screen, so nearest lookup does not alias."""
    from PIL import Image

    with Image.open(shared_root() / "fountain_P11" / "images" / name) as im:
        rgb = im.convert("RGB")
    if box is None:
        w, h = rgb.size
        side = min(w, h)
        box = ((w - side) // 2, (h - side) // 2, (w + side) // 2, (h + side) // 2)
    crop = rgb.crop(box).resize(size, Image.Resampling.LANCZOS)
    return np.asarray(crop, dtype=np.float64) / 255.0


def scene() -> list[Plane]:
    a = np.array
    half = _texture(*WALL_TEXTURE, size=(800, 800))
    wall = np.concatenate([half[:, ::-1], half, half[:, ::-1]], axis=1)  # the crop between its mirrors
    floor = _texture(*FLOOR_TEXTURE, size=(1372, 536))
    planes = [
        # floor z = 0, from in front of the cameras to the wall; texture rows run away from the viewer
        (Rect(a([-8.0, 3.0, 0.0]), a([16.0, 0, 0]), a([0, -8.0, 0]), floor, 0.9), False),
        # wall y = 3, 16 x 16/3 (the texture's 3:1), its rows run down from its top
        (Rect(a([-8.0, 3.0, 16 / 3]), a([16.0, 0, 0]), a([0, 0, -16 / 3]), wall, 1.0), False),
    ]
    faces = (  # the box's faces seen from the arc (-y side), texture top at the face's top edge
        (a([-1.0, -1.0, 2.0]), a([2.0, 0, 0]), a([0, 0, -2.0]), 1.0),  # y = -1
        (a([-1.0, 1.0, 2.0]), a([0, -2.0, 0]), a([0, 0, -2.0]), 0.85),  # x = -1
        (a([1.0, -1.0, 2.0]), a([0, 2.0, 0]), a([0, 0, -2.0]), 0.75),  # x = +1
        (a([-1.0, 1.0, 2.0]), a([2.0, 0, 0]), a([0, -2.0, 0]), 0.95),  # top
    )
    for (origin, eu, ev, shade), (name, box) in zip(faces, BOX_TEXTURES, strict=True):
        planes.append((Rect(origin, eu, ev, _texture(name, box, (600, 600)), shade), True))
    return planes


def render(
    rot: np.ndarray, trans: np.ndarray, planes: list[Plane], index: int
) -> tuple[np.ndarray, np.ndarray]:
    """(RGB H x W uint8, subject mask H x W bool) of one view: nearest hit per sample, SUPER x SUPER
    samples per pixel averaged; a pixel is subject where any of its samples hits the box."""
    n = SIDE * SUPER
    f = OPTIONS.focal * SUPER
    u, v = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    dirs = np.stack([(u - n / 2) / f, (v - n / 2) / f, np.ones_like(u)], axis=-1).reshape(-1, 3) @ rot
    centre = -rot.T @ trans
    depth = np.full(dirs.shape[0], np.inf)
    colour = np.full((dirs.shape[0], 3), 0.5)
    subject = np.zeros(dirs.shape[0], dtype=bool)
    for p, is_subject in planes:
        normal = np.cross(p.edge_u, p.edge_v)
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = ((p.origin - centre) @ normal) / (dirs @ normal)
        rel = centre + dist[:, None] * dirs - p.origin
        su = rel @ p.edge_u / (p.edge_u @ p.edge_u)
        sv = rel @ p.edge_v / (p.edge_v @ p.edge_v)
        ok = (dist > 1e-6) & (dist < depth) & (su >= 0) & (su < 1) & (sv >= 0) & (sv < 1)
        th, tw = p.texture.shape[:2]
        ti = np.clip((sv[ok] * th).astype(int), 0, th - 1)
        tj = np.clip((su[ok] * tw).astype(int), 0, tw - 1)
        colour[ok] = p.texture[ti, tj] * p.shade
        depth[ok] = dist[ok]
        subject[ok] = is_subject
    if np.isinf(depth).any():
        missed = int(np.isinf(depth).sum())
        raise ValueError(f"view {index}: {missed} samples hit no plane (widen the planes)")
    img = colour.reshape(SIDE, SUPER, SIDE, SUPER, 3).mean(axis=(1, 3)) * 255
    noise = np.random.default_rng(2000 + index).normal(0, NOISE_SIGMA, img.shape)
    rgb = np.clip(np.rint(img + noise), 0, 255).astype(np.uint8)
    mask = subject.reshape(SIDE, SUPER, SIDE, SUPER).any(axis=(1, 3))
    return rgb, mask


def make_fill_set(folder: Path) -> tuple[Path, Path]:
    """(images, masks) under folder, made once (the same bytes every time)."""
    from PIL import Image

    images, masks = folder / "images", folder / "masks"
    if (folder / ".done").exists():
        return images, masks
    images.mkdir(parents=True, exist_ok=True)
    masks.mkdir(parents=True, exist_ok=True)
    planes = scene()
    for i, (rot, trans) in enumerate(camera_poses(OPTIONS)):
        rgb, mask = render(rot, trans, planes, i)
        Image.fromarray(rgb).save(images / f"view_{i:02d}.png")
        Image.fromarray(mask.astype(np.uint8) * 255).save(masks / f"view_{i:02d}.png")
    (folder / ".done").touch()
    return images, masks


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    args = ap.parse_args(argv)
    images, masks = make_fill_set(args.out)
    from PIL import Image

    shares = [float(np.mean(np.asarray(Image.open(m)) > 0)) for m in sorted(masks.iterdir())]
    print(f"{images}: {len(shares)} views, subject {np.mean(shares):.0%} of the frame "
          f"({min(shares):.0%}-{max(shares):.0%})")  # fmt: skip


if __name__ == "__main__":
    main()
