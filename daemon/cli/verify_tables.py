"""How `ppd verify` and `ppd demo` show a verification report: one table per attacker profile
(clean vs poisoned SfM, cameras vs clean and ground truth), the splat stage's two costs, the
reasons and the overall verdict. Imported only when a report is printed (rich tables)."""

from __future__ import annotations

import math
from typing import Any

from rich.console import Console
from rich.table import Table

from verifier.verdict import Verdict, verdict_words

VERDICT_STYLE = {
    Verdict.PROTECTED: "bold green",
    Verdict.WEAK: "bold yellow",
    Verdict.NOT_PROTECTED: "bold red",
    Verdict.SFM_CRASHED: "bold magenta",
    Verdict.INCONCLUSIVE: "bold blue",
}


def _num(x: Any, pct: bool = False) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        if not math.isfinite(x):
            return "inf"
        return f"{100 * x:.0f}%" if pct else f"{x:.2f}"
    return str(x)


def _side_rows(clean: dict[str, Any], poisoned: dict[str, Any]) -> list[tuple[str, str, str]]:
    def reg(s: dict[str, Any]) -> str:
        if s.get("outcome") != "ok":
            return f"{s.get('outcome')} {s.get('signal', '')}".strip()
        return f"{s.get('registered', 0)}/{s.get('num_images', 0)}"

    return [
        ("outcome", str(clean.get("outcome")), str(poisoned.get("outcome"))),
        ("images registered", reg(clean), reg(poisoned)),
        ("models", _num(clean.get("num_models")), _num(poisoned.get("num_models"))),
        ("mean reprojection error (px)", _num(clean.get("mean_reprojection_error")),
         _num(poisoned.get("mean_reprojection_error"))),
        ("3D points", _num(clean.get("num_points3D")), _num(poisoned.get("num_points3D"))),
        ("SfM time (s)", _clean_time(clean), _num(poisoned.get("elapsed_s"))),
    ]  # fmt: skip


def _clean_time(clean: dict[str, Any]) -> str:
    """The clean run's seconds; an earlier run's when its result was reused (not measured now)."""
    seconds = _num(clean.get("elapsed_s"))
    return f"{seconds} (run {clean['reused_from']})" if clean.get("reused_from") else seconds


def reused_line(report: dict[str, Any]) -> str | None:
    """Which profiles took the clean reconstruction an earlier verification made of these same
    originals (names and bytes unchanged, same settings), and when it ran: the verdict is as good as
    a new one, and the user can tell a verification that measured the originals now from one that did
    not (a black-box review: only -v's log said so)."""
    reused = {name: p["clean"]["reused_from"] for name, p in report["profiles"].items()
              if (p.get("clean") or {}).get("reused_from")}  # fmt: skip
    if not reused:
        return None
    when = ", ".join(sorted(set(reused.values())))
    return (f"clean reference reused for {', '.join(reused)}: COLMAP on these same originals (unchanged: "
            f"names, bytes and settings), run {when}")  # fmt: skip


def _has_reference(clean: dict[str, Any], vs_clean: dict[str, Any]) -> bool:
    """Whether the clean column's figures vs clean mean anything: the clean run registered cameras
    and the poisoned run was compared with them. Otherwise "100%" would be a claim over nothing."""
    if clean.get("outcome") != "ok" or not vs_clean:
        return False
    compared = vs_clean.get("cameras_compared")  # absent in reports written before it was recorded
    return int(clean.get("registered") or 0) > 0 and (compared is None or int(compared) > 0)


def profile_table(p: dict[str, Any]) -> Table:
    verdict = p["verdict"]
    table = Table(
        title=f"profile [bold]{p['profile']}[/]: "
        f"[{VERDICT_STYLE.get(verdict, 'bold')}]{verdict_words(verdict)}[/]",
        title_justify="left",
    )
    table.add_column("metric", overflow="fold")  # folded, never cut with an ellipsis
    table.add_column("clean", justify="right", overflow="fold")
    table.add_column("poisoned", justify="right", overflow="fold")
    for row in _side_rows(p["clean"], p["poisoned"]):
        table.add_row(*row)
    vc = p.get("vs_clean") or {}
    gt_c, gt_p = p.get("clean_vs_gt") or {}, p.get("poisoned_vs_gt") or {}
    ref = _has_reference(p["clean"], vc)
    for t in (5, 10, 20):
        table.add_row(f"cameras within {t}° of clean", "100%" if ref else "-",
                      _num(vc.get(f"frac_within_{t}deg"), True))  # fmt: skip
    table.add_row("median rotation error (°)", "0" if ref else "-", _num(vc.get("median_rotation_error_deg")))
    table.add_row(
        "median relative rotation error (°)", "0" if ref else "-",
        _num(vc.get("median_relative_rotation_error_deg")),
    )  # fmt: skip
    aucs = " / ".join(_num(vc.get(f"auc_{t}")) for t in (5, 10, 20))
    table.add_row("pair pose AUC@5/10/20 vs clean", "1 / 1 / 1" if ref else "-", aucs)
    if gt_c or gt_p:
        for t in (5, 10, 20):
            table.add_row(f"within {t}° of ground truth", _num(gt_c.get(f"frac_within_{t}deg"), True),
                          _num(gt_p.get(f"frac_within_{t}deg"), True))  # fmt: skip
        table.add_row("pair pose AUC@5 vs ground truth", _num(gt_c.get("auc_5")), _num(gt_p.get("auc_5")))
    return table


def splat_table(splat: dict[str, Any]) -> Table:
    """The paper's two costs: cost1 (renders vs inputs, clean and poisoned), cost2 (poisoned vs clean)."""
    table = Table(title="splat stage (render quality)", title_justify="left")
    for col in ("", "SSIM", "PSNR (dB)", "LPIPS", "views", "iterations", "train s"):
        table.add_column(col, justify="right" if col else "left", overflow="fold")
    for side in ("clean", "poisoned"):
        s = splat.get(side) or {}
        c1 = s.get("cost1") or {}
        table.add_row(
            f"cost1 {side} renders vs inputs", _num(c1.get("ssim")), _num(c1.get("psnr")),
            _lpips(c1.get("lpips"), splat), _num(s.get("views")), _num(s.get("iterations")),
            _num(s.get("train_seconds")),
        )  # fmt: skip
    c2 = splat.get("cost2") or {}
    table.add_row("cost2 poisoned vs clean", _num(c2.get("ssim")), _num(c2.get("psnr")),
                  _lpips(c2.get("lpips"), splat), _num(c2.get("images")), "", "")  # fmt: skip
    return table


def _lpips(x: Any, splat: dict[str, Any]) -> str:
    if x is None and splat.get("lpips_unavailable"):
        return "n/a"  # the reason is printed under the table
    return "-" if x is None else f"{x:.3f}"


def print_report(report: dict[str, Any], console: Console) -> None:
    for p in report["profiles"].values():
        console.print(profile_table(p))
        splat = p.get("splat")
        if splat and splat.get("outcome") == "ok":
            console.print(splat_table(splat))
            if splat.get("lpips_unavailable"):
                console.print(f"  LPIPS n/a: {splat['lpips_unavailable']}")
            if splat.get("preview"):
                console.print(f"  picture (clean render | poisoned render | input): {splat['preview']}")
        for reason in p["reasons"]:
            console.print(f"  • {reason}")
        console.print()
    for line in report.get("summary") or []:  # visibility and the profiles it does not hold under
        console.print(f"  {line}", markup=False)
    if reused := reused_line(report):
        console.print(f"  {reused}", markup=False)
    console.print(overall_line(report))


def overall_line(report: dict[str, Any]) -> str:
    """`overall (weakest of default, ...): protected`; a dataset with files left without the mark
    (verify_cmd._as_published): `overall: NOT protected: 1 failed, unmarked: a.tif; the 7 patched
    (weakest of ...): protected`, the verdict of the patched files kept, never the last word."""
    from rich.markup import escape

    from daemon.datasets.folder_count import unmarked_why
    from daemon.states import unmarked_text

    v, measured = report["verdict"], report.get("patched_files_verdict", report["verdict"])
    said = f"[{VERDICT_STYLE.get(measured, 'bold')}]{verdict_words(measured)}[/]"
    if not report.get("unmarked"):
        return f"overall ({overall_basis(report)}): {said}"
    why = escape(unmarked_why(report["unmarked"], report.get("unmarked_files") or []))  # names: not markup
    patched = f"the {report['num_patched']} patched ({overall_basis(report)})"
    return f"overall: [{VERDICT_STYLE[v]}]{unmarked_text(why, patched, said)}[/]"


def overall_basis(report: dict[str, Any]) -> str:
    """What the overall verdict is the weakest of. Profiles whose clean run failed (inconclusive) are
    named apart: "protected" from one attacker of five reads otherwise as five (a review of a run on
    16 lego views, where only the global mapper reconstructed the originals)."""
    counted = list(report.get("verdict_counts") or report["profiles"])
    verdicts = {name: report["profiles"].get(name, {}).get("verdict") for name in counted}
    unmeasured = [name for name in counted if verdicts[name] == Verdict.INCONCLUSIVE]
    measured = [name for name in counted if name not in unmeasured]
    if not unmeasured or not measured:
        return f"weakest of {', '.join(counted)}"
    return (
        f"weakest of {', '.join(measured)}; not measured under {', '.join(unmeasured)}, whose COLMAP "
        "does not reconstruct the originals either"
    )


def json_safe(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    return x
