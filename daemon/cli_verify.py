"""`ppd verify DATASET|PATH`: prove protection with real COLMAP, clean vs poisoned.

Light at import (typer, rich only): the verifier modules are imported inside the command, and
pycolmap only ever runs in SfM child processes.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.table import Table

from verifier.verdict import verdict_words

PROFILE_CHOICES = ("default", "hardened", "published", "masked", "all")
VERDICT_STYLE = {
    "protected": "bold green",
    "weak": "bold yellow",
    "not_protected": "bold red",
    "sfm_crashed": "bold magenta",
    "inconclusive": "bold blue",
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
        ("SfM time (s)", _num(clean.get("elapsed_s")), _num(poisoned.get("elapsed_s"))),
    ]  # fmt: skip


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
    for t in (5, 10, 20):
        table.add_row(f"cameras within {t}° of clean", "100%", _num(vc.get(f"frac_within_{t}deg"), True))
    table.add_row("median rotation error (°)", "0", _num(vc.get("median_rotation_error_deg")))
    table.add_row(
        "median relative rotation error (°)", "0", _num(vc.get("median_relative_rotation_error_deg"))
    )
    aucs = " / ".join(_num(vc.get(f"auc_{t}")) for t in (5, 10, 20))
    table.add_row("pair pose AUC@5/10/20 vs clean", "1 / 1 / 1", aucs)
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
    v = report["verdict"]
    console.print(f"overall (weakest profile): [{VERDICT_STYLE.get(v, 'bold')}]{verdict_words(v)}[/]")


def _json_safe(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    return x


VERIFY_EXAMPLES = """\b
Examples:
  ppd verify castle                       a dataset
  ppd verify ~/shoots/castle              the folder `ppd poison` patched
  ppd verify pub/ --clean originals/      any patched folder and its originals
"""


def register(app: typer.Typer) -> None:
    @app.command("verify", epilog=VERIFY_EXAMPLES)
    def verify(
        target: str | None = typer.Argument(
            None, help="A dataset, or a folder ppd patched (or any patched folder, with --clean)."
        ),
        dataset: str | None = typer.Option(None, "--dataset", help="Verify this dataset (explicit form)."),
        folder: Path | None = typer.Option(None, "--folder", help="Verify this folder (explicit form)."),
        profile: str = typer.Option(
            "all", "--profile", "-p",
            help="Attacker profile: default, hardened, published, masked (corners masked out) or all.",
        ),
        as_json: bool = typer.Option(False, "--json", help="Print the verdict and every metric as JSON."),
        clean: Path | None = typer.Option(
            None, "--clean", metavar="DIR", help="Clean originals of a folder ppd did not patch (same names)."
        ),
        ground_truth: Path | None = typer.Option(
            None, "--gt", help="Ground-truth cameras: transforms_train.json or a gt_dense_cameras folder."
        ),
        out: Path | None = typer.Option(None, "--out", help="Where to keep the SfM models (with --clean)."),
        timeout: float = typer.Option(1800.0, "--timeout", help="Seconds allowed per SfM run."),
        splat: bool = typer.Option(
            False, "--splat", help="Also train clean and poisoned Gaussian splats (renders' quality)."
        ),
        splat_budget: float = typer.Option(
            150.0, "--splat-budget", help="Seconds of splat training per side (with --splat)."
        ),
        white_background: bool = typer.Option(
            False, "--white-background", help="Composite transparent images on white (NeRF-Synthetic)."
        ),
    ) -> None:
        """Run COLMAP (structure from motion) on the originals and on the patched set and say
        whether the patch protects: protected, weak, NOT protected, or could not be verified."""
        from daemon.cli_common import EXIT_USAGE, die, warning
        from daemon.cli_targets import TargetError, resolve_target
        from daemon.verify import verify_dataset
        from verifier.verification import VerificationInputError, VerifyOptions, verify_folders

        console = Console(stderr=as_json, soft_wrap=True, highlight=False)
        if profile not in PROFILE_CHOICES:
            raise die(f"--profile must be one of {', '.join(PROFILE_CHOICES)}", EXIT_USAGE)
        from verifier.verification import PROFILES

        profiles = PROFILES if profile == "all" else (profile,)
        options = VerifyOptions(timeout_s=timeout, ground_truth=ground_truth, splat=splat)
        options.splat_options.update(time_budget_s=splat_budget, white_background=white_background)
        try:
            from daemon.context import AppContext

            if clean is not None:
                path = folder or Path(target or "")
                if not path.is_dir():
                    raise VerificationInputError(
                        f"{path} is not a folder (with --clean, give the patched folder)"
                    )
                out_dir = out or Path(tempfile.mkdtemp(prefix="ppd-verify-"))
                with console.status("running COLMAP on clean and patched sets…"):
                    report = verify_folders(clean, path, out_dir, profiles, options)
            else:
                try:
                    ctx = AppContext.open()
                except Exception as exc:  # no usable store: only --clean can verify a folder
                    raise VerificationInputError(
                        f"ppd's store cannot be opened ({str(exc).splitlines()[0]}); for a folder, "
                        "give its clean originals with --clean DIR"
                    ) from None
                try:
                    chosen = resolve_target(ctx.store, target, dataset=dataset, folder=folder)
                    if chosen.note and chosen.folder is None:
                        warning(chosen.note)  # a name that is also a folder here: say which was taken
                    elif chosen.note:
                        console.print(chosen.note, markup=False)
                    if chosen.dataset is None:
                        raise VerificationInputError(
                            f"{chosen.folder} is not a folder ppd patched: give its clean originals "
                            "with --clean DIR"
                        )
                    with console.status(f"verifying dataset {chosen.dataset}…"):
                        report = verify_dataset(ctx, chosen.dataset, profiles, options)
                finally:
                    ctx.close()
        except (VerificationInputError, TargetError, ValueError, OSError) as exc:
            raise die(str(exc), EXIT_USAGE) from None
        data = report.to_dict()
        if as_json:
            print(json.dumps(_json_safe(data), indent=1))
        else:
            print_report(data, console)
            console.print(f"models: {report.out_dir}")
        raise typer.Exit(0 if report.verdict == "protected" else 1)
