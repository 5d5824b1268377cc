"""Issue 14: who wins COLMAP's two-view vote, a corner mark or the scene, at 800 px and at full size.

`nice -n 19 python -m bench.bench_mark_votes --sets dtu,dtu-full --design watermark-lanes`

Reads the features and raw matches that bench/bench_watermark.py cached for a (dataset, design) run
(WORK/<set>/runs-<design>-<spec id>/features-original-*.db: COLMAP's own SIFT, default extraction:
at most 8192 keypoint locations per image, up to 2 orientations each) and, per image pair, runs
COLMAP's two-view geometry estimation (pycolmap.estimate_two_view_geometry, the shared-focal path
that geometric verification takes for one camera without a focal prior) with RANSAC seed 0. A
keypoint belongs to the mark when it lies inside one of the image's mark squares grown by
MARGIN_PX (SIFT puts keypoints on the mark's outer edge). Per set: keypoints per image (all / on
the mark), raw matches per pair (all / mark-to-mark), inliers per pair (all / mark-to-mark), and the
pairs whose inliers are mostly the mark's. pycolmap runs in a child process (verifier.supervise);
a pair that crashes it is recorded as such and the child restarts at the next pair.
Writes bench/results/patch_votes.md's "Mark vs scene" section (the rest of the page is kept).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "patch_votes.md"
WORK = Path("/tmp/ppd-bench-watermark")
MARGIN_PX = 4
SECTION = "## Mark vs scene in COLMAP's two-view vote (issue 14)"


def mark_boxes(design: str, position: str, name: str, width: int, height: int) -> list[tuple[int, ...]]:
    """The mark squares (x0, y0, x1, y1) of one image under a bench design."""
    from testkit.watermark_designs import designs

    boxes = []
    for spec in designs()[design]:
        p = spec.replace(position=position).resolve(width, height, image_key=name)
        if p.parts:
            side = p.lane_size
            boxes += [(p.x + dx, p.y + dy, p.x + dx + side, p.y + dy + side) for dx, dy, _ in p.parts]
        else:
            boxes.append(p.box)
    return boxes


def on_mark(points: np.ndarray, boxes: list[tuple[int, ...]]) -> np.ndarray:
    hit = np.zeros(len(points), dtype=bool)
    for x0, y0, x1, y1 in boxes:
        hit |= (
            (points[:, 0] >= x0 - MARGIN_PX)
            & (points[:, 0] < x1 + MARGIN_PX)
            & (points[:, 1] >= y0 - MARGIN_PX)
            & (points[:, 1] < y1 + MARGIN_PX)
        )
    return hit


# ---- child: one pass over the pairs, one JSON line per pair -----------------------------------------
def child(db_path: str, design: str, position: str, start: int, out: str) -> None:
    from PIL import Image  # noqa: F401, I001 - PIL before pycolmap
    import pycolmap

    with pycolmap.Database.open(db_path) as db, open(out, "a") as fh:
        images = sorted(db.read_all_images(), key=lambda im: im.image_id)
        cams = {c.camera_id: c for c in db.read_all_cameras()}
        kps, marks = {}, {}
        for im in images:
            cam = cams[im.camera_id]
            kps[im.image_id] = db.read_keypoints(im.image_id)[:, :2].astype(np.float64)
            boxes = mark_boxes(design, position, im.name, cam.width, cam.height)
            marks[im.image_id] = on_mark(kps[im.image_id], boxes)
        if start == 0:
            for im in images:
                n_mark = int(marks[im.image_id].sum())
                row = {"image": im.name, "keypoints": len(kps[im.image_id]), "on_mark": n_mark}
                fh.write(json.dumps(row) + "\n")
        pairs = [(a, b) for i, a in enumerate(images) for b in images[i + 1 :]]
        opts = pycolmap.TwoViewGeometryOptions()
        opts.ransac.random_seed = 0
        for k in range(start, len(pairs)):
            a, b = pairs[k]
            fh.write(json.dumps({"pair": k, "started": True}) + "\n")
            fh.flush()
            m = db.read_matches(a.image_id, b.image_id)
            both = marks[a.image_id][m[:, 0]] & marks[b.image_id][m[:, 1]] if len(m) else np.zeros(0, bool)
            row: dict[str, Any] = {"pair": k, "matches": len(m), "mark_matches": int(both.sum())}
            if len(m) >= 15:
                ca, cb = cams[a.camera_id], cams[b.camera_id]
                g = pycolmap.estimate_two_view_geometry(
                    ca, kps[a.image_id], cb, kps[b.image_id], m.astype(np.uint32), opts
                )
                inl = np.asarray(g.inlier_matches).reshape(-1, 2)
                inl_mark = marks[a.image_id][inl[:, 0]] & marks[b.image_id][inl[:, 1]]
                row.update(config=str(g.config), inliers=len(inl), mark_inliers=int(inl_mark.sum()))
            fh.write(json.dumps(row) + "\n")
            fh.flush()


# ---- how many keypoints a mark keeps under the 8192 cap, by block size ------------------------------
BLOCK_VARIANTS = {
    "b=0.5% (8 px at 1600)": {"block_size": 0.005},
    "b=4 px": {"block_size": 4},
    "b=6 px": {"block_size": 6},
    "multiscale b=0.5%": {"pattern": "multiscale_blocks"},
}


def keypoint_child(image_dir: str, position: str, count: int, out: str) -> None:
    """SIFT (COLMAP's extractor, default options) on the first `count` images of image_dir poisoned
    with each block variant of the tilted lanes: keypoints in all / on the mark."""
    from PIL import Image  # noqa: I001 - PIL before pycolmap
    import pycolmap

    from poisoner.blend import apply_patch
    from poisoner.ladder import WATERMARK_LANES_2_SPEC

    base = WATERMARK_LANES_2_SPEC.replace(position=position)
    sift = pycolmap.Sift(pycolmap.FeatureExtractionOptions(), device=pycolmap.Device.cpu)
    names = sorted(p.name for p in Path(image_dir).glob("*.png"))[:count]
    with open(out, "w") as fh:
        for label, change in BLOCK_VARIANTS.items():
            spec = base.replace(**change)
            for name in names:
                rgb = np.asarray(Image.open(Path(image_dir) / name).convert("RGB"))
                p = spec.resolve(rgb.shape[1], rgb.shape[0], image_key=name)
                gray = np.asarray(Image.fromarray(apply_patch(rgb, p)).convert("L"))
                keypoints, _ = sift.extract(np.ascontiguousarray(gray))
                side = p.lane_size
                boxes = [(p.x + dx, p.y + dy, p.x + dx + side, p.y + dy + side) for dx, dy, _ in p.parts]
                row = {"variant": label, "image": name, "keypoints": len(keypoints)}
                row["on_mark"] = int(on_mark(np.asarray(keypoints)[:, :2], boxes).sum())
                fh.write(json.dumps(row) + "\n")
                fh.flush()


# ---- parent ---------------------------------------------------------------------------------------------
def measure(set_name: str, design: str) -> dict[str, Any]:
    from testkit.watermark_designs import designs
    from verifier.supervise import run_child

    spec_id = designs()[design][0].spec_id
    run_dir = WORK / set_name / f"runs-{design}-{spec_id}"
    dbs = [p for p in sorted(run_dir.glob("features-original-*.db")) if "-mask" not in p.name]
    if not dbs:
        raise SystemExit(f"no cached features in {run_dir}: run bench.bench_watermark on {set_name} first")
    position = json.loads((run_dir / "vis.json").read_text())["position"]
    out = run_dir / f"mark-votes-{design}.jsonl"
    out.unlink(missing_ok=True)
    start, crashed = 0, []
    while True:
        cmd = [sys.executable, "-m", "bench.bench_mark_votes", "--child", str(dbs[0]), "--design", design]
        cmd += ["--position", position, "--start", str(start), "--out", str(out)]
        outcome = run_child(cmd, log_path=run_dir / "mark-votes.log", timeout_s=3600, nice=19)
        rows = [json.loads(line) for line in out.read_text().splitlines()]
        if outcome.exited:
            break
        last = max(r["pair"] for r in rows if "pair" in r)  # the pair that was running when it died
        crashed.append(last)
        start = last + 1
    return summarise(set_name, design, rows, crashed)


def summarise(set_name: str, design: str, rows: list[dict[str, Any]], crashed: list[int]) -> dict[str, Any]:
    images = [r for r in rows if "image" in r]
    pairs = [r for r in rows if "inliers" in r]
    verified = [r for r in pairs if r["inliers"] >= 15 and r["config"] not in ("1", "7")]
    mark_won = [r for r in verified if r["mark_inliers"] > r["inliers"] - r["mark_inliers"]]

    def mean(key: str, items: list[dict[str, Any]]) -> float:
        return float(np.mean([r[key] for r in items])) if items else 0.0

    return {
        "set": set_name,
        "design": design,
        "keypoints": mean("keypoints", images),
        "kp_on_mark": mean("on_mark", images),
        "pairs": len(pairs),
        "matches": mean("matches", pairs),
        "mark_matches": mean("mark_matches", pairs),
        "verified": len(verified),
        "inliers": mean("inliers", verified),
        "mark_inliers": mean("mark_inliers", verified),
        "mark_won": len(mark_won),
        "crashed": len(crashed),
    }


def write(results: list[dict[str, Any]], argv: list[str]) -> None:
    lines = [
        SECTION,
        "",
        f"`python -m bench.bench_mark_votes {' '.join(argv)}` (bench/bench_mark_votes.py): COLMAP's SIFT "
        "(pycolmap 4.2.1, default extraction: 8192 keypoint locations, up to 2 orientations each) cached by "
        "bench_watermark; every image pair's two-view geometry with COLMAP's estimator (shared-focal path, "
        f"RANSAC seed 0). Mark = inside a mark square grown by {MARGIN_PX} px. Means per image / per pair; "
        "inliers over verified pairs (>= 15 inliers, not degenerate or watermark). mark won = pairs whose "
        "inliers are mostly mark-to-mark.",
        "",
        "| set | design | keypoints / image | on the mark | raw matches / pair | mark-to-mark "
        "| verified pairs | inliers / pair | mark inliers | scene inliers | mark won | crashed |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r['set']} | {r['design']} | {r['keypoints']:.0f} | {r['kp_on_mark']:.0f} "
            f"({100 * r['kp_on_mark'] / max(r['keypoints'], 1):.1f}%) | {r['matches']:.0f} "
            f"| {r['mark_matches']:.0f} "
            f"| {r['verified']}/{r['pairs']} | {r['inliers']:.0f} | {r['mark_inliers']:.0f} "
            f"| {r['inliers'] - r['mark_inliers']:.0f} | {r['mark_won']}/{r['verified']} | {r['crashed']} |"
        )
    old = RESULTS.read_text() if RESULTS.exists() else ""
    head = old.split(SECTION)[0].rstrip()
    kept = head + "\n\n" if head else ""
    RESULTS.write_text(kept + "\n".join(lines) + "\n")


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_mark_votes")
    ap.add_argument("--sets", default="dtu,dtu-full")
    ap.add_argument("--design", default="watermark-lanes", help="comma-separated bench_watermark designs")
    ap.add_argument("--child", default="")
    ap.add_argument("--position", default="top-left")
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--out", default="")
    ap.add_argument("--keypoints-child", default="", help="image folder: block-size variants' keypoints")
    args = ap.parse_args(argv)
    if args.keypoints_child:
        keypoint_child(args.keypoints_child, args.position, args.start, args.out)
        return
    if args.child:
        child(args.child, args.design, args.position, args.start, args.out)
        return
    results = []
    for design in args.design.split(","):
        for set_name in args.sets.split(","):
            try:
                results.append(measure(set_name, design))
            except SystemExit as exc:  # that (set, design) was not run by bench_watermark: say so, go on
                print(exc, flush=True)
                continue
            print(json.dumps(results[-1]), flush=True)
    write(results, argv)


if __name__ == "__main__":
    main(sys.argv[1:])
