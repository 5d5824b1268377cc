"""Issue 18: can an invisible perturbation break COLMAP on a textured real scene (fountain-P11)?

`nice -n 10 python -m bench.bench_textured [--only decoys,warp,targeted] [--sfm] [--sfm-clean]` writes
bench/results/textured.md (and textured.json next to it, the raw figures); `--picture NAME[,NAME]`
writes the side-by-side pictures of measured variants, `--counters NAME` measures an attacker's
clean-ups (half size, 2 px blur) of a measured variant, `--standin-check` compares kornia's SIFT with
COLMAP's at the same keypoints (textured_standin.json), `--render` only rewrites the table. Also
`python -m bench textured` (the yardstick without full reconstructions).

Yardstick (full size, 3072x2048, COLMAP defaults, pycolmap 4.2.1 in a child process):
- visibility: FLIP (flip-evaluator, LDR, 67 px/degree) of perturbed vs original on image 0004 at a
  1920 px display width, 99.9th percentile and mean, against a JPEG q85 re-encode of the same image;
- COLMAP's view of images 0003-0006 (three adjacent pairs, the middle of the sequence): keypoints
  kept per image (default cap 8192 locations) and verified inliers per adjacent pair after COLMAP's
  geometric verification, against the mapper's thresholds (15 to keep a pair, 30 to register an image,
  100 for the initial pair);
- with --sfm, for the candidates marked `sfm`: the full 11-image reconstruction (exhaustive matching,
  as 3DGS convert.py) under the default and hardened profiles, cameras registered and the fraction
  within 5 degrees of the ground-truth cameras.
Perturbed images are written as JPEG q95 (a creator's export), like bench_verify.
"""

from __future__ import annotations

import argparse
import io
import json
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageFilter  # PIL before anything that may load pycolmap

from bench import textured_mechanisms as mech
from bench.textured_colmap import descriptors, keypoints, pair_stats

ROOT = Path(__file__).resolve().parents[1]
FOUNTAIN = ROOT.parent / "shared" / "datasets" / "fountain_P11"
RESULTS = ROOT / "bench" / "results" / "textured.md"
RAW = ROOT / "bench" / "results" / "textured.json"
STANDIN = ROOT / "bench" / "results" / "textured_standin.json"
WORK = Path("/tmp/ppd-bench-textured")
SUBSET = ["0003.jpg", "0004.jpg", "0005.jpg", "0006.jpg"]
FLIP_IMAGE = "0004.jpg"
DISPLAY_WIDTH = 1920


@dataclass(frozen=True)
class Variant:
    name: str
    mechanism: str
    transform: Callable[[np.ndarray, str], np.ndarray]  # (rgb, image name) -> rgb
    images: tuple[str, ...] = tuple(SUBSET)  # which images it changes (others are copied)
    sfm: bool = False  # a final candidate: run the full reconstruction with --sfm
    raised_cap: int = 0  # also measure with this max_num_features (the attacker raises the cap)
    box: tuple[int, int, int, int] | None = None  # changes only this window of its images (a sample)


def seed_of(name: str) -> int:
    return int(Path(name).stem)


def load(name: str) -> np.ndarray:
    return np.asarray(Image.open(FOUNTAIN / "images" / name).convert("RGB"))


def to_display(rgb: np.ndarray, factor: float) -> np.ndarray:
    im = Image.fromarray(rgb)
    size = (round(im.width * factor), round(im.height * factor))
    return np.asarray(im.resize(size, Image.LANCZOS), np.float32) / 255.0


def flip_stats(
    ref: np.ndarray, test: np.ndarray, box: tuple[int, int, int, int] | None = None
) -> dict[str, float]:
    """FLIP at the display scale of the whole image (1920 px wide), over the window box if given."""
    import flip_evaluator as flip

    factor = DISPLAY_WIDTH / ref.shape[1]
    if box is not None:
        x0, y0, x1, y1 = box
        ref, test = ref[y0:y1, x0:x1], test[y0:y1, x0:x1]
    err, mean, _ = flip.evaluate(to_display(ref, factor), to_display(test, factor), "LDR", applyMagma=False)
    return {"flip_p999": float(np.percentile(err, 99.9)), "flip_mean": float(mean)}


def jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, "JPEG", quality=quality)
    return np.asarray(Image.open(buf).convert("RGB"))


def write_variant(v: Variant, names: list[str]) -> tuple[Path, float]:
    """Perturbed copies (JPEG q95) of names in WORK/v.name; returns the folder and seconds per image."""
    out = WORK / v.name
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    spent, n = 0.0, 0
    for name in names:
        if name in v.images:
            t = time.process_time()
            rgb = v.transform(load(name), name)
            spent += time.process_time() - t
            n += 1
            Image.fromarray(rgb).save(out / name, quality=95)
        else:
            shutil.copyfile(FOUNTAIN / "images" / name, out / name)
    return out, spent / max(n, 1)


def sfm_profiles(image_dir: Path, tag: str) -> dict[str, Any]:
    """Full reconstruction under default and hardened (features cached once), scored against GT."""

    from verifier.poses import compare_poses, load_ground_truth, poses_from_json
    from verifier.sfm import SfmJob, SfmSettings, run_sfm_job

    gt = load_ground_truth(FOUNTAIN / "gt_dense_cameras")
    cache = WORK / f"cache-{tag}.db"
    cache.unlink(missing_ok=True)
    out: dict[str, Any] = {}
    for profile in ("default", "hardened"):
        settings = SfmSettings()
        if profile == "hardened":
            settings = SfmSettings(filter_stationary_matches=True, ignore_watermarks=True)
        model = WORK / f"model-{tag}-{profile}"
        shutil.rmtree(model, ignore_errors=True)
        res = run_sfm_job(SfmJob(str(image_dir), str(cache), str(model), settings), timeout_s=3000)
        if res.get("outcome") != "ok":
            out[profile] = {"outcome": res.get("outcome"), "error": res.get("error")}
            continue
        cmp = compare_poses(poses_from_json(res["poses"]), gt)
        out[profile] = {
            "registered": res["registered"],
            "num_images": res["num_images"],
            "verified_pairs": res["verified_pairs"],
            "within_5deg": cmp["frac_within_5deg"],
            "median_rot_err_deg": cmp["median_rotation_error_deg"],
            "reproj_px": res["mean_reprojection_error"],
            "elapsed_s": res["elapsed_s"],
        }
        print(f"  sfm {tag} {profile}: {out[profile]}", flush=True)
    return out


# ---- the variants ---------------------------------------------------------------------------------
_KP_CACHE: dict[str, np.ndarray] = {}


def _colmap_keypoints(name: str) -> np.ndarray:
    if name not in _KP_CACHE:
        _KP_CACHE[name] = keypoints(FOUNTAIN / "images" / name)
    return _KP_CACHE[name]


TARGET_BOX = (1024, 640, 2048, 1408)  # a 1024x768 window of 0004: the fountain's centre, textured


def _targeted(epsilon: float, steps: int, ori_sign: float = 1.0) -> Callable[[np.ndarray, str], np.ndarray]:
    def run(rgb: np.ndarray, name: str) -> np.ndarray:
        kps = _colmap_keypoints(name)
        return mech.descriptor_attack(rgb, kps, epsilon, steps, box=TARGET_BOX, ori_sign=ori_sign)

    return run


def variants() -> dict[str, list[Variant]]:
    def decoy(sigma: float, amp: float, spacing: float, sfm: bool = False) -> Variant:
        return Variant(
            f"decoys-s{sigma:g}-a{amp:g}-d{spacing:g}",
            "decoys",
            lambda rgb, n: mech.coarse_decoys(rgb, seed_of(n), sigma, amp, spacing),
            sfm=sfm,
            raised_cap=32768,
        )

    def warp(amp: float, wavelength: float, sfm: bool = False) -> Variant:
        return Variant(
            f"warp-a{amp:g}px-w{wavelength:g}px",
            "warp",
            lambda rgb, n: mech.smooth_warp(rgb, seed_of(n), amp, wavelength),
            sfm=sfm,
        )

    return {
        "decoys": [
            decoy(3, 3, 12),
            decoy(3, 6, 12),
            decoy(6, 6, 24),
            decoy(2, 6, 8),
            decoy(3, 12, 12, sfm=True),
            decoy(3, 16, 12, sfm=True),
            decoy(3, 20, 12, sfm=True),
            decoy(3, 24, 12, sfm=True),
        ],
        "warp": [warp(8, 600), warp(30, 600, sfm=True)],
        # one image of one pair only (0004): the cheapest way to cut that pair's inliers
        "targeted": [
            Variant(
                "masked-noise-e24",
                "targeted",
                lambda rgb, n: mech.masked_noise(rgb, seed_of(n), 24.0, TARGET_BOX),
                images=("0004.jpg",),
                box=TARGET_BOX,
            ),
            Variant("targeted-e8-s20", "targeted", _targeted(8.0, 20), images=("0004.jpg",), box=TARGET_BOX),
            Variant(
                "targeted-e24-s20", "targeted", _targeted(24.0, 20), images=("0004.jpg",), box=TARGET_BOX
            ),
        ],
    }


# ---- measuring and reporting ---------------------------------------------------------------------
def measure(v: Variant, do_sfm: bool) -> dict[str, Any]:
    print(f"== {v.name}", flush=True)
    names = SUBSET[:3] if v.box else SUBSET  # a windowed attack on 0004 touches 0003-0004, 0004-0005
    folder, cpu_s = write_variant(v, names)
    shown = FLIP_IMAGE if FLIP_IMAGE in v.images else v.images[0]
    row: dict[str, Any] = {"name": v.name, "mechanism": v.mechanism, "cpu_s_per_image": cpu_s}
    row.update(flip_stats(load(shown), np.asarray(Image.open(folder / shown).convert("RGB")), v.box))
    boxes = dict.fromkeys(v.images, v.box) if v.box else None
    row["colmap"] = pair_stats(folder, names, boxes=boxes)
    if v.box:
        row["box"] = v.box
        row["clean_in_box"] = pair_stats(FOUNTAIN / "images", names, boxes=boxes)
    if v.raised_cap:
        row["colmap_raised_cap"] = pair_stats(folder, SUBSET, v.raised_cap)
        row["raised_cap"] = v.raised_cap
    if do_sfm and v.sfm:
        row["sfm"] = full_sfm(v)
    print(f"  {json.dumps({k: row[k] for k in row if k != 'sfm'})}", flush=True)
    return row


def full_sfm(v: Variant) -> dict[str, Any]:
    names = sorted(p.name for p in (FOUNTAIN / "images").glob("*.jpg"))
    full, _ = write_variant(Variant(v.name + "-all", v.mechanism, v.transform, tuple(names)), names)
    return sfm_profiles(full, v.name)


def baseline(do_sfm: bool) -> dict[str, Any]:
    print("== clean / jpeg-q85", flush=True)
    ref = load(FLIP_IMAGE)
    row: dict[str, Any] = {
        "name": "clean (JPEG q85 re-encode for FLIP)",
        "mechanism": "none",
        "cpu_s_per_image": 0,
    }
    row.update(flip_stats(ref, jpeg(ref, 85)))
    row["colmap"] = pair_stats(FOUNTAIN / "images", SUBSET)
    row["colmap_raised_cap"] = pair_stats(FOUNTAIN / "images", SUBSET, 32768)
    row["raised_cap"] = 32768
    if do_sfm:
        row["sfm"] = sfm_profiles(FOUNTAIN / "images", "clean")
    return row


def _pairs(c: dict[str, Any]) -> str:
    return " / ".join(str(p["inliers"]) for p in c["pairs"])


def _inlier_cell(r: dict[str, Any]) -> str:
    if "box" not in r:
        return _pairs(r["colmap"])
    pois = " / ".join(str(p["inliers_in_box"]) for p in r["colmap"]["pairs"])
    clean = " / ".join(str(p["inliers_in_box"]) for p in r["clean_in_box"]["pairs"])
    return f"{_pairs(r['colmap'])}; in the window {pois} (clean {clean})"


def _sfm_cell(row: dict[str, Any], profile: str) -> str:
    s = row.get("sfm", {}).get(profile)
    if not s:
        return "-"
    if "registered" not in s:
        return s.get("outcome", "?")
    cell = f"{s['registered']}/{s['num_images']}, {100 * s['within_5deg']:.0f}%"
    if s.get("median_rot_err_deg") is None:  # nothing registered
        return f"**{cell}**"
    return f"{cell} (median {s['median_rot_err_deg']:.2f}°, reproj {s['reproj_px']:.2f} px)"


def render(rows: list[dict[str, Any]], command: str) -> str:
    lines = [
        "# Textured real scene: fountain-P11 against invisible perturbations (issue 18)",
        "",
        f"`{command}` ({time.strftime('%Y-%m-%d %H:%M')} UTC, pycolmap 4.2.1, shared 2-core CPU). "
        "Full-size images (3072x2048, below COLMAP's 3200 px limit, so COLMAP sees them unscaled). "
        f"FLIP on {FLIP_IMAGE} at {DISPLAY_WIDTH} px display width (p99.9 / mean); the first row is a "
        "JPEG q85 re-encode of the original: the visibility budget. Keypoints: COLMAP SIFT kept per image "
        "(default cap 8192 locations, up to 2 orientations each). Inliers: COLMAP-verified inliers of the "
        "adjacent pairs 0003-0004 / 0004-0005 / 0005-0006 (thresholds: 15 keeps a pair, 30 registers an "
        "image, 100 for the initial pair). SfM: the full 11-image reconstruction (exhaustive), registered "
        "cameras and the fraction within 5 deg of ground truth. CPU: process time per 6 MP image "
        "(x2 for a 12 MP image); for the targeted rows per 1024x768 window of 0004 (x15 for 12 MP). "
        "Targeted rows and their control change only that window of 0004 and measure its two pairs.",
        "",
        "| variant | FLIP p99.9 / mean | keypoints / image | inliers per adjacent pair | "
        "inliers, cap raised | SfM default | SfM hardened | CPU s / image |",
        "|---|---|---|---|---|---|---|---|",
    ]
    order = {"none": 0, "decoys": 1, "warp": 2, "targeted": 3}
    rows = sorted(rows, key=lambda r: (order.get(r["mechanism"], 9), r["flip_p999"]))
    for r in rows:
        c = r["colmap"]
        kp = np.mean([i["keypoints"] for i in c["images"].values()])
        raised = (
            f"{_pairs(r['colmap_raised_cap'])} (cap {r['raised_cap']})" if "colmap_raised_cap" in r else "-"
        )
        lines.append(
            f"| {r['name']} | {r['flip_p999']:.3f} / {r['flip_mean']:.3f} | {kp:.0f} | {_inlier_cell(r)} "
            f"| {raised} | "
            f"{_sfm_cell(r, 'default')} | {_sfm_cell(r, 'hardened')} | {r['cpu_s_per_image']:.1f} |"
        )
    for r in rows:
        for tag, c in r.get("counters", {}).items():
            lines += ["", f"{r['name']}, after the attacker's clean-up '{tag}': inliers {_pairs(c)}."]
    return "\n".join(lines) + "\n"


COUNTERS: dict[str, Callable[[Image.Image], Image.Image]] = {
    "half size": lambda im: im.resize((im.width // 2, im.height // 2), Image.LANCZOS),
    "blur 2 px": lambda im: im.filter(ImageFilter.GaussianBlur(2)),
}


def counters(name: str) -> dict[str, Any]:
    """An attacker's cheap clean-ups of a measured variant's images, then COLMAP's view again."""
    out = {}
    for tag, clean_up in COUNTERS.items():
        folder = WORK / f"{name}-counter-{tag.replace(' ', '-')}"
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        for n in SUBSET:
            clean_up(Image.open(WORK / name / n)).save(folder / n, quality=95)
        out[tag] = pair_stats(folder, SUBSET)
        print(f"  {name} after {tag}: {_pairs(out[tag])}", flush=True)
    return out


def standin_check() -> dict[str, Any]:
    """Does the kornia stand-in compute COLMAP's descriptor? Same keypoints, compare the vectors."""
    kps, ref = descriptors(FOUNTAIN / "images" / FLIP_IMAGE, TARGET_BOX)
    x0, y0, x1, y1 = TARGET_BOX
    gray = np.asarray(Image.open(FOUNTAIN / "images" / FLIP_IMAGE).convert("L"))[y0:y1, x0:x1]
    out = []
    for magnif in (4.0, 6.0, 8.5):
        for sign in (1.0, -1.0):
            for offset in (0.0, 90.0):
                d = mech.standin_descriptors(gray, kps, magnif, sign, offset)
                nearest = (d @ ref.T).argmax(1) == np.arange(len(d))
                out.append(
                    {
                        "magnif": magnif,
                        "ori_sign": sign,
                        "ori_offset": offset,
                        "median_cosine": float(np.median((d * ref).sum(1))),
                        "nearest_is_same": float(nearest.mean()),
                    }
                )
                print(f"  stand-in {out[-1]}", flush=True)
    return {"keypoints": len(kps), "settings": out}


def picture(name: str) -> Path:
    """Clean | perturbed, a 800x560 window of 0004 at display size (the image shown 1920 px wide)."""
    factor = DISPLAY_WIDTH / 3072
    x0, y0 = 560, 360  # display pixels: the fountain's centre, where the window attack also worked
    panels = []
    for path in (FOUNTAIN / "images" / FLIP_IMAGE, WORK / name / FLIP_IMAGE):
        im = Image.open(path).convert("RGB")
        im = im.resize((round(im.width * factor), round(im.height * factor)), Image.LANCZOS)
        panels.append(im.crop((x0, y0, x0 + 800, y0 + 560)))
    both = Image.new("RGB", (1610, 560), (255, 255, 255))
    both.paste(panels[0], (0, 0))
    both.paste(panels[1], (810, 0))
    out = RESULTS.with_name(f"textured_{name}.png")
    both.save(out)
    return out


def save(rows: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Merge rows into textured.json (re-read first: another run may have added rows meanwhile)."""
    merged = json.loads(RAW.read_text()) if RAW.exists() else {}
    merged.update(rows)
    RAW.write_text(json.dumps(merged, indent=1))
    for name, row in rows.items():  # a copy per row, so concurrent runs cannot lose each other's rows
        (WORK / "rows").mkdir(parents=True, exist_ok=True)
        (WORK / "rows" / f"{name}.json").write_text(json.dumps(row))
    return merged


def main(argv: list[str] | None = None) -> None:
    argv = list(argv or [])  # `python -m bench textured` calls main() with no arguments
    ap = argparse.ArgumentParser(prog="python -m bench.bench_textured")
    ap.add_argument("--only", default="decoys,warp,targeted", help="comma-separated mechanisms")
    ap.add_argument("--sfm", action="store_true", help="full reconstructions for the final candidates")
    ap.add_argument(
        "--sfm-clean", action="store_true", help="also the clean reconstruction (verify.md has it)"
    )
    ap.add_argument("--variants", default="", help="comma-separated variant names (default: all)")
    ap.add_argument("--render", action="store_true", help="only merge saved rows and rewrite the table")
    ap.add_argument("--picture", default="", help="write textured_NAME.png for these variants and stop")
    ap.add_argument("--counters", default="", help="measure an attacker's clean-ups of these variants")
    ap.add_argument("--standin-check", action="store_true", help="kornia SIFT vs COLMAP SIFT, same keypoints")
    args = ap.parse_args(argv)
    WORK.mkdir(parents=True, exist_ok=True)
    if args.picture:
        for name in args.picture.split(","):
            print(f"wrote {picture(name)}")
        return
    if args.standin_check:
        STANDIN.write_text(json.dumps(standin_check(), indent=1))
        print(f"wrote {STANDIN}")
        return
    if args.counters:
        rows = json.loads(RAW.read_text())
        save({n: {**rows[n], "counters": counters(n)} for n in args.counters.split(",")})
        args.render = True
    if args.render:
        rows = {p.stem: json.loads(p.read_text()) for p in sorted((WORK / "rows").glob("*.json"))}
        merged = save(rows)
        RESULTS.write_text(render(list(merged.values()), "python -m bench.bench_textured"))
        print(f"wrote {RESULTS}")
        return
    previous = json.loads(RAW.read_text()) if RAW.exists() else {}
    if "clean" not in previous or args.sfm_clean:
        save({"clean": baseline(args.sfm_clean)})
    for mechanism in args.only.split(","):
        for v in variants()[mechanism]:
            if args.variants and v.name not in args.variants.split(","):
                continue
            if args.sfm and v.sfm and v.name in previous:  # reuse the measured row, add the reconstruction
                merged = save({v.name: {**previous[v.name], "sfm": full_sfm(v)}})
            else:
                merged = save({v.name: measure(v, args.sfm)})
    merged = save({})
    RESULTS.write_text(render(list(merged.values()), "python -m bench.bench_textured " + " ".join(argv)))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main(sys.argv[1:])
