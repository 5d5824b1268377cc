"""Issue 25, round 3: a subject filling the frame, and the creator's own mark.

`nice -n 19 python -m bench.bench_shrink fountain`   (a) a subject-filling capture that is not dtu
`nice -n 19 python -m bench.bench_shrink floor`      (b) why the crop stops at half the side
`nice -n 19 python -m bench.bench_shrink logo`       (c) the creator's logo: the file, and its picture
`nice -n 19 python -m bench.bench_shrink cost`       (d) what trying the cropped sides costs
`nice -n 19 python -m bench.bench_shrink room`       (e) the room off the subject on the 55% dtu crops

(a) fountain-P11's 11 views cropped square around the fountain (basin included) so that it fills the
frame, 800x800; the subject is a box marked by hand around the fountain in each view (FOUNTAIN_BOXES,
original pixels; its corners hold some wall, so a mark there counts as touching: conservative). Judged as
bench.bench_placement touch judges dtu's crops (same function), its rows added to touch.json there.
(b) SIFT (COLMAP's extractor, default options) on two plain 800x600 frames: the default mark whole in
one, cropped to each side in the other at another anchor; matches (mutual nearest neighbours, ratio
0.8, COLMAP's defaults) joining the same texture point of the same lane in both (within 2 px): what a
cropped copy still gives COLMAP against the whole copies of the other photos.
(c) A bold monogram (a disc with "AK" knocked out) drawn with Pillow, no download: WORK/logo/monogram.png,
what `bench.bench_placement colmap --mark-image` measures; its picture on a dtu_scan37 view:
bench/results/placement_mark_logo.png.
(d) Placing the mark on each of the 55% dtu crops (bench.bench_placement touch's crop55): round 3's
place_fitting against round 2's place_on_photo alone (same thumbnail), interleaved, median of rounds per
view; the ratio per kind of view (whole mark fits / cropped / nowhere plain even cropped).
(e) Per view of the 55% dtu crops: the share of the frame the subject mask covers and the side of the
largest square holding no subject pixel (WORK/room.json).

Results: bench/results/placement.md (touch.json via bench.bench_placement.write_markdown) and
WORK/floor.json (quoted in placement.md's analysis).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont  # PIL before anything that may load pycolmap

from bench.bench_placement import ROOT, SHARED, WORK, judge_set, shown_rgb, write_markdown

LOGO_PICTURE = ROOT / "bench" / "results" / "placement_mark_logo.png"
LOGO = WORK / "logo" / "monogram.png"

# (left, top, right, bottom) of the fountain, basin included, in each 3072x2048 view, marked by hand on
# 512 px thumbnails (about +-30 px)
FOUNTAIN_BOXES = [
    (480, 240, 1800, 1830), (468, 240, 1908, 1890), (546, 90, 2016, 1908), (528, 18, 2112, 1938),
    (528, 0, 2208, 1878), (516, 0, 2316, 1848), (630, 0, 2400, 1908), (708, 0, 2478, 1908),
    (726, 0, 2466, 1908), (768, 0, 2490, 1938), (828, 0, 2478, 1956),
]  # fmt: skip
FOUNTAIN_SIDE = 800
FOUNTAIN_PAD = 0.05  # the square crop's room around the fountain's box, of its longer side


def fountain_crop(box: tuple[int, int, int, int], size: tuple[int, int]) -> tuple[int, int, int, int]:
    """The square crop around a box (its longer side plus FOUNTAIN_PAD each way), kept in the frame."""
    x0, y0, x1, y1 = box
    side = min(round(max(x1 - x0, y1 - y0) * (1 + 2 * FOUNTAIN_PAD)), *size)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    left = int(min(max(round(cx - side / 2), 0), size[0] - side))
    top = int(min(max(round(cy - side / 2), 0), size[1] - side))
    return (left, top, left + side, top + side)


def box_mask(i: int, box: tuple[int, int, int, int], size: tuple[int, int]) -> np.ndarray:
    """Round 3's judge: the hand-marked box around the fountain, as a mask of the photo (255 = subject)."""
    mask = np.zeros((size[1], size[0]), dtype=np.uint8)
    mask[box[1] : box[3], box[0] : box[2]] = 255
    return mask


def make_fountain(folder: Path, mask_of: Callable[..., np.ndarray] = box_mask) -> tuple[Path, Path]:
    """fountain-P11's views cropped square around the fountain; mask_of(view index, box, photo size):
    the subject mask of each photo (round 4: bench.bench_fill's per-view outline)."""
    images, masks = folder / "images", folder / "masks"
    if images.exists():
        return images, masks
    images.mkdir(parents=True)
    masks.mkdir(parents=True)
    for i, box in enumerate(FOUNTAIN_BOXES):
        with Image.open(SHARED / "fountain_P11" / "images" / f"{i:04d}.jpg") as im:
            rgb = im.convert("RGB")
        crop = fountain_crop(box, rgb.size)
        mask = mask_of(i, box, rgb.size)
        out = (FOUNTAIN_SIDE, FOUNTAIN_SIDE)
        rgb.crop(crop).resize(out, Image.Resampling.LANCZOS).save(images / f"{i:04d}.png")
        Image.fromarray(mask).crop(crop).resize(out, Image.Resampling.NEAREST).save(masks / f"{i:04d}.png")
    return images, masks


def fountain(args: argparse.Namespace) -> None:
    from poisoner.ladder import default_spec
    from poisoner.subject import dataset_corner

    images, masks = make_fountain(WORK / "fountain-fill")
    new = default_spec()
    corner = dataset_corner(sorted(images.iterdir()), None, region=new.corner_region).corner
    rows = []
    old = new.replace(position=corner)  # the previous default: one corner per dataset
    designs = (("per-photo (new default)", new, "new"), (f"one corner per set ({corner}, old)", old, "old"))
    for label, spec, tag in designs:
        r = judge_set(images, masks, WORK / "fountain-fill" / f"out-{tag}", spec)
        r.update(set="fountain-fill", design=label)
        print(json.dumps({k: v for k, v in r.items() if k != "per_view"}), flush=True)
        rows.append(r)
    path = WORK / "touch.json"
    kept = [r for r in (json.loads(path.read_text()) if path.exists() else []) if r["set"] != "fountain-fill"]
    path.write_text(json.dumps(kept + rows))
    write_markdown()


# ---- (b) the floor --------------------------------------------------------------------------------------
def floor(args: argparse.Namespace) -> None:
    import pycolmap

    from poisoner.blend import apply_patch
    from poisoner.ladder import default_spec

    spec = default_spec()
    sift = pycolmap.Sift(pycolmap.FeatureExtractionOptions(), device=pycolmap.Device.cpu)
    grey = np.full((600, 800, 3), 128, dtype=np.uint8)

    def features(crop: int, anchor: tuple[int, int], key: str) -> tuple[Any, np.ndarray, np.ndarray]:
        p = spec.resolve(800, 600, key, anchor=anchor, crop=crop)
        gray = np.asarray(Image.fromarray(apply_patch(grey, p)).convert("L"))
        kp, desc = sift.extract(np.ascontiguousarray(gray))
        return p, np.asarray(kp)[:, :2], np.asarray(desc, dtype=np.float32)

    full, kpa, da = features(0, (150, 60), "v_3.png")
    rows = []
    for side in range(full.lane_size, 11, -full.block):
        cut, kpb, db = features(side if side < full.lane_size else 0, (420, 330), "v_4.png")
        good = _true_matches(full, kpa, da, cut, kpb, db)
        rows.append({"side": side, "keypoints_full": len(kpa), "keypoints_cropped": len(kpb),
                     "true_matches": good})  # fmt: skip
        print(json.dumps(rows[-1]), flush=True)
    (WORK / "floor.json").write_text(json.dumps(rows))


def _true_matches(pa: Any, kpa: np.ndarray, da: np.ndarray, pb: Any, kpb: np.ndarray, db: np.ndarray) -> int:
    """Mutual nearest neighbours passing the 0.8 ratio test whose two keypoints are the same texture
    point of the same lane (within 2 px)."""
    if len(kpa) < 2 or len(kpb) < 2:
        return 0
    da /= np.linalg.norm(da, axis=1, keepdims=True) + 1e-9
    db /= np.linalg.norm(db, axis=1, keepdims=True) + 1e-9
    dist = np.arccos(np.clip(da @ db.T, -1, 1))
    ab, ba = dist.argmin(1), dist.argmin(0)
    two = np.sort(dist, axis=1)[:, :2]
    good: int = 0
    for i, j in enumerate(ab):
        if ba[j] != i or two[i, 0] > 0.8 * two[i, 1]:
            continue
        la, lb = _lane_point(pa, kpa[i]), _lane_point(pb, kpb[j])
        good += int(la is not None and lb is not None and la[0] == lb[0] and np.hypot(*(la[1] - lb[1])) <= 2)
    return good


def _lane_point(p: Any, xy: np.ndarray) -> tuple[int, np.ndarray] | None:
    """(lane, point in its texture) of a keypoint on a lane's written square, None off the mark."""
    side = p.lane_side
    for k, (dx, dy, _) in enumerate(p.parts):
        local = xy - np.array([p.x + dx, p.y + dy])
        if (local >= -1).all() and (local <= side + 1).all():
            return k, local
    return None


# ---- (c) the creator's logo -----------------------------------------------------------------------------
def make_logo(path: Path = LOGO) -> Path:
    """A bold monogram: an opaque disc with "AK" knocked out (the alpha is the shape, as a creator's
    logo PNG has it), drawn with Pillow's built-in font."""
    path.parent.mkdir(parents=True, exist_ok=True)
    n = 512
    alpha = Image.new("L", (n, n), 0)
    draw = ImageDraw.Draw(alpha)
    draw.ellipse((8, 8, n - 8, n - 8), fill=255)
    font = ImageFont.load_default(size=250)
    draw.text((n // 2, n // 2), "AK", font=font, fill=0, anchor="mm", stroke_width=14, stroke_fill=0)
    logo = Image.new("RGBA", (n, n), (20, 20, 20, 0))
    logo.putalpha(alpha)
    logo.save(path)
    return path


def logo(args: argparse.Namespace) -> None:
    """The logo, and one dtu_scan37 view (800x600) with it as the mark: the photo, its marks enlarged
    3x (nearest neighbour) and the logo file, side by side."""
    from poisoner.formats import poison_file
    from poisoner.ladder import default_spec

    make_logo()
    spec = default_spec().replace(mark_image=str(LOGO))
    folder = WORK / "logo"
    with Image.open(SHARED / "dtu_scan37" / "images" / "000010.png") as im:
        im.convert("RGB").resize((800, 600), Image.Resampling.LANCZOS).save(folder / "000010.png")
    poison_file(folder / "000010.png", folder / "out.png", spec)
    a, b = shown_rgb(folder / "000010.png"), shown_rgb(folder / "out.png")
    ys, xs = np.nonzero(np.any(a != b, axis=2))
    x0, y0, x1, y1 = xs.min() - 8, ys.min() - 8, xs.max() + 9, ys.max() + 9
    zoom = Image.fromarray(b[y0:y1, x0:x1]).resize(((x1 - x0) * 3, (y1 - y0) * 3), Image.Resampling.NEAREST)
    with Image.open(LOGO) as lg:
        file = Image.alpha_composite(Image.new("RGBA", lg.size, (255, 255, 255, 255)), lg).convert("RGB")
    file = file.resize((160, 160), Image.Resampling.LANCZOS)
    photo = Image.fromarray(b)
    canvas = Image.new("RGB", (photo.width + 32 + max(zoom.width, file.width), photo.height), (32, 32, 32))
    canvas.paste(photo, (0, 0))
    canvas.paste(zoom, (photo.width + 16, 0))
    canvas.paste(file, (photo.width + 16, zoom.height + 16))
    canvas.save(LOGO_PICTURE, optimize=True)
    print(f"wrote {LOGO} and {LOGO_PICTURE}")


# ---- (d) the cost ---------------------------------------------------------------------------------------
def cost(args: argparse.Namespace) -> None:
    import statistics
    import time

    from poisoner.ladder import default_spec
    from poisoner.placement import place_on_photo
    from poisoner.shrink import place_fitting
    from poisoner.subject import display_detail

    spec = default_spec()
    kinds: dict[str, list[float]] = {}
    for f in sorted((WORK / "crop55" / "images").iterdir()):
        detail, o = display_detail(f.read_bytes(), f.name)
        times: dict[str, list[float]] = {"r2": [], "r3": []}
        for _ in range(5):
            for label, fn in (("r2", place_on_photo), ("r3", place_fitting)):
                t = time.perf_counter()
                _, place = fn(spec, 800, 600, f.name, o, detail)
                times[label].append(time.perf_counter() - t)
        kind = "cropped" if place.shrunk else ("whole" if place.free else "nowhere plain")
        kinds.setdefault(kind, []).append(statistics.median(times["r3"]) / statistics.median(times["r2"]))
    rows = [{"kind": k, "views": len(v), "ratio_median": round(statistics.median(v), 2)}
            for k, v in kinds.items()]  # fmt: skip
    print(json.dumps(rows))
    (WORK / "cost.json").write_text(json.dumps(rows))


# ---- (e) the room off the subject ----------------------------------------------------------------------
def largest_free_square(free: np.ndarray) -> int:
    """The side of the largest square of True pixels (the classic dynamic programme, a row at a time)."""
    h, w = free.shape
    prev = np.zeros(w + 1, dtype=np.int32)
    best = 0
    for y in range(h):
        row = np.zeros(w + 1, dtype=np.int32)
        for x in np.nonzero(free[y])[0]:
            row[x + 1] = 1 + min(prev[x + 1], row[x], prev[x])
        best = max(best, int(row.max()))
        prev = row
    return best


def room(args: argparse.Namespace) -> None:
    rows = []
    for m in sorted((WORK / "crop55" / "masks").iterdir()):
        subject = np.asarray(Image.open(m)) > 0
        rows.append({"name": m.name, "subject": round(float(subject.mean()), 3),
                     "largest_free_square": largest_free_square(~subject)})  # fmt: skip
        print(json.dumps(rows[-1]), flush=True)
    (WORK / "room.json").write_text(json.dumps(rows))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="part", required=True)
    parts = {"fountain": fountain, "floor": floor, "logo": logo, "cost": cost, "room": room}
    for name in parts:
        sub.add_parser(name)
    args = parser.parse_args(argv)
    WORK.mkdir(parents=True, exist_ok=True)
    parts[args.part](args)


if __name__ == "__main__":
    main()
