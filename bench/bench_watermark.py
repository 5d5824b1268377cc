"""Issue 14: kinds of protection (paper / roaming / watermark) x datasets x COLMAP profiles, with
what a viewer sees (FLIP, verifier/visibility.py).

`nice -n 19 python -m bench.bench_watermark --dataset dtu --designs watermark,roaming
--profiles default,hardened,published,masked [--seeds 0,1] [--spec-seed 0]`

Per (dataset, design): every image is poisoned (moving and tumbling specs keyed by the file
name; watermark designs leave the subject mask alone where the dataset has one, and sit in the
corner whose region the subject covers least over the whole set); visibility is measured on the
first and middle image (worst of the two) at 1920 px display width, FLIP's default 67 ppd, with
a JPEG q85 re-encode of the same original as the budget; changed area, one-corner containment
and subject contact over every image. SfM is real pycolmap 4.2.1 in child processes
(verifier.sfm.run_sfm_job); profiles: default (3DGS convert.py), hardened (stationary filter +
ignore_watermarks), published (JPEG q85 round trip, long edge <= 2048), masked (four 20% x 20%
corner regions masked out of feature extraction). Cell: poisoned cameras within 5 deg of the
clean solution (robust similarity alignment; unregistered = failure). Clean runs use seed 0 and
are cached per dataset. One JSON line per case in WORK/results.jsonl; bench/results/watermark.md
is rebuilt after each case.

Datasets are kept small for a 2-core machine: lego 40 views at 800 px (on white, intrinsics
unknown; at 400 px its clean set registered only 3/40), dtu_scan37 25 views at 800x600 with
its subject masks (intrinsics unknown), object
(verifier/synthetic.py's box on a plain backdrop, 16 views 640x480, seed 7, held out, known
intrinsics), fountain-P11 at 1024x683.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
from PIL import Image  # PIL before anything that may load pycolmap

from bench.results_page import rewrite_keeping_analysis
from poisoner.blend import apply_patch
from poisoner.corner import choose_corner
from poisoner.motion import CORNER_MOTIONS
from poisoner.spec import PatchSpec
from testkit.watermark_designs import designs
from verifier import poses as posemod
from verifier.sfm import SfmJob, SfmSettings, profile_sfm_settings, run_sfm_job
from verifier.verification import round_trip
from verifier.visibility import box_in_one_corner, visibility_report

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ["PPD_SHARED_DATA"])  # bench/__init__.py: the checkout's ../shared/datasets
RESULTS_MD = ROOT / "bench" / "results" / "watermark.md"
WORK = Path("/tmp/ppd-bench-watermark")
RESULTS_JSONL = WORK / "results.jsonl"
PROFILES = ("default", "hardened", "published", "masked")


@dataclass(frozen=True)
class Dataset:
    name: str
    clean: Path
    masks: Path | None  # subject masks named as the images (white = subject)
    camera_params: str | None


def _shared(name: str) -> Path:
    for base in (SHARED, Path("/work/shared/datasets")):
        if (base / name).exists():
            return base / name
    raise SystemExit(f"shared dataset {name} not found")


def _resized(src: Image.Image, width: int, resample: int = Image.Resampling.LANCZOS) -> Image.Image:
    return src.resize((width, round(src.height * width / src.width)), resample)


def setup(name: str) -> Dataset:
    base = WORK / name
    clean, masks = base / "clean", base / "mask"
    if name == "lego":
        if not clean.exists():
            clean.mkdir(parents=True)
            for i in range(40):
                with Image.open(_shared("nerf_synthetic_lego") / "train" / f"r_{i}.png") as im:
                    rgba = im.convert("RGBA")
                white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
                Image.alpha_composite(white, rgba).convert("RGB").save(clean / f"r_{i}.png")
        return Dataset(name, clean, None, None)
    if name in ("dtu", "dtu-full"):
        src = _shared("dtu_scan37")
        width = 800 if name == "dtu" else 1600  # dtu-full: the set's own 1600x1200
        if not clean.exists():
            clean.mkdir(parents=True)
            masks.mkdir(parents=True, exist_ok=True)
            for p in sorted((src / "images").glob("*.png")):
                with Image.open(p) as im:
                    _resized(im.convert("RGB"), width).save(clean / p.name)
                with Image.open(src / "mask" / f"{int(p.stem):03d}.png") as m:
                    _resized(m.convert("L"), width, Image.Resampling.NEAREST).save(masks / p.name)
        return Dataset(name, clean, masks, None)
    if name == "lego-k":  # lego with its true intrinsics (camera_angle_x of transforms_train.json)
        meta = json.loads((_shared("nerf_synthetic_lego") / "transforms_train.json").read_text())
        focal = 400 / np.tan(meta["camera_angle_x"] / 2)
        return Dataset(name, setup("lego").clean, None, f"{focal:.2f},{focal:.2f},400,400,0,0,0,0")
    if name == "dtu-k":  # dtu at 800x600 with its true intrinsics given to COLMAP (calibrated path)
        base_dtu = setup("dtu")
        return Dataset(name, base_dtu.clean, base_dtu.masks, dtu_camera_params(800 / 1600))
    if name == "object":
        from verifier.synthetic import SyntheticOptions, render_scene

        opts = SyntheticOptions(
            num_views=16, width=640, height=480, focal=768.0, arc_deg=90.0, seed=7, backdrop="plain"
        )
        if not clean.exists():
            render_scene(clean, opts, base / "gt.json")
        return Dataset(name, clean, None, opts.camera_params())
    if name == "fountain":
        if not clean.exists():
            clean.mkdir(parents=True)
            for p in sorted((_shared("fountain_P11") / "images").glob("*.jpg")):
                with Image.open(p) as im:
                    _resized(im.convert("RGB"), 1024).save(clean / p.name, quality=95)
        return Dataset(name, clean, None, None)
    raise SystemExit(f"unknown dataset {name!r}: lego, dtu, dtu-full, object or fountain")


def dtu_camera_params(scale: float) -> str:
    """dtu_scan37's intrinsics (mean over its views, from P = K [R | t]) scaled to the bench size,
    as Verifier I takes them ("fx,fy,cx,cy,k1,k2,p1,p2")."""
    import scipy.linalg

    data = np.load(_shared("dtu_scan37") / "cameras_sphere.npz")
    ks = []
    for key in (k for k in data.files if k.startswith("world_mat_") and "inv" not in k):
        k, _ = scipy.linalg.rq(data[key][:3, :3])
        ks.append(np.abs(k / k[2, 2]))
    k = np.mean(ks, axis=0) * scale
    return f"{k[0, 0]:.2f},{k[1, 1]:.2f},{k[0, 2]:.2f},{k[1, 2]:.2f},0,0,0,0"


def names_of(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))


def subject_mask(ds: Dataset, name: str) -> np.ndarray | None:
    if ds.masks is None:
        return None
    with Image.open(ds.masks / name) as m:
        return np.asarray(m.convert("L")) > 127


# The designs measured here: testkit/watermark_designs.py (the product's named kinds plus issue 14's).


# ---- poisoning and visibility --------------------------------------------------------------------
def poison(ds: Dataset, design: str, specs: tuple[PatchSpec, ...], dst: Path) -> dict[str, Any]:
    """Poison every image; the visibility figures of the set."""
    names = names_of(ds.clean)
    is_mark = specs[0].motion in (*CORNER_MOTIONS, "slide")
    masks = {n: subject_mask(ds, n) for n in names}
    if is_mark and ds.masks is not None:
        corner = choose_corner(list(masks.values()), region=specs[0].corner_region)
        specs = tuple(s.replace(position=corner) for s in specs)
    dst.mkdir(parents=True, exist_ok=True)
    picks = {names[0], names[len(names) // 2]}
    vis: list[dict[str, Any]] = []
    areas, corners, touches = [], [], []
    for name in names:
        with Image.open(ds.clean / name) as im:
            pixels = np.asarray(im.convert("RGB"))
        h, w = pixels.shape[:2]
        keep_out = masks[name] if is_mark else None
        out = pixels
        for spec in specs:
            out = apply_patch(out, spec.resolve(w, h, image_key=name), keep_out)
        diff = np.any(out != pixels, axis=2)
        areas.append(float(diff.mean()))
        ys, xs = np.nonzero(diff)
        if len(xs):
            box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
            corners.append(box_in_one_corner(box, w, h, 0.2))
        if masks[name] is not None:
            touches.append(bool(np.any(diff & masks[name])))
        if name in picks:
            vis.append(visibility_report(pixels, out, subject_mask=masks[name]).to_dict())
        kwargs = {"quality": 95} if name.lower().endswith((".jpg", ".jpeg")) else {}
        Image.fromarray(out).save(dst / name, **kwargs)
    worst = max(vis, key=lambda v: v["flip_p999"])
    return {
        "position": specs[0].position,
        "flip_mean": worst["flip_mean"],
        "flip_p99": worst["flip_p99"],
        "flip_p999": worst["flip_p999"],
        "flip_max": worst["flip_max"],
        "area_above_half": worst["area_above_half"],
        "jpeg_p999": worst["jpeg_p999"],
        "p999_vs_jpeg": worst["p999_vs_jpeg"],
        "changed_area_max": max(areas),
        "all_in_one_corner": bool(corners) and all(corners),
        "touches_subject": (any(touches) if touches else None),
    }


# ---- SfM --------------------------------------------------------------------------------------------
def sfm(images: Path, work: Path, settings: SfmSettings, tag: str, source: str) -> dict[str, Any]:
    """One SfM run with a result file reused when it exists (clean runs are shared by designs).

    Features and raw matches are cached per image source and feature settings: default and
    hardened share them (they differ in verification and mapping only)."""
    result_file = work / f"{tag}.json"
    if result_file.exists():
        return json.loads(result_file.read_text())
    db = work / f"features-{source}-{settings.feature_key().replace(',', '_')}.db"
    model = work / f"model-{tag}"
    res = run_sfm_job(SfmJob(str(images), str(db), str(model), settings), timeout_s=1200)
    if res.get("outcome") != "ok" and (model / "sfm.log").exists():  # keep the log of a crash
        shutil.copy(model / "sfm.log", work / f"{tag}.log")
    shutil.rmtree(model, ignore_errors=True)
    result_file.parent.mkdir(parents=True, exist_ok=True)
    result_file.write_text(json.dumps(res))
    return res


def _unpublished(poses: dict[str, Any], names: list[str]) -> dict[str, Any]:
    """Poses keyed by the original names (the round trip appends .jpg to PNG names)."""
    return {k.removesuffix(".jpg") if k[:-4] in names else k: v for k, v in poses.items()}


def profile_images(folder: Path, profile: str, cache: Path) -> Path:
    if profile != "published":
        return folder
    return round_trip(folder, cache, names_of(folder), 2048, 85)


def run_profiles(
    ds: Dataset, pois: Path, profiles: tuple[str, ...], seeds: tuple[int, ...], pois_work: Path
) -> dict[str, Any]:
    names = names_of(ds.clean)
    base = SfmSettings(camera_params=ds.camera_params)
    out: dict[str, Any] = {}
    for profile in profiles:
        settings = profile_sfm_settings(profile, base)
        cimg = profile_images(ds.clean, profile, WORK / ds.name / "clean-published")
        source = "published" if profile == "published" else "original"
        clean = sfm(cimg, WORK / ds.name / "clean-runs", settings, f"{profile}@0", source)
        pimg = profile_images(pois, profile, pois_work / "published")
        cells = []
        for seed in seeds:
            s = msgspec.structs.replace(settings, random_seed=seed)
            t = time.time()
            res = sfm(pimg, pois_work, s, f"{profile}@{seed}", source)
            cell: dict[str, Any] = {"seed": seed, "outcome": res.get("outcome"), "s": round(time.time() - t)}
            if clean.get("outcome") == "ok" and res.get("outcome") == "ok":
                vc = posemod.compare_poses(
                    posemod.poses_from_json(_unpublished(res["poses"], names)),
                    posemod.poses_from_json(_unpublished(clean["poses"], names)),
                )
                cell.update(within5=vc["frac_within_5deg"], registered=res.get("registered"))
            cells.append(cell)
            print(f"  {ds.name} {profile} seed {seed}: {cell}", flush=True)
        out[profile] = {"clean_registered": clean.get("registered"), "n": len(names), "runs": cells}
    return out


# ---- one case and the report ----------------------------------------------------------------------------
def run_case(
    ds: Dataset, design: str, specs: tuple[PatchSpec, ...], profiles: tuple[str, ...], seeds: tuple[int, ...]
) -> None:
    spec = specs[0]
    pois_work = WORK / ds.name / f"runs-{design}-{spec.spec_id}"
    pois = pois_work / "images"
    if not pois.exists():
        shutil.rmtree(pois_work, ignore_errors=True)
        vis = poison(ds, design, specs, pois)
        pois_work.mkdir(parents=True, exist_ok=True)
        (pois_work / "vis.json").write_text(json.dumps(vis))
    vis = json.loads((pois_work / "vis.json").read_text())
    print(f"{ds.name} {design}: {json.dumps(vis)}", flush=True)
    row = {
        "dataset": ds.name,
        "design": design,
        "spec": spec.to_dict(),
        "spec_id": spec.spec_id,
        "more_specs": [s.to_dict() for s in specs[1:]],
        "visibility": vis,
        "profiles": run_profiles(ds, pois, profiles, seeds, pois_work) if profiles else {},
        "when": time.strftime("%Y-%m-%d %H:%M"),
    }
    RESULTS_JSONL.parent.mkdir(parents=True, exist_ok=True)
    with RESULTS_JSONL.open("a") as f:
        f.write(json.dumps(row) + "\n")
    write_markdown()


def _cell(p: dict[str, Any] | None) -> str:
    if not p:
        return "·"
    parts = []
    for r in p["runs"]:
        if r.get("within5") is None:
            parts.append(str(r.get("outcome")))
        else:
            parts.append(f"{100 * r['within5']:.0f}% ({r.get('registered')}/{p['n']})")
    return " ; ".join(parts)


def _spec_ids_per_name(rows: list[dict[str, Any]]) -> dict[tuple[str, str, int], set[str]]:
    """Spec ids per (dataset, design, spec seed): a design whose spec changed between runs has one
    row per spec, told apart by its spec id."""
    ids: dict[tuple[str, str, int], set[str]] = {}
    for r in rows:
        ids.setdefault((r["dataset"], r["design"], r["spec"].get("seed", 0)), set()).add(r["spec_id"])
    return ids


def write_markdown() -> None:
    rows = [json.loads(line) for line in RESULTS_JSONL.read_text().splitlines() if line.strip()]
    merged: dict[tuple[str, str], dict[str, Any]] = {}
    for r in rows:
        key = (r["dataset"], r["design"] + "|" + r["spec_id"])
        m = merged.setdefault(key, {**r, "profiles": {}})
        for k, v in r["profiles"].items():
            if k in m["profiles"]:  # more seeds of the same profile: keep every run
                seen = {x["seed"] for x in m["profiles"][k]["runs"]}
                m["profiles"][k]["runs"] += [x for x in v["runs"] if x["seed"] not in seen]
            else:
                m["profiles"][k] = v
    lines = [
        "# Issue 14: kinds of protection x datasets x COLMAP profiles, with FLIP visibility",
        "",
        "Written by `nice -n 19 python -m bench.bench_watermark` (bench/bench_watermark.py), real",
        "pycolmap 4.2.1. Visibility: worst of the first and middle image, both shown 1920 px wide at",
        "FLIP's default 67 ppd; `vs JPEG` = the mark's FLIP p99.9 / a JPEG q85 re-encode's p99.9 on the",
        "same image (<= 1: within the JPEG budget). Area: largest fraction of pixels changed in any image.",
        "Corner: every changed pixel of every image inside one 20% x 20% corner region. Subject: any",
        "changed pixel on the subject mask (dtu only). Profile cells: poisoned cameras within 5° of the",
        "clean solution (registered/images), one entry per COLMAP seed (`;`-separated).",
        "",
        "| dataset | design | FLIP mean | p99 | p99.9 | max | area FLIP>0.5 | vs JPEG | area changed "
        "| corner | subject | default | hardened | published | masked |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    ids_per_name = _spec_ids_per_name(list(merged.values()))
    for (_, _), r in sorted(merged.items()):
        v, p = r["visibility"], r["profiles"]
        subj = "-" if v["touches_subject"] is None else ("yes" if v["touches_subject"] else "no")
        seed = r["spec"].get("seed", 0)
        name = r["design"] + (f" (spec seed {seed})" if seed else "")
        if len(ids_per_name[(r["dataset"], r["design"], seed)]) > 1:
            name += f" [{r['spec_id'][:6]}]"
        lines.append(
            f"| {r['dataset']} | {name} | {v['flip_mean']:.4f} | {v['flip_p99']:.3f} | {v['flip_p999']:.3f} "
            f"| {v['flip_max']:.2f} | {100 * v['area_above_half']:.2f}% | {v['p999_vs_jpeg']:.2f} "
            f"| {100 * v['changed_area_max']:.2f}% | {'yes' if v['all_in_one_corner'] else 'no'} | {subj} "
            f"| {_cell(p.get('default'))} | {_cell(p.get('hardened'))} | {_cell(p.get('published'))} "
            f"| {_cell(p.get('masked'))} |"
        )
    lines += ["", "Specs:", ""]
    described = {
        (r["design"], r["spec_id"][:6], json.dumps([r["spec"], *r.get("more_specs", [])], sort_keys=True))
        for r in rows
    }
    for design, short_id, text in sorted(described):
        lines.append(f"- `{design}` [{short_id}]: {text}")
    rewrite_keeping_analysis(RESULTS_MD, lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_watermark")
    ap.add_argument("--dataset", choices=["lego", "lego-k", "dtu", "dtu-k", "dtu-full", "object", "fountain"])
    ap.add_argument("--pictures", action="store_true", help="--designs (all if none) on dtu 000000.png")
    ap.add_argument("--designs", default="", help=f"comma-separated: {', '.join(designs())}")
    ap.add_argument("--profiles", default=",".join(PROFILES), help="comma-separated; '' = visibility only")
    ap.add_argument("--seeds", default="0", help="COLMAP random seeds of the poisoned runs")
    ap.add_argument("--spec-seed", type=int, default=0, help="the spec's seed (texture, per-image turns)")
    args = ap.parse_args(argv if argv is not None else [])
    if args.pictures:
        dtu = _shared("dtu_scan37")
        out = RESULTS_MD.parent / "designs"
        masks = sorted((dtu / "mask").glob("*.png"))
        chosen = [d for d in args.designs.split(",") if d] or list(designs())
        rows = pictures(dtu / "images" / "000000.png", dtu / "mask" / "000.png", masks, out, chosen)
        index = out / "pictures.json"
        old = json.loads(index.read_text()) if index.exists() else []
        kept = [r for r in old if r["design"] not in chosen]  # other designs' figures stay
        index.write_text(json.dumps(kept + rows, indent=1) + "\n")
        return
    if not args.dataset or not args.designs:
        raise SystemExit("--dataset and --designs are required (or --pictures)")
    specs = designs()
    ds = setup(args.dataset)
    profiles = tuple(p for p in args.profiles.split(",") if p)
    seeds = tuple(int(s) for s in args.seeds.split(","))
    for design in args.designs.split(","):
        if design not in specs:
            raise SystemExit(f"unknown design {design!r}; choose from {', '.join(specs)}")
        # spec seed k shifts every mark's seed by k (texture and per-image poses)
        seeded = tuple(s.replace(seed=s.seed + args.spec_seed) for s in specs[design])
        run_case(ds, design, seeded, profiles, seeds)


# ---- pictures ----------------------------------------------------------------------------------------------
def pictures(
    photo: Path,
    mask: Path,
    set_masks: list[Path],
    out_dir: Path,
    chosen: list[str],
    display_width: int = 1920,
) -> list[dict[str, Any]]:
    """Each design on one real photo (full resolution), saved at display size (WebP q80), with FLIP figures.

    The watermark designs keep off this photo's subject mask and sit in the corner the subject
    covers least over the whole set (set_masks), as bench runs place them."""
    with Image.open(photo) as im:
        pixels = np.asarray(im.convert("RGB"))

    def load(p: Path) -> np.ndarray:
        with Image.open(p) as m:
            return np.asarray(m.convert("L")) > 127

    subject = load(mask)
    corner = choose_corner([load(p) for p in set_masks], region=0.2)
    rows = []
    out_dir.mkdir(parents=True, exist_ok=True)
    h, w = pixels.shape[:2]
    for design in chosen:
        specs = designs()[design]
        keep_out = subject if specs[0].motion in (*CORNER_MOTIONS, "slide") else None
        out = pixels
        for spec in specs:
            if spec.motion in (*CORNER_MOTIONS, "slide"):
                spec = spec.replace(position=corner)
            out = apply_patch(out, spec.resolve(w, h, image_key=photo.name), keep_out)
        vis = visibility_report(pixels, out, display_width=display_width, subject_mask=subject)
        shown = Image.fromarray(out).resize(
            (display_width, round(h * display_width / w)), Image.Resampling.LANCZOS
        )
        path = out_dir / f"design-{design}.webp"  # WebP q80 at display size: ~0.3 MB a picture
        shown.save(path, quality=80, method=6)
        rows.append({"design": design, "file": path.name, **vis.to_dict()})
        print(f"{design}: {json.dumps(rows[-1])}", flush=True)
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
