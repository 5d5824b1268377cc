"""The figures and tables an HTML report shows (verifier.html_report lays them out on the page):
per-profile metrics and the verification history, camera trajectories clean vs poisoned, the
splat stage's render comparison, the patch preview, and what a viewer sees (FLIP table, the
protected image at display size with the mark enlarged). Each picture is a nicety: one that
cannot be made is logged with its file and left out, never failing the report."""

from __future__ import annotations

import base64
import json
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

log = logging.getLogger(__name__)

# Every profile a verification can run: the report's table lists each, "not run" where absent.
REPORT_PROFILES = ("default", "hardened", "published", "global", "masked")


# ---- a report's parts ------------------------------------------------------------------------
@dataclass
class Table:
    title: str
    header: list[str]
    rows: list[list[str]]


@dataclass
class Figure:
    caption: str
    png: bytes


# ---- small helpers ----------------------------------------------------------------------------
def png_bytes(pixels: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    Image.fromarray(np.asarray(pixels, dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def fmt(value: Any, digits: int = 2, pct: bool = False) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        if value != value:  # nan
            return "—"
        if value in (float("inf"), float("-inf")):
            return "inf"
        return f"{100 * value:.0f}%" if pct else f"{value:.{digits}f}"
    return str(value)


def when(ts: float | None) -> str:
    return "—" if not ts else time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(ts))


def _load_poses(side_dir: Path) -> dict[str, Any]:
    from verifier.poses import poses_from_json

    result = side_dir / "result.json"
    if not result.is_file():
        return {}
    try:
        return poses_from_json(json.loads(result.read_text()).get("poses") or {})
    except (ValueError, KeyError, TypeError) as exc:
        log.warning("unreadable poses", extra={"file": str(result), "error": str(exc)})
        return {}


# ---- a verification's figures and tables -----------------------------------------------------
def trajectory_figure(model_dir: str | Path | None, profile: str) -> Figure | None:
    """Clean vs poisoned camera centres of one profile's models, when both sides have poses."""
    if not model_dir:
        return None
    from verifier.plots import trajectory_png

    clean, poisoned = _load_poses(Path(model_dir) / "clean"), _load_poses(Path(model_dir) / "poisoned")
    if not clean and not poisoned:
        return None
    from verifier.plots import alignment

    aligned = alignment(poisoned, clean)[1]  # never said "aligned" of cameras that were not (0 clean)
    how = "aligned onto clean by a robust similarity"
    if not aligned:
        how = f"NOT aligned: {_why_not_aligned(clean, poisoned)}"
    caption = (
        f"Camera trajectories, profile {profile}: clean SfM ({len(clean)} cameras, green) vs poisoned SfM "
        f"({len(poisoned)} cameras, orange, {how}); grey lines join the same image."
    )
    title = "Camera centres: clean SfM vs poisoned SfM" + (" (aligned onto clean)" if aligned else "")
    return Figure(caption, trajectory_png(clean, poisoned, title=title))


def _why_not_aligned(clean: Mapping[str, Any], poisoned: Mapping[str, Any]) -> str:
    """Why plots.alignment found no similarity: fewer than 3 images both sides registered, or none
    that fits them (it said "too few cameras in both" of a clean side of 8: a black-box review)."""
    common = len(set(clean) & set(poisoned))
    if common >= 3:
        return f"no similarity fits the {common} cameras both sides registered"
    return f"{common} camera{'' if common == 1 else 's'} registered on both sides (3 are needed)"


def splat_figure(splat: Mapping[str, Any] | None, profile: str) -> Figure | None:
    preview = (splat or {}).get("preview")
    if not preview or not Path(preview).is_file():
        return None
    layout = (splat or {}).get("preview_layout", "clean render | poisoned render | poisoned input")
    return Figure(f"Render comparison (splat stage, profile {profile}): {layout}", Path(preview).read_bytes())


def profile_table(profiles: Mapping[str, Mapping[str, Any]]) -> Table:
    """Per profile: registrations, cameras within 5° (of clean and of GT), errors, splat costs."""
    rows = []
    for name in [*REPORT_PROFILES, *(p for p in profiles if p not in REPORT_PROFILES)]:
        if name not in profiles:
            rows.append([name, "not run", *(["—"] * 8)])
            continue
        m = profiles[name]
        c, p = m.get("clean") or {}, m.get("poisoned") or {}
        vc, cg, pg = m.get("vs_clean") or {}, m.get("clean_vs_gt") or {}, m.get("poisoned_vs_gt") or {}
        splat = m.get("splat") or {}
        c1 = (splat.get("poisoned") or {}).get("cost1") or {}
        c1c = (splat.get("clean") or {}).get("cost1") or {}
        c2 = splat.get("cost2") or {}
        poisoned_reg = (
            f"{fmt(p.get('registered'))}/{fmt(p.get('num_images'))}"
            if p.get("outcome") in (None, "ok")
            else str(p.get("outcome"))
        )
        rows.append(
            [
                name,
                str(m.get("verdict", "—")),
                f"{fmt(c.get('registered'))}/{fmt(c.get('num_images'))}",
                poisoned_reg,
                fmt(vc.get("frac_within_5deg"), pct=True),
                fmt(vc.get("median_rotation_error_deg"), 1),
                f"{fmt(cg.get('frac_within_5deg'), pct=True)} / {fmt(pg.get('frac_within_5deg'), pct=True)}",
                f"{fmt(c1c.get('ssim'), 3)} / {fmt(c1.get('ssim'), 3)}",
                f"{fmt(c1c.get('psnr'))} / {fmt(c1.get('psnr'))}",
                f"{fmt(c2.get('ssim'), 4)} / {fmt(c2.get('psnr'))} / {fmt(c2.get('lpips'), 4)}",
            ]
        )
    header = [
        "profile", "verdict", "clean registered", "poisoned registered", "poisoned within 5° of clean",
        "median rotation error °", "within 5° of GT clean / poisoned", "render SSIM clean / poisoned (cost1)",
        "render PSNR clean / poisoned", "clean-vs-poisoned SSIM / PSNR / LPIPS (cost2)",
    ]  # fmt: skip
    return Table("Metrics per profile (latest verification)", header, rows)


def history_table(runs: Sequence[Mapping[str, Any]]) -> Table:
    rows = []
    for r in runs:
        vc = (r.get("metrics") or {}).get("vs_clean") or {}
        rows.append(
            [
                when(r.get("finished_at")),
                str(r.get("profile")),
                str(r.get("verdict")),
                fmt(vc.get("frac_within_5deg"), pct=True),
                f"{(r.get('finished_at') or 0) - (r.get('started_at') or 0):.0f}",
                str(r.get("error") or ""),
            ]
        )
    return Table(
        "Verification history (newest first)",
        ["finished", "profile", "verdict", "within 5° of clean", "seconds", "error"],
        rows,
    )


PATCH_PREVIEW = "Patch preview"  # how the preview's caption begins (html_report.has_patch_preview)


def patch_preview_figure(
    original: Path, protected: Path, spec: Any, mark: Mapping[str, Any] | None = None
) -> Figure | None:
    """poisoner.preview of one original and its patched file (image files only), as a viewer shows
    them, zoomed on the mark (shown_pair: where ppd recorded it, given mark; else where the pixels
    changed); the caption says where it is."""
    from poisoner.orientation import position_words
    from poisoner.preview import render_preview
    from poisoner.spec import PatchPlacement

    try:
        a, b, box, recorded = shown_pair(original, protected, mark)
        if box is None:
            return Figure(f"{PATCH_PREVIEW}: {protected.name}: no pixel changed", png_bytes(b))
        (x0, y0, x1, y1), (h, w) = box, a.shape[:2]
        side = max(x1 - x0, y1 - y0)
        zoom = PatchPlacement(max(0, min(x0, w - side)), max(0, min(y0, h - side)), side, 1, 255, 255,
                              spec.pattern, spec.seed)  # fmt: skip
        pixels = render_preview(a, b, zoom, labels=("original", f"patched ({protected.name})"))
    except Exception as exc:  # a preview is a nicety: never fail the report for it
        log.warning("no patch preview", extra={"file": str(protected), "error": str(exc)})
        return None
    # a per-photo mark's own words: split squares each have theirs, not their box's middle
    words = ((mark or {}).get("place") or {}).get("words") if recorded else None
    how = "as recorded when ppd patched it" if recorded else "where the pixels changed"
    return Figure(
        f"{PATCH_PREVIEW}: original | patched ({protected.name}), zoom on the patch below; mark at the "
        f"{words or position_words(box, w, h)}, within pixels ({x0},{y0})-({x1},{y1}) as shown ({how})",
        png_bytes(pixels),
    )


def shown_pair(
    original: Path, protected: Path, mark: Mapping[str, Any] | None = None
) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int] | None, bool]:
    """(original, patched, the mark's box, recorded): both pictures as a viewer shows them, decoded as
    `ppd poison` decodes them (HEIC through pillow-heif: the report's process had no opener, and no
    preview), the patched file's EXIF orientation applied. The box is where ppd recorded the mark
    when it patched the file (mark: daemon.protect.job.report_detail's "place" or "placement";
    recorded True), else where the pixels differ (None: none do), which is the whole picture for a
    file ppd re-encodes whole (HEIC)."""
    from poisoner.image.read import decoded_rgb
    from poisoner.preview import orient

    (a, _), (b, orientation) = decoded_rgb(original), decoded_rgb(protected)
    stored = b.shape[1], b.shape[0]
    a, b = orient(a, orientation), orient(b, orientation)
    if a.shape != b.shape:
        raise ValueError(
            f"the original is {a.shape[1]}x{a.shape[0]}, the patched file {b.shape[1]}x{b.shape[0]}"
        )
    box = recorded_box(mark, orientation, *stored) if mark else None
    if box is not None:
        return a, b, box, True
    ys, xs = np.nonzero(np.any(a != b, axis=2))
    changed = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1) if xs.size else None
    return a, b, changed, False


def recorded_box(
    mark: Mapping[str, Any], orientation: int | None, width: int, height: int
) -> tuple[int, int, int, int] | None:
    """The mark's box as the picture is shown, from what ppd recorded when it patched the file (a
    stored width x height picture): a per-photo mark's own box, else the spec's square turned as the
    picture is shown; None when neither was recorded (a video, an older ppd)."""
    from poisoner.orientation import turn_square

    place, placement = mark.get("place") or {}, mark.get("placement") or {}
    if len(place.get("box") or ()) == 4:
        x0, y0, x1, y1 = (int(v) for v in place["box"])
        return x0, y0, x1, y1
    if {"x", "y", "size"} <= placement.keys():
        side = int(placement["size"])
        x, y = turn_square(int(placement["x"]), int(placement["y"]), side, orientation or 1, width, height)
        return x, y, x + side, y + side
    return None


# ---- what a viewer sees (verifier.visibility) -------------------------------------------------
def visibility_table(visibility: Mapping[str, Any]) -> Table:
    """Per measured file and the worst over them: FLIP figures, changed area, corner, subject."""
    rows = []
    for item in visibility.get("images") or []:
        rows.append(_visibility_row(str(item.get("name")), item.get("figures") or {}))
    rows.append(_visibility_row(f"worst of {visibility.get('measured')}", visibility.get("worst") or {}))
    header = [
        "image", "judged at (px wide)", "FLIP mean", "FLIP p99", "FLIP p99.9", "FLIP max",
        "area FLIP > 0.5", "changed area", "in one corner", "on subject mask",
        "p99.9 vs JPEG q85 (its p99.9)",
    ]  # fmt: skip
    return Table("Visibility: what a viewer sees (FLIP)", header, rows)


def _visibility_row(name: str, v: Mapping[str, Any]) -> list[str]:
    subject = {True: "YES", False: "no", None: "no mask"}[v.get("touches_subject")]
    corner = {True: "yes", False: "NO", None: "nothing changed"}[v.get("in_one_corner")]
    return [
        name,
        fmt(v.get("display_width")),
        fmt(v.get("flip_mean"), 4),
        fmt(v.get("flip_p99"), 3),
        fmt(v.get("flip_p999"), 3),
        fmt(v.get("flip_max"), 3),
        f"{100 * float(v.get('area_above_half') or 0):.3f}%",
        f"{100 * float(v.get('changed_area') or 0):.3f}%",
        corner,
        subject,
        f"{fmt(v.get('p999_vs_jpeg'), 1)}x ({fmt(v.get('jpeg_p999'), 3)})",
    ]


def visibility_note(visibility: Mapping[str, Any] | None) -> str:
    """How visibility was measured, or that it was not."""
    if not visibility:
        return (
            "Visibility was not measured in this verification (older run, or visibility_images = 0): "
            "run `ppd verify` again to see it."
        )
    worst = visibility.get("worst") or {}
    return (
        f"Visibility is measured on {visibility.get('measured')} of {visibility.get('total')} images "
        "(spread over the set, to bound its cost), each shown min(1920, its width) px wide at "
        f"{fmt(worst.get('ppd'), 0)} pixels per degree (NVIDIA FLIP); a JPEG q85 re-encode of the same "
        "image is the accepted-as-invisible yardstick. FLIP > 0.5 marks a clearly visible difference."
    )


def mark_at_display_figure(
    original: Path, protected: Path, mark: Mapping[str, Any] | None = None
) -> Figure | None:
    """One protected image at display size (min(1920, width) px wide, as a viewer shows it) with an
    enlarged view of its mark below (original | protected; shown_pair: where ppd recorded it, given
    mark, else where the pixels differ)."""
    from verifier.visibility import DISPLAY_WIDTH

    try:
        a, b, box, recorded = shown_pair(original, protected, mark)
        pixels = _display_with_zoom(a, b, min(DISPLAY_WIDTH, a.shape[1]), box)
    except Exception as exc:  # a picture is a nicety: never fail the report for it
        log.warning("no display picture", extra={"file": str(protected), "error": str(exc)})
        return None
    where = "no pixel differs"
    if box is not None:
        what = "the mark as recorded" if recorded else "changed pixels"
        where = f"{what} in x {box[0]}–{box[2]}, y {box[1]}–{box[3]}"
    return Figure(
        f"{protected.name} at display size ({pixels.shape[1]} px wide); below, enlarged: "
        f"original | protected around the mark ({where})",
        png_bytes(pixels),
    )


def _display_with_zoom(
    a: np.ndarray, b: np.ndarray, width: int, box: tuple[int, int, int, int] | None
) -> np.ndarray:
    """The protected image resized to width, and below it the region of both around box, enlarged."""
    h, w = b.shape[:2]
    display = (
        b
        if w == width
        else np.asarray(
            Image.fromarray(b).resize((width, max(1, round(h * width / w))), Image.Resampling.LANCZOS)
        )
    )
    if box is None:
        return display
    pad = max(8, (box[2] - box[0]) // 4, (box[3] - box[1]) // 4)
    left, top = max(0, box[0] - pad), max(0, box[1] - pad)
    right, bottom = min(w, box[2] + pad), min(h, box[3] + pad)
    half = max(16, width // 2 - 8)
    crops = [_fit(x[top:bottom, left:right], half) for x in (a, b)]
    gap = np.full((crops[0].shape[0], 8, 3), 255, np.uint8)
    zoom = np.concatenate([crops[0], gap, crops[1]], axis=1)[:, :width]
    canvas = np.full((display.shape[0] + 8 + zoom.shape[0], width, 3), 255, np.uint8)
    canvas[: display.shape[0]] = display
    canvas[display.shape[0] + 8 :, : zoom.shape[1]] = zoom
    return canvas


def _fit(crop: np.ndarray, width: int) -> np.ndarray:
    """A crop enlarged by a whole factor (nearest: the pixels as they are) or shrunk to width."""
    w = crop.shape[1]
    if w > width:
        height = max(1, round(crop.shape[0] * width / w))
        return np.asarray(Image.fromarray(crop).resize((width, height), Image.Resampling.LANCZOS))
    scale = max(1, min(8, width // max(1, w)))
    return np.repeat(np.repeat(crop, scale, axis=0), scale, axis=1)
