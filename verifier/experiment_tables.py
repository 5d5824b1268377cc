"""An experiment's tables: finished rows aggregated per setting (mean ± sample std over runs and
scenes), the CSV of every row, and the paper's markdown tables (one per ablation).

Rows are verifier.experiment's result rows (dicts read from results.jsonl); nothing here runs SfM.
"""

from __future__ import annotations

import csv
import io
import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any


def _get(row: dict[str, Any], path: str) -> Any:
    cur: Any = row
    for part in path.split("."):
        if not isinstance(cur, dict):
            return None
        cur = cur.get(part)
    return cur


METRICS: dict[str, str] = {
    # column -> dotted path in a row
    "render_ssim": "cost1.ssim",
    "render_psnr": "cost1.psnr",
    "render_lpips": "cost1.lpips",
    "cvp_ssim": "cost2.ssim",
    "cvp_psnr": "cost2.psnr",
    "cvp_lpips": "cost2.lpips",
    "within5_of_clean": "within5_of_clean",
    "poisoned_within5_of_gt": "poisoned_within5_of_gt",
    "median_rot_err_deg": "median_rot_err_deg",
    "poisoned_sfm_s": "poisoned_sfm_s",
    "seconds": "seconds",
    # what a viewer sees (verifier.visibility; worst over the images measured in that run)
    "flip_p999": "visibility.flip_p999",
    "area_above_half": "visibility.area_above_half",
    "changed_area": "visibility.changed_area",
}


@dataclass(frozen=True)
class Stat:
    mean: float | None
    std: float | None  # sample std over runs (and scenes); None with one value
    n: int

    def text(self, digits: int) -> str:
        if self.mean is None:
            return "—"
        if math.isinf(self.mean):
            return "inf"
        if self.std is None:
            return f"{self.mean:.{digits}f}"
        return f"{self.mean:.{digits}f} ± {self.std:.{digits}f}"


def stat(values: Iterable[Any]) -> Stat:
    xs = [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
    xs = [x for x in xs if not math.isnan(x)]
    if not xs:
        return Stat(None, None, 0)
    if any(math.isinf(x) for x in xs):
        return Stat(math.inf, None, len(xs))
    return Stat(statistics.fmean(xs), statistics.stdev(xs) if len(xs) > 1 else None, len(xs))


def aggregate(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One entry per setting (over runs and scenes), in first-seen order: label, groups, Stats, verdicts."""
    by_setting: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by_setting.setdefault(r["setting_id"], []).append(r)
    out = []
    for sid, rs in by_setting.items():
        entry: dict[str, Any] = {
            "setting_id": sid,
            "label": rs[0]["label"],
            "kind": rs[0]["kind"],
            "groups": rs[0].get("groups", []),
            "params": rs[0].get("params", {}),
            "n": len(rs),
            "verdicts": [r.get("verdict") for r in rs],
        }
        for col, path in METRICS.items():
            entry[col] = stat(_get(r, path) for r in rs)
        if rs[0]["kind"] == "clean":  # the reference: cost1 is the clean splat's, cost2 is exact
            entry["render_ssim"] = stat(_get(r, "cost1_clean.ssim") for r in rs)
            entry["render_psnr"] = stat(_get(r, "cost1_clean.psnr") for r in rs)
            entry["render_lpips"] = stat(_get(r, "cost1_clean.lpips") for r in rs)
        out.append(entry)
    return out


CSV_COLUMNS = (
    "setting_id", "label", "kind", "groups", "run", "seed", "verdict", "images_changed",
    "cost1_ssim", "cost1_psnr", "cost1_lpips", "clean_cost1_ssim", "clean_cost1_psnr", "clean_cost1_lpips",
    "cost2_ssim", "cost2_psnr", "cost2_lpips", "within5_of_clean", "median_rot_err_deg",
    "clean_within5_of_gt", "poisoned_within5_of_gt", "poisoned_outcome", "poisoned_sfm_s", "seconds", "error",
    "flip_p999", "area_above_half", "changed_area",
)  # fmt: skip
VISIBILITY_COLUMNS = ("flip_p999", "area_above_half", "changed_area")


def csv_text(rows: Sequence[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(CSV_COLUMNS)
    for r in rows:
        flat = {
            **{k: r.get(k) for k in CSV_COLUMNS},
            "groups": ";".join(r.get("groups", [])),
            **{f"cost1_{m}": _get(r, f"cost1.{m}") for m in ("ssim", "psnr", "lpips")},
            **{f"clean_cost1_{m}": _get(r, f"cost1_clean.{m}") for m in ("ssim", "psnr", "lpips")},
            **{f"cost2_{m}": _get(r, f"cost2.{m}") for m in ("ssim", "psnr", "lpips")},
            **{m: _get(r, f"visibility.{m}") for m in VISIBILITY_COLUMNS},
        }
        w.writerow(["" if flat[k] is None else flat[k] for k in CSV_COLUMNS])
    return buf.getvalue()


GROUP_TITLES = {
    "clean": "Clean reference",
    "patch_size": "Patch size P",
    "block_size": "Block size b",
    "alpha": "Blend α",
    "contrast": "Contrast Δc",
    "pattern": "Pattern",
    "ratio": "Poisoning ratio",
    "baselines": "Baselines",
}
TABLE_HEADER = (
    "| setting | n | render SSIM | render PSNR | render LPIPS | clean-vs-poisoned SSIM | PSNR | LPIPS "
    "| cameras within 5° of clean | within 5° of GT | FLIP p99.9 | area FLIP > 0.5 | verdict(s) |"
)


def _pct(s: Stat) -> str:
    if s.mean is None:
        return "—"
    return f"{100 * s.mean:.0f}%" + (f" ± {100 * s.std:.0f}" if s.std is not None else "")


def _area(s: Stat) -> str:
    """A fraction of the picture, to 0.01%: a visible mark covers well under 1%."""
    if s.mean is None:
        return "—"
    return f"{100 * s.mean:.2f}%" + (f" ± {100 * s.std:.2f}" if s.std is not None else "")


def table_row(e: dict[str, Any]) -> str:
    verdicts = ", ".join(sorted({str(v) for v in e["verdicts"]}))
    return (
        f"| {e['label']} | {e['n']} | {e['render_ssim'].text(3)} | {e['render_psnr'].text(2)} "
        f"| {e['render_lpips'].text(3)} | {e['cvp_ssim'].text(4)} | {e['cvp_psnr'].text(2)} "
        f"| {e['cvp_lpips'].text(4)} | {_pct(e['within5_of_clean'])} | {_pct(e['poisoned_within5_of_gt'])} "
        f"| {e['flip_p999'].text(3)} | {_area(e['area_above_half'])} | {verdicts} |"
    )


def markdown_tables(rows: Sequence[dict[str, Any]]) -> str:
    """The paper's layout, one table per ablation; cost1 = render metrics, cost2 = clean vs poisoned."""
    entries = aggregate(rows)
    clean = [e for e in entries if e["kind"] == "clean"]
    out = [
        "Mean ± sample std over runs (and scenes); n = rows averaged. render = cost1 (splat trained on "
        "the set with its own SfM poses, vs its inputs; — when the splat stage did not run); "
        "clean-vs-poisoned = cost2. Cameras within 5° = Verifier I, after robust alignment. FLIP p99.9 and "
        "area FLIP > 0.5 = what a viewer sees (verifier.visibility, worst of a few images per run).",
        "",
    ]
    groups = [g for g in GROUP_TITLES if g != "clean" and any(g in e["groups"] for e in entries)]
    for g in groups:
        out += [f"### {GROUP_TITLES[g]}", "", TABLE_HEADER, "|" + "---|" * TABLE_HEADER.count(" |")]
        out += [table_row(e) for e in clean]
        out += [table_row(e) for e in entries if g in e["groups"]]
        out.append("")
    return "\n".join(out)


