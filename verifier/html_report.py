"""Self-contained HTML reports (issue 7): `build_*` gathers a `ReportData`, `render_html` writes it;
the figures and tables on the page are verifier.report_figures'.

One file, no remote resources and no JavaScript: pictures are PNG data URIs, CSS is inline. What a
report shows: the verdict (a coloured banner) and its reasons per profile, the verification
history (Store's verification_runs), metrics tables, camera trajectories clean vs poisoned (3D
matplotlib PNG), the splat stage's render comparisons when present, and the patch preview.

Sources:
- a dataset's verification history (`dataset_history_report(...)`, given its Store rows, model
  folders and an (original, patched) pair for the preview; daemon.verification.dataset_report
  gathers them);
- a verification folder (`build_verification_report(dir)`): `report.json` (verify_dataset's run
  dir) or `<profile>/report.json` files (verify_folders' out dir);
- an experiment folder (`build_experiment_report(dir)`): results.jsonl -> the paper's tables,
  the trade-off figure and metric-vs-parameter figures.

Where a daemon dataset's latest report lives is the application's convention
(daemon.verification.dataset_report).
"""

from __future__ import annotations

import html
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from poisoner.atomic import atomic_write_bytes
from poisoner.errors import ExitStatus, PpdError
from verifier.report_figures import (
    PATCH_PREVIEW,
    REPORT_PROFILES,
    Figure,
    Table,
    data_uri,
    history_table,
    mark_at_display_figure,
    patch_preview_figure,
    profile_table,
    splat_figure,
    trajectory_figure,
    visibility_note,
    visibility_table,
    when,
)
from verifier.verdict import (
    MASKED_MEANING,
    Verdict,
    headline,
    left_out_line,
    masked_line,
    measured_verdict,
    unverified,
)

# Banner colours: distinctive, saturated, one per verdict (the screenshot test looks for them).
VERDICT_COLOURS: dict[str, str] = {
    Verdict.PROTECTED: "#0a7d3b",
    Verdict.WEAK: "#c26a00",
    Verdict.NOT_PROTECTED: "#c4161c",
    Verdict.SFM_CRASHED: "#6b2fb3",
    Verdict.INCONCLUSIVE: "#4a5568",
    "error": "#4a5568",
}
VERDICT_TEXT: dict[str, str] = {
    Verdict.PROTECTED: "PROTECTED — the attacker's SfM does not recover the cameras",
    Verdict.WEAK: "WEAK — a partial reconstruction is likely",
    Verdict.NOT_PROTECTED: "NOT PROTECTED — the attacker gets a usable reconstruction",
    Verdict.SFM_CRASHED: "SfM CRASHED — no result, which is not proof of protection",
    Verdict.INCONCLUSIVE: "INCONCLUSIVE — COLMAP also fails on the originals",
}


class ReportError(PpdError, ValueError):
    """Nothing to report on (message = one clear line)."""

    exit_status = ExitStatus.USAGE


@dataclass
class ReportData:
    title: str
    verdict: str | None  # None: no verification to judge (e.g. an experiment overview)
    reasons: dict[str, list[str]] = field(default_factory=dict)  # profile -> reasons
    tables: list[Table] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    generated_at: float = field(default_factory=time.time)
    protection: str | None = None  # a dataset's state in ppd's words, e.g. "patched, not verified"
    holding: str | None = None  # where the protection does NOT hold, and where it could not be verified
    # a dataset with files left without the mark: the banner's words ("NOT protected: 1 failed, ...; the
    # 7 patched: protected under ..."), as its verdict is NOT protected whatever SfM measured
    unmarked: str | None = None
    # the headline profiles the verdict rests on, when others could not be verified: said in the banner
    # (a black-box review: "Verdict: PROTECTED" in large type, measured under global alone of five)
    measured_only: str | None = None


# ---- builders ---------------------------------------------------------------------------------
def latest_run_group(runs: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The rows of the newest verification (same run folder), one per profile."""
    if not runs:
        return []
    newest = runs[0]
    run_dir = str(Path(newest["model_dir"]).parent) if newest.get("model_dir") else None
    group: dict[str, Mapping[str, Any]] = {}
    for r in runs:
        same = run_dir is not None and r.get("model_dir") and str(Path(r["model_dir"]).parent) == run_dir
        if (same or r is newest) and r["profile"] not in group:
            group[r["profile"]] = r
    return list(group.values())


def _verdicts(profiles: Mapping[str, Mapping[str, Any]]) -> dict[str, str]:
    return {name: str(m.get("verdict", "")) for name, m in profiles.items()}


def _left_out(profiles: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The photos a counted profile's COLMAP did not read (none in reports made before)."""
    return sorted({n for name in headline(_verdicts(profiles)) for n in profiles[name].get("left_out") or ()})


def _verdict(profiles: Mapping[str, Mapping[str, Any]]) -> str:
    """The page's verdict: `ppd verify`'s (VerificationReport.verdict)."""
    return measured_verdict(_verdicts(profiles), _left_out(profiles))


def _add_profile_content(
    data: ReportData, profiles: Mapping[str, Mapping[str, Any]], corner_mark: bool | None = None
) -> None:
    data.reasons = {name: list(m.get("reasons") or []) for name, m in profiles.items()}
    data.holding = _holding_text(profiles, corner_mark)
    data.measured_only = _measured_only(profiles)
    if left := _left_out(profiles):
        line = left_out_line(left)
        data.notes.append(f"{line[0].upper()}{line[1:]}.")
    if "masked" in profiles:
        data.notes.append(f"The verdict counts every attacker run, masked included; {MASKED_MEANING}.")
    data.tables.append(profile_table(profiles))
    for name, m in profiles.items():
        fig = trajectory_figure(m.get("model_dir"), name)
        if fig:
            data.figures.append(fig)
        fig = splat_figure(m.get("splat"), name)
        if fig:
            data.figures.append(fig)


def dataset_history_report(
    title: str,
    runs: Sequence[Mapping[str, Any]],
    protection: str | None,
    pairs: Sequence[tuple[Path, Path]],
    spec: Any | None,
    unverified_note: str,
    current: Sequence[Mapping[str, Any]] | None = None,
    mark_of: Callable[[Path], Mapping[str, Any]] | None = None,
) -> ReportData:
    """A dataset's verification history (Store rows, newest first, with their model folders) and a
    patch preview from its first (original, patched) image pair. protection is the dataset's state
    in the user's words; unverified_note is said when there is no run at all. current: the rows the
    verdict and the profile table rest on (the newest of each profile that measured today's pixels);
    default, the newest verification's rows. mark_of: what ppd recorded of a patched file's mark
    (report_figures.patch_preview_figure's mark)."""
    latest = latest_run_group(runs) if current is None else list(current)
    profiles = {r["profile"]: {**(r.get("metrics") or {}), "verdict": r["verdict"],
                               "model_dir": r.get("model_dir")} for r in latest}  # fmt: skip
    data = ReportData(title=title, verdict=_verdict(profiles) if latest else None)
    data.protection = protection
    if not runs:  # runs that measured earlier pixels are history, not "never verified" (the caller says so)
        data.notes.append(unverified_note)
    corner = next((m["corner_mark"] for m in profiles.values() if m.get("corner_mark") is not None), None)
    _add_profile_content(data, profiles, corner)
    data.notes += next((m["video_frames"] for m in profiles.values() if m.get("video_frames")), [])
    image_pair = next(((o, p) for o, p in pairs if not _is_video(p)), None)
    mark = mark_of(image_pair[1]) if mark_of is not None and image_pair is not None else None
    if latest:
        visibility = next(
            (r["metrics"]["visibility"] for r in latest if (r.get("metrics") or {}).get("visibility")), None
        )
        _add_visibility_content(data, visibility, image_pair, mark)
    if runs:
        data.tables.append(history_table(runs))
    if spec is not None and image_pair is not None:
        fig = patch_preview_figure(image_pair[0], image_pair[1], spec, mark)
        if fig:
            data.figures.append(fig)
    return data


def has_patch_preview(data: ReportData) -> bool:
    """Whether the page shows a patch preview (a text may point at it only then)."""
    return any(f.caption.startswith(PATCH_PREVIEW) for f in data.figures)


def _is_video(path: Path) -> bool:
    from poisoner.media import is_video

    return is_video(path)


def build_verification_report(folder: Path) -> ReportData:
    """A verification folder: verify_dataset's run dir (report.json) or verify_folders' out dir."""
    folder = Path(folder)
    top = folder / "report.json"
    report: dict[str, Any] = {}
    if top.is_file():
        report = json.loads(top.read_text())
        profiles = report.get("profiles") or {}
    else:
        profiles = {}
        for sub in sorted(folder.glob("*/report.json")):
            d = json.loads(sub.read_text())
            profiles[d.get("profile", sub.parent.name)] = d
    if not profiles:
        raise ReportError(f"{folder}: no report.json here (a verification folder or an experiment folder?)")
    data = ReportData(title=f"ppd report — {folder.name}", verdict=_verdict(profiles))
    corner = report.get("corner_mark")
    if corner is None:
        corner = ((report.get("visibility") or {}).get("worst") or {}).get("in_one_corner")
    _add_profile_content(data, profiles, corner)
    data.notes += report.get("video_frames") or []  # the frames a video's verdict rests on
    _add_visibility_content(data, report.get("visibility"), _measured_pair(report))
    return data


def _measured_pair(report: Mapping[str, Any]) -> tuple[Path, Path] | None:
    """The first image whose visibility was measured, when both folders are still there (a
    dataset's staged copies are removed after its verification)."""
    images = (report.get("visibility") or {}).get("images") or []
    if not images or not report.get("clean_dir") or not report.get("poisoned_dir"):
        return None
    name = str(images[0].get("name"))
    pair = (Path(report["clean_dir"]) / name, Path(report["poisoned_dir"]) / name)
    return pair if pair[0].is_file() and pair[1].is_file() else None


def build_experiment_report(folder: Path) -> ReportData:
    """An experiment folder: the paper's tables, trade-off and parameter figures, per-setting rows."""
    from verifier.experiment import MANIFEST_NAME, RESULTS_NAME, aggregate, load_rows, table_row
    from verifier.plots import parameter_pngs, tradeoff_png

    folder = Path(folder)
    rows = load_rows(folder / RESULTS_NAME)
    if not rows:
        raise ReportError(f"{folder}: no finished settings in {RESULTS_NAME} yet")
    manifest = folder / MANIFEST_NAME
    config_id = json.loads(manifest.read_text()).get("config_id") if manifest.is_file() else None
    if config_id and any(r.get("config_id") == config_id for r in rows):
        rows = [r for r in rows if r.get("config_id") == config_id]
    entries = aggregate(rows)
    data = ReportData(title=f"ppd experiment — {folder.name}", verdict=None)
    data.notes.append(
        f"{len(rows)} finished setting-runs. render = cost1 (splat on the set's own SfM poses; — when the "
        "splat stage did not run); clean-vs-poisoned = cost2; cameras within 5° = Verifier I."
    )
    header = [
        "setting", "n", "render SSIM", "render PSNR", "render LPIPS", "clean-vs-poisoned SSIM", "PSNR",
        "LPIPS", "cameras within 5° of clean", "within 5° of GT", "FLIP p99.9", "area FLIP > 0.5",
        "verdict(s)",
    ]  # fmt: skip
    data.tables.append(
        Table("All settings (mean ± std over runs)", header, [_md_cells(table_row(e)) for e in entries])
    )
    data.figures.append(Figure("Trade-off: one point per setting", tradeoff_png(entries)))
    for param, png in parameter_pngs(entries).items():
        data.figures.append(Figure(f"Metrics against {param}", png))
    example = next(
        (r for r in rows if r.get("kind") == "patch" and r.get("profiles")), next(iter(rows))
    )  # the first patch setting with models: its trajectories
    for name, prof in (example.get("profiles") or {}).items():
        fig = trajectory_figure(prof.get("model_dir"), f"{name}, setting {example['label']}")
        if fig:
            data.figures.append(fig)
        break
    return data


def _md_cells(row: str) -> list[str]:
    return [c.strip() for c in row.strip().strip("|").split("|")]


def build_report(source: str, dataset_report: Callable[[str], ReportData] | None = None) -> ReportData:
    """source: an experiment folder, a verification folder, or (with dataset_report, the
    application's lookup) a dataset name."""
    from verifier.experiment import RESULTS_NAME

    path = Path(source)
    if path.is_dir():
        if (path / RESULTS_NAME).is_file():
            return build_experiment_report(path)
        return build_verification_report(path)
    if dataset_report is None:
        raise ReportError(f"{source}: not a folder, and no daemon store to look a dataset up in")
    return dataset_report(source)


# ---- HTML -------------------------------------------------------------------------------------
CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:24px;color:#1f2937;background:#fff}
h1{font-size:22px}h2{font-size:18px;margin-top:28px}
.banner{color:#fff;padding:18px 22px;font-size:20px;font-weight:700;border-radius:4px}
.nobanner{background:#f3f4f6;color:#374151;padding:12px 16px}
table{border-collapse:collapse;font-size:13px;margin:8px 0}
th,td{border:1px solid #d1d5db;padding:4px 8px;text-align:left;vertical-align:top}
th{background:#f3f4f6}figure{margin:16px 0}img{max-width:100%;border:1px solid #e5e7eb}
figcaption{font-size:13px;color:#4b5563}.note{font-size:13px;color:#4b5563}
"""


def _table_html(t: Table) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in t.header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in t.rows)
    return (
        f"<h2>{html.escape(t.title)}</h2>\n<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
    )


def render_html(data: ReportData) -> str:
    """The whole page: inline CSS, images as data URIs, no script, no external reference."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(data.title)}</title>",
        f"<style>{CSS}</style></head><body>",
        f"<h1>{html.escape(data.title)}</h1>",
        f'<p class="note">Generated {when(data.generated_at)} by ppd.</p>',
    ]
    if data.verdict is not None:
        colour = VERDICT_COLOURS.get(data.verdict, VERDICT_COLOURS[Verdict.INCONCLUSIVE])
        text = data.unmarked or VERDICT_TEXT.get(data.verdict, data.verdict)
        if data.measured_only and not data.unmarked and data.verdict in (Verdict.PROTECTED, Verdict.WEAK):
            text = f"{text} ({data.measured_only})"
        parts.append(
            f'<div class="banner" id="verdict" data-verdict="{html.escape(data.verdict)}" '
            f'style="background:{colour}">Verdict: {html.escape(text)}</div>'
        )
    elif data.protection is not None:
        parts.append(f'<div class="nobanner" id="protection">{html.escape(data.protection)}</div>')
    else:
        parts.append('<div class="nobanner">No verdict: this page summarises an experiment.</div>')
    if data.protection is not None and data.verdict is not None:
        parts.append(f'<p id="protection">Dataset: {html.escape(data.protection)}</p>')
    if data.holding is not None:
        parts.append(f'<p id="holding"><strong>{html.escape(data.holding)}</strong></p>')
    if data.reasons:
        parts.append("<h2>Why</h2>")
        for profile, reasons in data.reasons.items():
            items = "".join(f"<li>{html.escape(r)}</li>" for r in reasons) or "<li>—</li>"
            parts.append(f"<h3>{html.escape(profile)}</h3><ul>{items}</ul>")
    parts += [f'<p class="note">{html.escape(n)}</p>' for n in data.notes]
    parts += [_table_html(t) for t in data.tables]
    for f in data.figures:
        parts.append(
            f'<figure><img alt="{html.escape(f.caption)}" src="{data_uri(f.png)}">'
            f"<figcaption>{html.escape(f.caption)}</figcaption></figure>"
        )
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_report(data: ReportData, out: Path) -> Path:
    """Write the page atomically (poisoner.atomic), creating folders as needed."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, render_html(data).encode("utf-8"))
    return out


# ---- what a viewer sees and where the protection holds ------------------------------------------


def _add_visibility_content(
    data: ReportData,
    visibility: Mapping[str, Any] | None,
    pair: tuple[Path, Path] | None,
    mark: Mapping[str, Any] | None = None,
) -> None:
    """What a viewer sees: the figures, and pair's patched picture at display size (mark: what ppd
    recorded of its mark, report_figures.shown_pair)."""
    data.notes.append(visibility_note(visibility))
    if visibility:
        data.tables.append(visibility_table(visibility))
    if pair is not None:
        fig = mark_at_display_figure(*pair, mark)
        if fig:
            data.figures.append(fig)


def _measured_only(profiles: Mapping[str, Mapping[str, Any]]) -> str | None:
    """"under global only; not verified under default, ..." when some headline profiles told nothing
    (COLMAP failed on the originals, or crashed) and others were measured; else None."""
    counted = headline(_verdicts(profiles))
    unknown = unverified(counted)
    measured = [name for name in counted if name not in unknown]
    if not unknown or not measured:
        return None
    return f"under {', '.join(measured)} only; not verified under {', '.join(unknown)}"


def _holding_text(profiles: Mapping[str, Mapping[str, Any]], corner_mark: bool | None = None) -> str | None:
    """Where the protection does not hold (the headline profiles), and the masked attacker's line."""
    from verifier.verdict import holding_line

    if not profiles:
        return None
    verdicts = _verdicts(profiles)
    counted = headline(verdicts)
    missing = [p for p in REPORT_PROFILES if p not in profiles]
    line = holding_line(counted)
    line = line[0].upper() + line[1:] + (f" (not run here: {', '.join(missing)})" if missing else "")
    masked = masked_line(verdicts, corner_mark)
    return f"{line}. {masked[0].upper()}{masked[1:]}." if masked else line
