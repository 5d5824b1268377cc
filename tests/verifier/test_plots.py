"""Figures (issue 7): valid PNGs that show what they claim; camera alignment for the trajectories."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from verifier import plots
from verifier.experiment import Stat
from verifier.poses import Pose

ROOT = Path(__file__).resolve().parents[2]


def _img(png: bytes) -> np.ndarray:
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def _has_colour(img: np.ndarray, hex_colour: str, tol: int = 8) -> bool:
    rgb = np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)])
    return bool((np.abs(img.astype(int) - rgb).max(axis=-1) <= tol).any())


def _entry(label: str, kind: str, groups: tuple[str, ...], params: dict, **stats: float) -> dict:
    return {"label": label, "kind": kind, "groups": groups, "params": params,
            **{k: Stat(v, 0.01, 2) for k, v in stats.items()}}  # fmt: skip


ENTRIES = [
    _entry("clean", "clean", ("clean",), {}, cvp_ssim=1.0, within5_of_clean=1.0),
    _entry("P=12 b=4", "patch", ("patch_size",), {"patch_size": 12}, cvp_ssim=0.9996, within5_of_clean=0.1),
    _entry("P=48 b=4", "patch", ("patch_size",), {"patch_size": 48}, cvp_ssim=0.995, within5_of_clean=0.0),
    _entry("blur=11", "baseline", ("baselines",), {"kind": "blur"}, cvp_ssim=0.86, within5_of_clean=0.95),
]


def test_tradeoff_has_a_point_per_kind_and_falls_back_to_verifier_one() -> None:
    assert plots.degradation_axis(ENTRIES) == "within5_of_clean"  # no render SSIM anywhere
    img = _img(plots.tradeoff_png(ENTRIES))
    for colour in plots.KIND_COLOURS.values():
        assert _has_colour(img, colour)
    only_patches = [e for e in ENTRIES if e["kind"] == "patch"]
    img = _img(plots.tradeoff_png(only_patches))
    assert _has_colour(img, plots.KIND_COLOURS["patch"])
    assert not _has_colour(img, plots.KIND_COLOURS["baseline"])
    with_render = [*ENTRIES[:1], {**ENTRIES[1], "render_ssim": Stat(0.8, None, 1)}]
    assert plots.degradation_axis(with_render) == "render_ssim"


def test_parameter_figures_only_for_swept_parameters() -> None:
    figures = plots.parameter_pngs(ENTRIES)
    assert set(figures) == {"patch_size"}  # baselines are not a parameter; one value is not a sweep
    img = _img(figures["patch_size"])
    assert img.shape[0] > 200 and _has_colour(img, plots.KIND_COLOURS["patch"])


def _rot(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def test_trajectories_align_a_transformed_copy_onto_clean() -> None:
    rng = np.random.default_rng(1)
    clean: dict[str, Pose] = {}
    for i in range(8):
        r = _rot(45 * i)
        centre = rng.normal(size=3) * 3
        clean[f"v{i}"] = (r, -r @ centre)
    # the same cameras in another frame: x' = 2 R x + t  ->  R_cw' = R_cw R^T, C' = 2 R C + t
    frame_r, t = _rot(30), np.array([1.0, -2.0, 0.5])
    moved = {}
    for name, (r, tr) in clean.items():
        c = -r.T @ tr
        c2 = 2 * frame_r @ c + t
        r2 = r @ frame_r.T
        moved[name] = (r2, -r2 @ c2)
    aligned = plots.aligned_centres(moved, clean)
    for name, (r, tr) in clean.items():
        assert np.allclose(aligned[name], -r.T @ tr, atol=1e-6)
    img = _img(plots.trajectory_png(clean, moved))
    assert _has_colour(img, plots.KIND_COLOURS["clean"]) and _has_colour(img, plots.KIND_COLOURS["patch"])


def test_plots_never_load_pyplot_or_a_gui_backend() -> None:
    code = (
        "import sys; from verifier import plots; from verifier.experiment import Stat;"
        "plots.trajectory_png({}, {});"
        "print('matplotlib.pyplot' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_view_box_follows_the_clean_cameras_not_wild_poisoned_ones() -> None:
    clean = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 6, 12)])
    centre, half = plots._view_box(clean)
    assert np.allclose(centre, np.median(clean, axis=0)) and 1.0 < half < 3.5
    wild = {"v0": (np.eye(3), np.array([500.0, 0.0, 0.0]))}
    img = _img(plots.trajectory_png({f"v{i}": (np.eye(3), -c) for i, c in enumerate(clean)}, wild))
    assert _has_colour(img, plots.KIND_COLOURS["clean"])
