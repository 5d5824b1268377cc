"""The paper's ablations and baselines on any image folder (issue 7): `run_experiment(...)`.

A sweep is a list of *settings* (one patch spec or one baseline each) x `runs` seeds. Each
(setting, run) is: poison a copy of the clean folder -> Verifier I (`verify_folders`, the clean
SfM cached once per sweep via `clean_cache_dir`) -> optionally Verifier II (the splat stage, the
paper's cost1) -> cost2 (clean vs poisoned SSIM / PSNR / LPIPS, always) -> one result row
appended (fsync'd) to `<exp_dir>/results.jsonl`. A killed sweep rerun with the same exp dir skips
every row already there, so it continues where it stopped.

Sweeps vary one parameter at a time from a base patch (the paper's layout: P=100, b=4, alpha=1,
contrast 255; the patch-size rows keep b=4), so `--sweep patch_size=12,48 --sweep block=2,8`
gives 4 settings (+ the base, shared by both tables), not a cartesian product.

This module's top level imports neither torch nor pycolmap (LPIPS loads lazily; SfM and the splat
run in child processes), so `ppd experiment` stays light until it needs them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
from PIL import Image  # PIL before anything that may load pycolmap

from poisoner.atomic import atomic_write_bytes
from poisoner.baselines import BASELINE_KINDS, BaselineKind, BaselineSpec, apply_baseline
from poisoner.errors import ExitStatus, PpdError
from poisoner.formats import poison_file
from poisoner.media import is_image
from poisoner.spec import PatchSpec, SpecError

# Tables over finished rows (verifier.experiment_tables), re-exported: callers import them from here.
from verifier.experiment_tables import CSV_COLUMNS as CSV_COLUMNS
from verifier.experiment_tables import METRICS as METRICS
from verifier.experiment_tables import Stat as Stat
from verifier.experiment_tables import aggregate as aggregate
from verifier.experiment_tables import csv_text, markdown_tables
from verifier.experiment_tables import stat as stat
from verifier.experiment_tables import table_row as table_row

log = logging.getLogger(__name__)

RESULTS_NAME = "results.jsonl"
MANIFEST_NAME = "experiment.json"
CSV_NAME = "results.csv"
TABLE_NAME = "results.md"

# The paper's swept parameters -> PatchSpec field; short aliases accepted on the command line.
PARAM_FIELDS: dict[str, str] = {
    "patch_size": "patch_size", "p": "patch_size", "size": "patch_size",
    "block": "block_size", "block_size": "block_size", "b": "block_size",
    "alpha": "alpha", "contrast": "contrast", "pattern": "pattern", "ratio": "ratio",
}  # fmt: skip
# The paper's ablation base: P=100, b=4, alpha=1, full contrast (the patch-size table uses b=4 too).
BASE_PATCH = PatchSpec(patch_size=100, block_size=4, alpha=1.0, contrast=255)
# `--baselines` without a list: one representative of each family (the must-show set).
DEFAULT_BASELINES: tuple[BaselineSpec, ...] = (
    BaselineSpec("blur", 11),
    BaselineSpec("noise", 10),
    BaselineSpec("jpeg", 25),
    BaselineSpec("rotation", 15),
)


class ExperimentError(PpdError, ValueError):
    """Bad sweep spec or inputs (message = one clear line)."""

    exit_status = ExitStatus.USAGE


# ---- settings ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Setting:
    """One row of a paper table: a patch spec, a baseline, or the clean reference."""

    kind: str  # "patch" | "baseline" | "clean"
    label: str  # "P=100 b=4 a=1 c=255 checkerboard r=1" / "blur=11" / "clean"
    patch: PatchSpec | None = None
    baseline: BaselineSpec | None = None
    groups: tuple[str, ...] = ()  # the ablation tables it belongs to ("patch_size", "baselines", ...)

    @property
    def setting_id(self) -> str:
        """Stable across processes: what the setting *does*, not which tables show it."""
        if self.patch is not None:
            body = self.patch.replace(seed=0).to_json()
        elif self.baseline is not None:
            body = json.dumps({**dataclasses.asdict(self.baseline), "seed": 0}, sort_keys=True)
        else:
            body = "clean"
        return hashlib.sha256(f"{self.kind}:{body}".encode()).hexdigest()[:12]

    def params(self) -> dict[str, Any]:
        if self.patch is not None:
            d = self.patch.to_dict()
            return {k: d[k] for k in ("patch_size", "block_size", "alpha", "contrast", "pattern", "ratio")}
        if self.baseline is not None:
            return {"kind": self.baseline.kind, "value": self.baseline.value}
        return {}

    def with_seed(self, seed: int) -> Setting:
        if self.patch is not None:
            return dataclasses.replace(self, patch=self.patch.replace(seed=seed))
        if self.baseline is not None:
            return dataclasses.replace(self, baseline=dataclasses.replace(self.baseline, seed=seed))
        return self


def patch_label(spec: PatchSpec) -> str:
    return (
        f"P={spec.patch_size:g} b={spec.block_size:g} a={spec.alpha:g} c={spec.contrast} "
        f"{spec.pattern} r={spec.ratio:g}"
    )


def _parse_value(field_name: str, text: str) -> Any:
    text = text.strip()
    if field_name == "pattern":
        return text
    try:
        if field_name in ("patch_size", "block_size"):
            # "12" = pixels, "0.06" = a fraction of the width (PatchSpec's Length)
            return int(text) if text.lstrip("-").isdigit() else float(text)
        if field_name == "contrast":
            return int(text)
        return float(text)
    except ValueError as exc:
        raise ExperimentError(f"bad value {text!r} for {field_name}") from exc


def parse_sweep(text: str) -> tuple[str, list[Any]]:
    """'patch_size=12,24,48' -> ('patch_size', [12, 24, 48]); names are PatchSpec fields or aliases."""
    name, sep, values = text.partition("=")
    key = name.strip().lower()
    if not sep or not values.strip():
        raise ExperimentError(f"bad sweep {text!r}: expected NAME=V1,V2,... (e.g. patch_size=12,48,100)")
    if key not in PARAM_FIELDS:
        raise ExperimentError(
            f"unknown sweep parameter {name!r}; choose one of {', '.join(sorted(set(PARAM_FIELDS)))}"
        )
    field_name = PARAM_FIELDS[key]
    return field_name, [_parse_value(field_name, v) for v in values.split(",") if v.strip()]


def parse_baseline(text: str) -> list[BaselineSpec]:
    """'blur=3,7,11' -> three BaselineSpecs; shear takes an axis suffix: 'shear-x=0.2'."""
    name, sep, values = text.partition("=")
    kind, _, axis = name.strip().lower().partition("-")
    if not sep or kind not in BASELINE_KINDS:
        raise ExperimentError(
            f"bad baseline {text!r}: expected KIND=V1,V2 with KIND in {', '.join(BASELINE_KINDS)}"
        )
    out = []
    # kind is one of BASELINE_KINDS (checked above); BaselineSpec checks axis and raises ValueError.
    extra: dict[str, Any] = {"axis": axis} if axis else {}
    for v in values.split(","):
        try:
            out.append(BaselineSpec(cast(BaselineKind, kind), float(v), **extra))
        except (ValueError, TypeError) as exc:
            raise ExperimentError(f"bad baseline {kind}={v}: {exc}") from exc
    return out


def build_settings(
    sweeps: Sequence[tuple[str, Sequence[Any]]],
    baselines: Sequence[BaselineSpec] = (),
    base: PatchSpec = BASE_PATCH,
    include_clean: bool = True,
) -> list[Setting]:
    """One-at-a-time grid from `base` (the paper's ablations), deduplicated, in a stable order."""
    by_id: dict[str, Setting] = {}

    def add(setting: Setting, group: str) -> None:
        sid = setting.setting_id
        old = by_id.get(sid)
        groups = (old.groups if old else ()) + ((group,) if group not in (old.groups if old else ()) else ())
        by_id[sid] = dataclasses.replace(old or setting, groups=groups)

    if include_clean:
        add(Setting("clean", "clean"), "clean")
    for field_name, values in sweeps:
        for value in values:
            try:
                spec = base.replace(**{field_name: value})
            except (SpecError, TypeError) as exc:
                raise ExperimentError(f"{field_name}={value}: {exc}") from exc
            add(Setting("patch", patch_label(spec), patch=spec), field_name)
    for b in baselines:
        add(Setting("baseline", b.label, baseline=b), "baselines")
    return list(by_id.values())


# ---- options ----------------------------------------------------------------------------------
@dataclass
class ExperimentOptions:
    runs: int = 1
    profiles: tuple[str, ...] = ("default",)
    splat: bool = False  # Verifier II cost1 (trains two splats per setting: expensive on CPU)
    splat_options: dict[str, Any] = field(
        default_factory=lambda: {
            "long_edge": 200,
            "iterations": 1500,
            "time_budget_s": 150.0,
            "cost2_long_edge": 200,
        }
    )
    camera_params: str | None = None  # known intrinsics variant; None = the attacker's default
    ground_truth: Path | None = None
    sfm_timeout_s: float = 1800.0
    cost2_lpips: bool = True  # LPIPS of clean vs poisoned (exact, over the changed region)
    # LPIPS on CPU costs ~1-4 s per 800 px image here, so it runs on this many evenly spaced
    # images (0 = all); SSIM and PSNR always use every image.
    cost2_lpips_images: int = 8
    lpips_net: str = "vgg"

    def config_id(self) -> str:
        """What changes the numbers (not runs): rows from another config are not reused."""
        d = {
            "profiles": list(self.profiles),
            "splat": self.splat,
            "splat_options": self.splat_options if self.splat else None,
            "camera_params": self.camera_params,
            "cost2_lpips": self.cost2_lpips,
            "cost2_lpips_images": self.cost2_lpips_images,
            "lpips_net": self.lpips_net,
        }
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:10]


# ---- poisoning a copy -------------------------------------------------------------------------
def image_names(folder: Path) -> list[str]:
    return sorted(p.name for p in Path(folder).iterdir() if p.is_file() and is_image(p))


def _save_like(src: Path, pixels: np.ndarray, dst: Path) -> None:
    """Write a baseline's pixels in the source's format (JPEG at q95, as a creator's export)."""
    im = Image.fromarray(pixels)
    if src.suffix.lower() in (".jpg", ".jpeg"):
        im.save(dst, format="JPEG", quality=95)
    else:
        im.save(dst, format="PNG")


def make_poisoned_copy(clean_dir: Path, dst_dir: Path, setting: Setting) -> int:
    """Poison (or perturb) every image of clean_dir into dst_dir; returns how many changed."""
    if dst_dir.exists():
        shutil.rmtree(dst_dir)
    dst_dir.mkdir(parents=True)
    changed = 0
    for name in image_names(clean_dir):
        src, dst = clean_dir / name, dst_dir / name
        if setting.patch is not None and setting.patch.selects(name):
            poison_file(src, dst, setting.patch)
            changed += 1
        elif setting.baseline is not None:
            with Image.open(src) as im:
                pixels = np.asarray(im.convert("RGB"))
            _save_like(src, apply_baseline(pixels, setting.baseline, name), dst)
            changed += 1
        else:  # clean reference, or an image the ratio leaves alone
            shutil.copy2(src, dst)
    return changed


# ---- cost2 ------------------------------------------------------------------------------------
def _rgb_unit(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        if im.mode in ("RGBA", "LA", "P"):
            rgba = np.asarray(im.convert("RGBA")).astype(np.float64) / 255
            return rgba[..., :3] * rgba[..., 3:] + (1 - rgba[..., 3:])  # on white, as 3DGS for NeRF data
        return np.asarray(im.convert("RGB")).astype(np.float64) / 255


def evenly_spaced(names: Sequence[str], count: int) -> list[str]:
    """count names spread over the list (all when count <= 0 or >= len)."""
    if count <= 0 or count >= len(names):
        return list(names)
    return [names[round(i * (len(names) - 1) / (count - 1))] if count > 1 else names[0] for i in range(count)]


def cost2(
    clean_dir: Path, poisoned_dir: Path, lpips_net: str | None = "vgg", lpips_images: int = 0
) -> dict[str, Any]:
    """The paper's imperceptibility: mean SSIM / PSNR / LPIPS of each poisoned image vs its original.

    PSNR of identical images is inf; the mean PSNR is over finite values with `psnr_identical`
    counting the rest (a ratio < 1 leaves images untouched). LPIPS is None with a reason when
    the weights are missing.
    """
    from verifier.metrics import psnr, ssim

    lp = None
    reason = None
    if lpips_net:
        from verifier.lpips import Lpips, lpips_available  # torch: only when asked

        ok, reason = lpips_available(lpips_net)
        lp = Lpips(lpips_net) if ok else None
    ssims, psnrs, lpipss, identical = [], [], [], 0
    names = image_names(clean_dir)
    lpips_names = set(evenly_spaced(names, lpips_images))
    for name in names:
        a, b = _rgb_unit(clean_dir / name), _rgb_unit(poisoned_dir / name)
        if a.shape != b.shape:
            raise ExperimentError(f"{name}: clean {a.shape} and poisoned {b.shape} differ in size")
        ssims.append(ssim(a, b))
        p = psnr(a, b)
        if math.isfinite(p):
            psnrs.append(p)
        else:
            identical += 1
        if lp is not None and name in lpips_names:
            lpipss.append(
                0.0
                if not math.isfinite(p)
                else float(lp.distance(a.astype(np.float32), b.astype(np.float32)))
            )
    return {
        "ssim": float(np.mean(ssims)) if ssims else None,
        "psnr": float(np.mean(psnrs)) if psnrs else (math.inf if identical else None),
        "lpips": float(np.mean(lpipss)) if lpipss else None,
        "lpips_unavailable": reason if lp is None and lpips_net else None,
        "images": len(ssims),
        "lpips_images": len(lpipss),
        "psnr_identical": identical,
    }


# ---- one row ----------------------------------------------------------------------------------
def _profile_fields(prof: Any) -> dict[str, Any]:
    c, p = prof.clean, prof.poisoned
    vc, cg, pg = prof.vs_clean or {}, prof.clean_vs_gt or {}, prof.poisoned_vs_gt or {}
    return {
        "verdict": prof.verdict,
        "reasons": prof.reasons,
        "poisoned_outcome": p.get("outcome"),
        "clean_registered": c.get("registered"),
        "poisoned_registered": p.get("registered"),
        "num_images": c.get("num_images"),
        "within5_of_clean": vc.get("frac_within_5deg"),
        "median_rot_err_deg": vc.get("median_rotation_error_deg"),
        "auc5_vs_clean": vc.get("auc_5"),
        "clean_within5_of_gt": cg.get("frac_within_5deg"),
        "poisoned_within5_of_gt": pg.get("frac_within_5deg"),
        "clean_sfm_s": c.get("elapsed_s"),
        "poisoned_sfm_s": p.get("elapsed_s"),
        "model_dir": prof.model_dir,
    }


def _splat_fields(splat: dict[str, Any] | None) -> dict[str, Any]:
    if not splat or splat.get("outcome") != "ok":
        return {"splat_outcome": (splat or {}).get("outcome"), "splat_error": (splat or {}).get("error")}
    return {
        "splat_outcome": "ok",
        "cost1": splat["poisoned"].get("cost1"),
        "cost1_clean": splat["clean"].get("cost1"),
        "splat_cost2": splat.get("cost2"),
        "splat_seconds": splat.get("seconds"),
        "splat_preview": splat.get("preview"),
    }


def run_setting(
    setting: Setting,
    run: int,
    clean_dir: Path,
    exp_dir: Path,
    options: ExperimentOptions,
) -> dict[str, Any]:
    """Poison a copy, verify it, measure it; the result row (never raises for a failed SfM)."""
    started = time.time()
    work = exp_dir / "work" / f"{setting.setting_id}-run{run}"
    poisoned_dir = work / "poisoned"
    changed = make_poisoned_copy(clean_dir, poisoned_dir, setting.with_seed(run))
    row = _row_header(setting, run, options, changed)
    t = time.time()
    row["cost2"] = cost2(
        clean_dir,
        poisoned_dir,
        options.lpips_net if options.cost2_lpips else None,
        options.cost2_lpips_images,
    )
    row["cost2_s"] = round(time.time() - t, 1)
    try:
        row.update(_verification_fields(clean_dir, poisoned_dir, work / "verify", exp_dir, run, options))
    except Exception as exc:  # a bad setting is a row with its error, the sweep goes on
        log.exception("setting failed", extra={"setting": setting.label, "run": run})
        row["verdict"] = "error"
        row["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0]
    shutil.rmtree(poisoned_dir, ignore_errors=True)  # models stay under work/verify
    row["seconds"] = round(time.time() - started, 1)
    row["finished_at"] = time.time()
    return row


def _row_header(setting: Setting, run: int, options: ExperimentOptions, changed: int) -> dict[str, Any]:
    return {
        "setting_id": setting.setting_id,
        "config_id": options.config_id(),
        "run": run,
        "seed": run,
        "kind": setting.kind,
        "label": setting.label,
        "groups": list(setting.groups),
        "params": setting.params(),
        "images_changed": changed,
    }


def _verification_fields(
    clean_dir: Path, poisoned_dir: Path, verify_dir: Path, exp_dir: Path, run: int, options: ExperimentOptions
) -> dict[str, Any]:
    """verify_folders on one poisoned copy: verdict, per-profile figures, splat costs, visibility."""
    import msgspec

    from verifier.verification import VerifyOptions, verify_folders

    splat_options = {**options.splat_options, "seed": run, "lpips_net": options.lpips_net}
    verify_options = VerifyOptions(
        timeout_s=options.sfm_timeout_s,
        camera_params=options.camera_params,
        ground_truth=options.ground_truth,
        clean_cache_dir=exp_dir / "clean-cache",  # the clean SfM once per sweep
        splat=options.splat,
        splat_profile=options.profiles[0],
        splat_options=splat_options,
    )
    report = verify_folders(clean_dir, poisoned_dir, verify_dir, options.profiles, verify_options)
    fields: dict[str, Any] = {
        "verdict": str(report.verdict),
        "profiles": {name: _profile_fields(p) for name, p in report.profiles.items()},
        # what a viewer sees of this setting (worst over a few images)
        "visibility": msgspec.to_builtins(report.visibility.worst) if report.visibility else None,
    }
    splat = next((p.splat for p in report.profiles.values() if p.splat is not None), None)
    fields.update(_splat_fields(splat) if options.splat else {})
    first = report.profiles.get(options.profiles[0])
    if first is not None:
        fields.update({k: v for k, v in _profile_fields(first).items() if k not in ("reasons", "model_dir")})
    return fields


# ---- the results file (resumable) -------------------------------------------------------------
def append_row(path: Path, row: dict[str, Any]) -> None:
    """One JSON line, flushed and fsync'd: a kill leaves every finished row intact."""
    line = json.dumps(row, sort_keys=True, default=_json_default) + "\n"
    with open(path, "a+b") as f:
        f.seek(0, os.SEEK_END)
        if f.tell() > 0:
            f.seek(-1, os.SEEK_END)
            if f.read(1) != b"\n":  # a torn last line (killed mid-write): start a fresh one
                line = "\n" + line
        f.write(line.encode("utf-8"))
        f.flush()
        os.fsync(f.fileno())


def _json_default(x: Any) -> Any:
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    raise TypeError(f"not JSON: {type(x).__name__}")


def load_rows(path: Path) -> list[dict[str, Any]]:
    """Every complete row; a torn last line (killed mid-write) is ignored."""
    if not Path(path).is_file():
        return []
    rows = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            log.warning("skipping a torn result line", extra={"file": str(path)})
    return rows


def pending(
    settings: Sequence[Setting], runs: int, done_rows: Iterable[dict[str, Any]], config_id: str
) -> list[tuple[Setting, int]]:
    done = {(r["setting_id"], r["run"]) for r in done_rows if r.get("config_id") == config_id}
    return [(s, run) for run in range(runs) for s in settings if (s.setting_id, run) not in done]


@dataclass
class ExperimentResult:
    exp_dir: Path
    rows: list[dict[str, Any]]
    ran: int  # settings x runs computed in this call
    skipped: int  # already in results.jsonl
    seconds: float
    csv_path: Path
    table_path: Path


RunFn = Callable[[Setting, int, Path, Path, ExperimentOptions], dict[str, Any]]


def run_experiment(
    clean_dir: Path,
    exp_dir: Path,
    settings: Sequence[Setting],
    options: ExperimentOptions,
    progress: Callable[[str], None] | None = None,
    run_fn: RunFn = run_setting,
) -> ExperimentResult:
    """Run every (setting, run) not yet in exp_dir/results.jsonl; then write CSV + Markdown."""
    clean_dir, exp_dir = Path(clean_dir), Path(exp_dir)
    names = image_names(clean_dir) if clean_dir.is_dir() else []
    if len(names) < 3:
        raise ExperimentError(f"{clean_dir}: needs a folder with at least 3 images (found {len(names)})")
    exp_dir.mkdir(parents=True, exist_ok=True)
    results = exp_dir / RESULTS_NAME
    config_id = options.config_id()
    todo = pending(settings, options.runs, load_rows(results), config_id)
    total = len(settings) * options.runs
    manifest = {
        "clean_dir": str(clean_dir),
        "images": len(names),
        "config_id": config_id,
        "options": dataclasses.asdict(options),
        "settings": [{"id": s.setting_id, "label": s.label, "groups": s.groups} for s in settings],
    }
    manifest_json = json.dumps(manifest, indent=1, default=_json_default)
    atomic_write_bytes(exp_dir / MANIFEST_NAME, manifest_json.encode())
    started = time.time()
    for i, (setting, run) in enumerate(todo, 1):
        if progress:
            progress(f"[{total - len(todo) + i}/{total}] {setting.label} run {run}")
        row = run_fn(setting, run, clean_dir, exp_dir, options)
        append_row(results, row)
        log.info("setting done", extra={"setting": setting.label, "run": run, "verdict": row.get("verdict"),
                                         "seconds": row.get("seconds")})  # fmt: skip
    rows = [r for r in load_rows(results) if r.get("config_id") == config_id]
    csv_path, table_path = write_outputs(exp_dir, rows)
    return ExperimentResult(
        exp_dir, rows, len(todo), total - len(todo), time.time() - started, csv_path, table_path
    )


def write_outputs(exp_dir: Path, rows: Sequence[dict[str, Any]]) -> tuple[Path, Path]:
    csv_path, table_path = exp_dir / CSV_NAME, exp_dir / TABLE_NAME
    atomic_write_bytes(csv_path, csv_text(rows).encode())
    atomic_write_bytes(table_path, (markdown_tables(rows) + "\n").encode())
    return csv_path, table_path
