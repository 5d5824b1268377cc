"""Protection at a creator's scale (issue 30): does the default mark hold at 6000 px, and why not.

Sets: `python -m testkit.creator_set OUT --views 12 --width W --height W*2/3` (a box with real
fountain-P11 crops as faces, plain backdrop, JPEG q92, poisoned by ppd's own `poison_file`).

- `verify SET --seeds 0,1 --profiles default`: `verify_folders` per seed (COLMAP's RANSAC/mapper seed,
  VerifyOptions.random_seed; a crash counts as a crash), one profile at a time, the clean reference
  cached per set, the poisoned features reused across seeds; the feature databases kept
  (`keep_cache`) for `counts`. Rows in SET/runs.json.
- `counts SET`: from the kept feature databases: keypoints kept per image (COLMAP caps them at 8192
  locations), how many lie on the mark (its changed pixels grown by 4 px), their scale (octave), raw
  matches joining mark pixels in both views vs the rest, and the same among verified inliers.
- `screen SET --labels A,B --views 4 [--published]`: features, raw matches and a verified copy of the
  first views only (no mapping): a cheap first look at a candidate mark; four views are not the set.
- `pairs SET DB [--verify]`: per verified pair of a whole verification's kept database, the mark's and
  the scene's inliers, by how many views apart the pair is (what decides the mapping).
- `poison SET --label L --block PX [--pattern P]`: a candidate mark on the same clean photos.
- `upscaled SET [--width 6000 --height 4000]`: an upscaled shared set, not a render: dtu_scan37's 25
  views (1600 x 1200, real photos) upscaled (Lanczos) to cover W x H, centre-cropped to it, JPEG q92,
  and poisoned by ppd's own file path (the default mark placed per photo); no detail finer than the
  originals' 1600 px, so it says how the mark fares at 24 MP on a capture with little fine texture.
  No gt.json: `verify` then compares with the clean run only.

Results: bench/results/protection_24mp.md (written by hand from these rows, with the commands).
"""

from __future__ import annotations

import argparse
import json
import os
import sqlite3
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

PAIR_BASE = 2147483647


def _load(path: Path) -> list[dict[str, Any]]:
    return json.loads(path.read_text()) if path.exists() else []


def verify(args: argparse.Namespace) -> None:
    from verifier.verification import VerifyOptions, verify_folders

    root = Path(args.set)
    clean, poisoned = root / "clean", Path(args.poisoned) if args.poisoned else root / "poisoned"
    label = args.label or poisoned.name
    profiles = args.profiles.split(",")
    for seed in (int(s) for s in args.seeds.split(",")):
        # one verification of every profile asked (its shared work, as `ppd verify`), one folder for
        # every seed: the poisoned features and raw matches are reused by the next seed
        out = root / "verify" / f"{label}-{'-'.join(profiles)}"
        options = VerifyOptions(
            random_seed=seed, keep_cache=True, clean_cache_dir=root / "clean-cache",
            ground_truth=root / "gt.json" if (root / "gt.json").exists() else None, visibility_images=1,
        )  # fmt: skip
        t0 = time.monotonic()
        report = verify_folders(clean, poisoned, out, profiles, options)
        wall = round(time.monotonic() - t0)
        for profile in profiles:
            rep = report.profiles[profile]
            vs = rep.vs_clean or {}
            row = {
                "set": root.name, "mark": label, "profile": profile, "seed": seed,
                "verdict": str(rep.verdict), "error": rep.error,
                "clean_registered": rep.clean.get("registered"), "registered": rep.poisoned.get("registered"),
                "poisoned_outcome": rep.poisoned.get("outcome"),
                "within5": vs.get("frac_within_5deg"), "median_rot": vs.get("median_rotation_error_deg"),
                "poisoned_vs_gt_within5": (rep.poisoned_vs_gt or {}).get("frac_within_5deg"),
                "clean_vs_gt_within5": (rep.clean_vs_gt or {}).get("frac_within_5deg"),
                "wall_s": wall, "profiles_in_run": len(profiles),
            }  # fmt: skip
            print(json.dumps(row), flush=True)
            runs = [
                r
                for r in _load(root / "runs.json")
                if (r["mark"], r["profile"], r["seed"]) != (label, profile, seed)
            ]
            (root / "runs.json").write_text(json.dumps([*runs, row], indent=1))


# ---- what of the mark survives COLMAP's feature cap --------------------------------------------------------
def _shown(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), dtype=np.int16)


def mark_masks(
    clean: Path, poisoned: Path, grow: int = 4, only: list[str] | None = None
) -> dict[str, np.ndarray]:
    """Per file: the pixels the mark changed, grown by `grow` px (a keypoint on its edge is the mark's)."""
    from scipy.ndimage import binary_dilation

    out = {}
    for f in sorted(poisoned.glob("*.jpg")):
        if only is not None and f.name not in only:
            continue
        changed = np.abs(_shown(clean / f.name) - _shown(f)).max(axis=2) > 8  # JPEG noise below 8 levels
        out[f.name] = binary_dilation(changed, iterations=grow)
    return out


def _verified_tally(db: Path, tally: Any) -> dict[str, int]:
    """The default profile's geometric verification of the raw matches (a copy), then its inliers' tally."""
    import shutil
    import tempfile

    from verifier.sfm import SfmSettings, profile_sfm_settings, verify_pairs

    with tempfile.TemporaryDirectory(prefix=".ppd-tmp-") as tmp:
        work = Path(tmp) / "work.db"
        shutil.copyfile(db, work)
        verify_pairs(work, profile_sfm_settings("default", SfmSettings()))
        con = sqlite3.connect(str(work))
        try:
            return tally("two_view_geometries", con)
        finally:
            con.close()


def db_counts(db: Path, marks: dict[str, np.ndarray], verify: bool = True) -> dict[str, Any]:
    """Keypoints per image and on the mark (with their scales), raw and verified matches mark/scene."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        names = dict(con.execute("select image_id, name from images"))
        on: dict[int, np.ndarray] = {}
        kp_total, kp_mark, scales_mark, scales_all = [], [], [], []
        for iid, n, cols, data in con.execute("select image_id, rows, cols, data from keypoints"):
            k = np.frombuffer(data, np.float32).reshape(n, cols) if n else np.zeros((0, 6), np.float32)
            m = marks[Path(names[iid]).name]
            xy = k[:, :2].astype(int)
            hit = m[np.clip(xy[:, 1], 0, m.shape[0] - 1), np.clip(xy[:, 0], 0, m.shape[1] - 1)]
            on[iid] = hit
            scale = np.sqrt(np.abs(k[:, 2] * k[:, 5] - k[:, 3] * k[:, 4])) if cols >= 6 else np.zeros(n)
            kp_total.append(int(n))
            kp_mark.append(int(hit.sum()))
            scales_mark.extend(scale[hit].tolist())
            scales_all.extend(scale.tolist())

        def tally(table: str, c: sqlite3.Connection = con) -> dict[str, int]:
            mark = scene = mixed = 0
            for pid, n, cols, data in c.execute(f"select pair_id, rows, cols, data from {table}"):
                if not n:
                    continue
                i2 = pid % PAIR_BASE
                i1 = (pid - i2) // PAIR_BASE
                mm = np.frombuffer(data, np.uint32).reshape(n, cols)
                a, b = on[i1][mm[:, 0]], on[i2][mm[:, 1]]
                mark, scene, mixed = (
                    mark + int((a & b).sum()),
                    scene + int((~a & ~b).sum()),
                    mixed + int((a ^ b).sum()),
                )
            return {"mark": mark, "scene": scene, "mixed": mixed}

        raw = tally("matches")
    finally:
        con.close()
    verified = _verified_tally(db, tally) if verify else None
    sm, sa = np.array(scales_mark), np.array(scales_all)
    return {
        "images": len(kp_total),
        "keypoints_per_image": round(float(np.mean(kp_total))),
        "mark_keypoints_per_image": round(float(np.mean(kp_mark)), 1),
        "mark_scale_median_px": round(float(np.median(sm)), 2) if sm.size else None,
        "all_scale_min_px": round(float(sa.min()), 2) if sa.size else None,
        "raw": raw,
        "verified": verified,
    }


def counts(args: argparse.Namespace) -> None:
    root = Path(args.set)
    poisoned = Path(args.poisoned) if args.poisoned else root / "poisoned"
    marks = mark_masks(root / "clean", poisoned)
    rows = []
    # the raw feature caches (keypoints and raw matches) of the clean and the poisoned side
    label = args.label or poisoned.name
    dbs = [
        *sorted((root / "verify").glob(f"{label}-*/.cache/*.db")),
        *sorted((root / "clean-cache").glob("*/*.db")),
    ][:2]
    for db in dbs:
        row = {"set": root.name, "db": str(db.relative_to(root)), **db_counts(db, marks)}
        print(json.dumps(row), flush=True)
        rows.append(row)
    (root / f"counts-{args.label or poisoned.name}.json").write_text(json.dumps(rows, indent=1))


def screen(args: argparse.Namespace) -> None:
    """A cheap look at a mark before a whole verification: features and raw matches of the first
    `views` photos (COLMAP's default extraction and exhaustive matching, in a child as everywhere),
    then `db_counts` (the default profile's geometric verification of a copy). No mapping.
    --published: the photos after the published round trip (2048 px, JPEG 85) instead."""
    from verifier.published import round_trip
    from verifier.sfm import SfmSettings, build_cache_db

    root = Path(args.set)
    for label in args.labels.split(","):
        src = root / label
        names = [f.name for f in sorted(src.glob("*.jpg"))[: args.views]]
        tag = f"{label}-{args.views}" + ("-published" if args.published else "")
        work = root / "screen" / tag
        images = work / "images"
        if args.published:
            round_trip(src, images, names, 2048, 85)
        else:
            images.mkdir(parents=True, exist_ok=True)
            for name in names:
                if not (images / name).exists():
                    (images / name).symlink_to((src / name).resolve())
        db = work / "features.db"
        t0 = time.monotonic()
        if not db.exists():
            build_cache_db(images, db, SfmSettings())
        took = round(time.monotonic() - t0)
        # the mark's pixels at full size (the clean side: where the default mark goes), then at the
        # size COLMAP was given
        marks = mark_masks(root / "clean", src if label != "clean" else root / "poisoned", only=names)
        marks = {n: _to_shape(m, images / n) for n, m in marks.items()}
        row = {
            "set": root.name,
            "mark": tag,
            "views": args.views,
            "extract_match_s": took,
            **db_counts(db, marks),
        }
        print(json.dumps(row), flush=True)
        rows = [r for r in _load(root / "screen.json") if r["mark"] != tag]
        (root / "screen.json").write_text(json.dumps([*rows, row], indent=1))


def _to_shape(mask: np.ndarray, image: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(image) as im:
        size = im.size
    if size == (mask.shape[1], mask.shape[0]):
        return mask
    small = Image.fromarray(mask.astype(np.uint8) * 255).resize(size, Image.Resampling.BOX)
    return np.asarray(small) > 0


def pairs(args: argparse.Namespace) -> None:
    """Per verified pair of a kept verified database (no COLMAP run: SQLite only): the mark's and the
    scene's inliers; summed by how many views apart the pair is."""
    import shutil
    import tempfile

    root = Path(args.set)
    poisoned = root / args.label
    marks = mark_masks(root / "clean", poisoned)
    with tempfile.TemporaryDirectory(prefix=".ppd-tmp-") as tmp:
        db = Path(args.db)
        if args.verify:  # a raw cache: the default profile's geometric verification of a copy first
            from verifier.sfm import SfmSettings, profile_sfm_settings, verify_pairs

            db = Path(tmp) / "work.db"
            shutil.copyfile(args.db, db)
            verify_pairs(db, profile_sfm_settings("default", SfmSettings()))
        by_gap = _pair_tally(db, marks)
    for gap in sorted(by_gap):
        print(json.dumps({"db": Path(args.db).name, "views_apart": gap, **by_gap[gap]}), flush=True)


def _pair_tally(db: Path, marks: dict[str, np.ndarray]) -> dict[int, dict[str, int]]:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        names = dict(con.execute("select image_id, name from images"))
        on = {}
        for iid, n, cols, data in con.execute("select image_id, rows, cols, data from keypoints"):
            k = np.frombuffer(data, np.float32).reshape(n, cols) if n else np.zeros((0, 6), np.float32)
            m = marks[Path(names[iid]).name]
            xy = k[:, :2].astype(int)
            on[iid] = m[np.clip(xy[:, 1], 0, m.shape[0] - 1), np.clip(xy[:, 0], 0, m.shape[1] - 1)]
        by_gap: dict[int, dict[str, int]] = {}
        for pid, n, cols, data in con.execute("select pair_id, rows, cols, data from two_view_geometries"):
            i2 = pid % PAIR_BASE
            i1 = (pid - i2) // PAIR_BASE
            gap = abs(int(Path(names[i1]).stem[-4:]) - int(Path(names[i2]).stem[-4:]))
            g = by_gap.setdefault(gap, {"pairs": 0, "verified": 0, "mark_won": 0, "mark": 0, "scene": 0})
            g["pairs"] += 1
            if not n:
                continue
            mm = np.frombuffer(data, np.uint32).reshape(n, cols)
            a, b = on[i1][mm[:, 0]], on[i2][mm[:, 1]]
            mark, scene = int((a & b).sum()), int((~a & ~b).sum())
            g["verified"] += 1
            g["mark_won"] += int(mark > scene)
            g["mark"] += mark
            g["scene"] += scene
    finally:
        con.close()
    return by_gap


def poison(args: argparse.Namespace) -> None:
    """A candidate mark on the same set: the default spec, another block size / pattern; ppd's file path."""
    from concurrent.futures import ProcessPoolExecutor

    from poisoner.ladder import default_spec

    root = Path(args.set)
    out = root / args.label
    out.mkdir(exist_ok=True)
    block: float | int = float(args.block) if "." in args.block else int(args.block)
    spec = default_spec().replace(block_size=block, pattern=args.pattern)
    if args.area:  # issue 30's area sweep: lanes up to this share of the frame, stacked in 45% of the height
        spec = spec.replace(patch_size=0.5, corner_region=0.45)
    files = sorted((root / "clean").glob("*.jpg"))
    with ProcessPoolExecutor(min(8, os.cpu_count() or 2)) as pool:
        list(pool.map(_poison_one, [(f, out / f.name, spec, args.area) for f in files]))
    print(json.dumps({"label": args.label, "spec": spec.to_dict(), "files": len(files)}))


def _poison_one(job: tuple[Path, Path, Any, float]) -> None:
    import poisoner.spec
    from poisoner.formats import poison_file

    src, dst, spec, area = job
    if area:  # an experiment only: ppd's cap is the visibility budget (issue 14: 1%)
        poisoner.spec.LANES_MAX_AREA = area
    poison_file(src, dst, spec)


def upscaled(args: argparse.Namespace) -> None:
    """dtu_scan37's views upscaled to cover W x H and centre-cropped (JPEG q92), then poisoned."""
    from concurrent.futures import ProcessPoolExecutor

    from PIL import Image

    from poisoner.ladder import default_spec
    from verifier.shared_data import shared_root

    root = Path(args.set)
    clean, poisoned = root / "clean", root / "poisoned"
    clean.mkdir(parents=True, exist_ok=True)
    poisoned.mkdir(exist_ok=True)
    w, h = args.width, args.height
    for src in sorted((shared_root() / "dtu_scan37" / "images").glob("*.png")):
        with Image.open(src) as im:
            scale = max(w / im.width, h / im.height)
            big = im.convert("RGB").resize((round(im.width * scale), round(im.height * scale)), Image.LANCZOS)
        x0, y0 = (big.width - w) // 2, (big.height - h) // 2
        big.crop((x0, y0, x0 + w, y0 + h)).save(clean / f"{src.stem}.jpg", quality=92)
    files = sorted(clean.glob("*.jpg"))
    with ProcessPoolExecutor(min(2, os.cpu_count() or 1)) as pool:
        list(pool.map(_poison_one, [(f, poisoned / f.name, default_spec(), 0.0) for f in files]))
    print(json.dumps({"set": str(root), "files": len(files), "size": [w, h]}))


def main(argv: list[str] | None = None) -> None:
    if argv is None and Path(sys.argv[0]).stem != Path(__file__).stem:
        argv = []  # called by `python -m bench`: its arguments are bench names, not ours
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="part")
    v = sub.add_parser("verify")
    v.add_argument("set")
    v.add_argument("--seeds", default="0,1")
    v.add_argument("--profiles", default="default")
    v.add_argument(
        "--poisoned", default="", help="another poisoned folder of the same set (a candidate mark)"
    )
    v.add_argument("--label", default="")
    c = sub.add_parser("counts")
    c.add_argument("set")
    c.add_argument("--poisoned", default="")
    c.add_argument("--label", default="")
    s = sub.add_parser("screen")
    s.add_argument("set")
    s.add_argument("--labels", default="poisoned", help="poisoned folders of the set, comma-separated")
    s.add_argument("--views", type=int, default=4)
    s.add_argument("--published", action="store_true", help="after the published round trip (2048 px, q85)")
    q = sub.add_parser("pairs")
    q.add_argument("set")
    q.add_argument("db", help="a verified feature database kept by `verify`")
    q.add_argument("--label", default="poisoned", help="the poisoned folder the database was made from")
    q.add_argument("--verify", action="store_true", help="a raw cache: verify a copy first (COLMAP)")
    p = sub.add_parser("poison")
    p.add_argument("set")
    p.add_argument("--label", required=True)
    p.add_argument("--block", required=True, help="px (an integer) or a fraction of the width (0.005)")
    p.add_argument("--pattern", default="random_blocks")
    p.add_argument("--area", type=float, default=0.0, help="lanes area cap, share of the frame (ppd: 0.0096)")
    u = sub.add_parser("upscaled")
    u.add_argument("set")
    u.add_argument("--width", type=int, default=6000)
    u.add_argument("--height", type=int, default=4000)
    args = ap.parse_args(argv)
    if args.part is None:  # hours of COLMAP on sets made by hand: run by parts, never by `python -m bench`
        print("bench_protection_24mp: run its parts on a creator set (see its docstring); nothing run")
        return
    parts = {"verify": verify, "counts": counts, "poison": poison, "screen": screen, "pairs": pairs,
             "upscaled": upscaled}
    parts[args.part](args)


if __name__ == "__main__":
    main()
