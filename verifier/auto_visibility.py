"""What a viewer sees of a candidate patch on a dataset's sample, against the visibility budget.

Step 2 of the preflight (verifier.auto_search) and the whole of the interim choice: each sample image
clean vs poisoned through FLIP (verifier.visibility) at the budget's viewing condition, the worst
image per figure, and how much of the budget (verifier.auto_options.VisibilityBudget) that uses.
Whole-image SSIM (as 3DGS) and LPIPS are measured alongside and reported, never gating.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import PIL.Image  # noqa: F401  (before anything that could bring pycolmap here: pillow 13 + pycolmap 4.2.1)

from verifier.auto_options import VisibilityBudget
from verifier.metrics import ssim_map

SSIM_RADIUS = 5  # 3DGS SSIM: 11 x 11 window


class ImageVisibility(msgspec.Struct, frozen=True):
    """One sample image, clean vs poisoned: what a viewer sees (FLIP) and the paper's figures."""

    display_width: int  # the width it was judged at (the budget's, or the image's own when smaller)
    noticeable_area: float  # fraction of the displayed picture with FLIP > 0.5
    flip_p999: float
    flip_mean: float
    changed_area: float  # fraction of pixels that differ at all
    in_one_corner: bool | None  # None: nothing changed
    p999_vs_jpeg: float | None  # flip_p999 / a JPEG q85 re-encode's (None: not measured)
    ssim: float  # whole image, 3DGS formula (reported)
    lpips: float | None  # None: not measured (reported)


class SampleVisibility(msgspec.Struct, frozen=True):
    """A candidate's visibility on the sample: the worst image for each figure."""

    images: int
    display_width: int  # the widest the sample images were judged at
    noticeable_area_max: float
    flip_p999_max: float
    flip_mean_max: float
    changed_area_max: float
    in_one_corner: bool | None  # every image's change in one corner region (None: nothing changed)
    p999_vs_jpeg_max: float | None
    ssim_min: float | None
    ssim_mean: float | None
    lpips_max: float | None
    lpips_mean: float | None


def load_rgb8(path: Path) -> np.ndarray:
    """H x W x 3 uint8, decoded as ppd decodes what it patches (poisoner.image.read: HEIC and AVIF
    too); transparency composited on white (as Verifier I's round trip). ImageFormatError (one line)
    when it does not decode."""
    from poisoner.image.read import open_decoded
    from verifier.verification import to_rgb

    with open_decoded(path, path.read_bytes()) as im:
        rgb = to_rgb(im)
    return np.asarray(rgb, dtype=np.uint8)


def load_rgb(path: Path) -> np.ndarray:
    """H x W x 3 float in [0, 1] (load_rgb8 scaled)."""
    return load_rgb8(path).astype(np.float64) / 255.0


def changed_box(a: np.ndarray, b: np.ndarray) -> tuple[int, int, int, int] | None:
    """(y0, x0, y1, x1), exclusive ends, of the pixels where a and b differ; None when identical."""
    diff = np.any(a != b, axis=2) if a.ndim == 3 else a != b
    rows, cols = np.flatnonzero(diff.any(axis=1)), np.flatnonzero(diff.any(axis=0))
    if rows.size == 0:
        return None
    return int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1


def whole_image_ssim(clean: np.ndarray, poisoned: np.ndarray) -> float:
    """`verifier.metrics.ssim` over the whole image, computed only around the change.

    Why: a patch changes a few thousand pixels of a 6-megapixel photo. Where both windows see
    identical pixels the SSIM map is exactly 1, so the whole-image mean is 1 minus the deficit
    summed over the changed box grown by the window radius; the crop keeps one more radius of
    real context so every window in that box sees what it sees in the full image (crop edges
    inside the image never reach the summed pixels; edges on the image border pad with zeros
    exactly as the full computation does). Equal to the full computation (tested)."""
    a, b = np.asarray(clean, dtype=np.float64), np.asarray(poisoned, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    box = changed_box(a, b)
    if box is None:
        return 1.0
    h, w, c = a.shape
    y0, x0, y1, x1 = box
    r = SSIM_RADIUS
    sy0, sx0, sy1, sx1 = max(0, y0 - r), max(0, x0 - r), min(h, y1 + r), min(w, x1 + r)
    cy0, cx0, cy1, cx1 = max(0, sy0 - r), max(0, sx0 - r), min(h, sy1 + r), min(w, sx1 + r)
    smap = ssim_map(a[cy0:cy1, cx0:cx1], b[cy0:cy1, cx0:cx1])
    inner = smap[sy0 - cy0 : sy1 - cy0, sx0 - cx0 : sx1 - cx0]
    return float(1.0 - np.sum(1.0 - inner) / (h * w * c))


def shown_width(image: np.ndarray, budget: VisibilityBudget) -> int:
    """The width the image is judged at: the budget's display width, or its own when smaller (a
    small image is shown at its size, not blown up; as verifier.visibility.measure_pairs does)."""
    return min(budget.display_width, int(image.shape[1]))


def jpeg_reference_p999(clean: np.ndarray, budget: VisibilityBudget) -> float:
    """FLIP p99.9 of a JPEG q85 re-encode of the clean image at the budget's viewing condition:
    what creators accept as invisible (computed once per image, not per candidate)."""
    from verifier.visibility import jpeg_reencode, visibility_report

    return visibility_report(
        clean, jpeg_reencode(clean), display_width=shown_width(clean, budget), jpeg_reference=False
    ).flip_p999


def measure_image(
    clean: np.ndarray,
    poisoned: np.ndarray,
    budget: VisibilityBudget,
    lpips_model: Any = None,
    jpeg_p999: float | None = None,
) -> ImageVisibility:
    """What a viewer sees of the change (uint8 H x W x 3 in), and SSIM/LPIPS for the record.

    lpips_model: a `verifier.lpips.Lpips` or None (then lpips is None: not measured)."""
    from verifier.visibility import visibility_report

    v = visibility_report(
        clean, poisoned, display_width=shown_width(clean, budget), corner_region=budget.corner_region,
        jpeg_reference=False,
    )  # fmt: skip
    a, b = clean.astype(np.float64) / 255.0, poisoned.astype(np.float64) / 255.0
    return ImageVisibility(
        display_width=v.display_width,
        noticeable_area=v.area_above_half,
        flip_p999=v.flip_p999,
        flip_mean=v.flip_mean,
        changed_area=v.changed_area,
        in_one_corner=v.in_one_corner,
        p999_vs_jpeg=v.flip_p999 / jpeg_p999 if jpeg_p999 else None,
        ssim=whole_image_ssim(a, b),
        lpips=None if lpips_model is None else float(lpips_model.distance(a, b)),
    )


def open_lpips(net: str = "vgg") -> tuple[Any, str | None]:
    """(model, None) or (None, why LPIPS is not measured here)."""
    if net == "none":
        return None, "not requested (lpips_net = none)"
    try:
        from verifier.lpips import Lpips, lpips_available
    except ImportError as exc:  # torch missing
        return None, f"LPIPS unavailable ({exc})"
    ok, reason = lpips_available(net)
    if not ok:
        return None, reason
    return Lpips(net), None


def _worst(values: Sequence[float | None], pick: Any) -> float | None:
    present = [float(v) for v in values if v is not None]
    return pick(present) if present else None


def summarise_visibility(per_image: Sequence[ImageVisibility]) -> SampleVisibility:
    """The worst image for each figure (a viewer notices the worst picture, not the average)."""
    corners = [v.in_one_corner for v in per_image if v.in_one_corner is not None]
    ssims = [v.ssim for v in per_image]
    lp = [v.lpips for v in per_image if v.lpips is not None]
    return SampleVisibility(
        images=len(per_image),
        display_width=max(v.display_width for v in per_image),
        noticeable_area_max=max(v.noticeable_area for v in per_image),
        flip_p999_max=max(v.flip_p999 for v in per_image),
        flip_mean_max=max(v.flip_mean for v in per_image),
        changed_area_max=max(v.changed_area for v in per_image),
        in_one_corner=all(corners) if corners else None,
        p999_vs_jpeg_max=_worst([v.p999_vs_jpeg for v in per_image], max),
        ssim_min=min(ssims) if ssims else None,
        ssim_mean=float(np.mean(ssims)) if ssims else None,
        lpips_max=max(lp) if lp else None,
        lpips_mean=float(np.mean(lp)) if lp else None,
    )


def budget_use(vis: SampleVisibility, budget: VisibilityBudget) -> float:
    """The largest fraction of a budget limit the worst image uses: <= 1 fits, > 1 exceeds.

    One number so candidates can be ordered by measured visibility; the JPEG ratio counts when the
    budget gates it (max_p999_vs_jpeg > 0) and it was measured."""
    parts = [vis.noticeable_area_max / max(1e-12, budget.max_noticeable_area)]
    if budget.max_p999_vs_jpeg > 0 and vis.p999_vs_jpeg_max is not None:
        parts.append(vis.p999_vs_jpeg_max / budget.max_p999_vs_jpeg)
    return float(max(parts))


def within_budget(vis: SampleVisibility, budget: VisibilityBudget) -> bool:
    """Whether the candidate fits: every limit, and one corner region when the budget asks for it."""
    outside_corner = budget.corner_only and vis.in_one_corner is False
    return budget_use(vis, budget) <= 1.0 and not outside_corner


def budget_notes(vis: SampleVisibility, budget: VisibilityBudget) -> list[str]:
    """Plain sentences on what exceeds the budget (empty when it fits)."""
    notes = []
    if vis.noticeable_area_max > budget.max_noticeable_area:
        notes.append(
            f"{vis.noticeable_area_max:.2%} of the picture noticeably changed (FLIP > 0.5) > "
            f"{budget.max_noticeable_area:.2%} on the worst sample image"
        )
    ratio = vis.p999_vs_jpeg_max
    if budget.max_p999_vs_jpeg > 0 and ratio is not None and ratio > budget.max_p999_vs_jpeg:
        notes.append(f"FLIP p99.9 {ratio:.1f}x a JPEG q85 re-encode's > {budget.max_p999_vs_jpeg:g}x")
    if budget.corner_only and vis.in_one_corner is False:
        notes.append(f"changes leave the corner region ({budget.corner_region:.0%} of width and height)")
    return notes
