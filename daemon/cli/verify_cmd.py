"""`ppd verify DATASET|FOLDER`: prove protection with real COLMAP, clean vs poisoned.

Light at import: the verifier modules load inside the command, and pycolmap only ever runs in
SfM child processes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from daemon.cli.errors import die, one_line
from daemon.cli.interrupt import TermAsInterrupt
from daemon.cli.options import dataset_option, folder_option, subject_masks_option
from poisoner.errors import ExitStatus, PpdError
from verifier.verdict import Verdict

if TYPE_CHECKING:
    from rich.console import Console

PROFILE_CHOICES = ("default", "hardened", "published", "global", "masked", "all")

def checked_profiles(given: list[str], option: str) -> tuple[str, ...]:
    """The profiles named, in the usual order (several -p: every one given; only the last was run: a
    black-box review); an unknown one is one line, exit 2 (`ppd demo --profiles nosuch` said nothing)."""
    from verifier.verification import PROFILES

    for one in given:
        if one not in PROFILE_CHOICES:
            raise die(f"{option} must be one of {', '.join(PROFILE_CHOICES)}; got {one!r}", ExitStatus.USAGE)
    return PROFILES if "all" in given else tuple(p for p in PROFILES if p in given)


VERIFY_EXAMPLES = """\b
Examples:
  ppd verify castle                       a dataset
  ppd verify ~/shoots/castle              the folder `ppd poison` patched
  ppd verify pub/ --clean originals/      any patched folder and its originals
"""


def _verify_folder(path: Path, clean: Path, out: Path | None, profiles: tuple[str, ...], options: Any,
                   console: Console) -> Any:  # fmt: skip
    """Any patched folder against its clean originals (nothing from the store)."""
    import dataclasses

    from daemon.cli.verify_progress import progress_display
    from daemon.paths import AppPaths
    from poisoner import scratch
    from verifier.verification import VerificationInputError, verify_folders

    if not path.is_dir():
        raise VerificationInputError(f"{path} is not a folder (with --clean, give the patched folder)")
    # Ours until the report is in it: a run killed outright leaves it to the next ppd's sweep.
    out_dir = out or scratch.make_owned_temp_dir("ppd-verify-")
    # issue 30: the clean reference of these originals is reused until they change (a few kept)
    cache = AppPaths.from_env().cache_dir / "verify-clean"
    options = dataclasses.replace(options, clean_cache_dir=cache, clean_cache_keep=3)
    try:
        with progress_display(console, str(path)) as on_progress:
            options = dataclasses.replace(options, on_progress=on_progress)
            report = verify_folders(clean, path, out_dir, profiles, options)
    except BaseException:  # a run with no report leaves no folder of ppd's behind (a given --out stays)
        if out is None:
            scratch.remove_owned(out_dir)
        raise
    if out is None:
        scratch.release(out_dir, keep=True)  # the report's folder is the user's now
    return report


def _verify_stored(target: str | None, dataset: str | None, folder: Path | None,
                   profiles: tuple[str, ...], options: Any, console: Console) -> dict[str, Any]:  # fmt: skip
    """A dataset of the store (named, or the folder ppd patched) against its vault originals: the
    report's dict as the dataset is published (_as_published)."""
    import sqlite3

    from daemon.cli.targets import resolve_target, say_note
    from daemon.context import AppContext
    from daemon.verification.verify import verify_dataset
    from verifier.verification import VerificationInputError

    try:
        ctx = AppContext.open()
    except (PpdError, OSError, sqlite3.Error) as exc:  # no usable store: only --clean can verify a folder
        raise VerificationInputError(
            f"ppd's store cannot be opened ({one_line(exc)}); for a folder, "
            "give its clean originals with --clean DIR"
        ) from None
    try:
        chosen = resolve_target(ctx.store, target, dataset=dataset, folder=folder)
        say_note(chosen, console)
        if chosen.dataset is None:
            raise VerificationInputError(
                f"{chosen.folder} is not a folder ppd patched: give its clean originals with --clean DIR"
            )
        import dataclasses

        from daemon.cli.verify_progress import progress_display

        with progress_display(console, chosen.dataset) as on_progress:
            options = dataclasses.replace(options, on_progress=on_progress)
            report = verify_dataset(ctx, chosen.dataset, profiles, options)
        return _as_published(report.to_dict(), ctx, chosen.dataset, _say_left_out(ctx, chosen.dataset))
    finally:
        ctx.close()


def _say_left_out(ctx: Any, dataset: str) -> dict[str, Any]:
    """The dataset's files the verification did not measure, on stderr: it reconstructs from the
    patched files only, and a restored or failed photo published beside them is not protected (a
    black-box review: "protected" with exit 0 and nothing said of 5 restored originals). Returns
    the dataset's status (status_queries.dataset_status)."""
    from daemon.cli.output import err_console
    from daemon.cli.status_queries import dataset_status, unprotected_files

    d = dataset_status(ctx, dataset)
    if left := unprotected_files(d):
        err_console().print(f"not verified, and NOT protected: {', '.join(left)} (only the {d['patched']} "
                            "patched files were measured); `ppd status --failed` and `ppd poison` say more",
                            markup=False, highlight=False)  # fmt: skip
    return d


def _as_published(report: dict[str, Any], ctx: Any, dataset: str, d: dict[str, Any]) -> dict[str, Any]:
    """The report with the verdict of the dataset as it is published: NOT protected while a file of it
    is left without the mark (the files the line above names: unprotected_files), whatever SfM
    measured on the patched ones, which "patched_files_verdict" keeps (a black-box review: "overall:
    protected", exit 0, `--json` "protected" with a failed photo in the published folder)."""
    from daemon.cli.status_queries import unprotected_files
    from daemon.datasets.folder_count import unmarked_names

    left = unprotected_files(d)
    names = unmarked_names(ctx, dataset, d["root"]) if left else []
    measured = report["verdict"]
    verdict = Verdict.NOT_PROTECTED.value if left else measured
    return {**report, "verdict": verdict, "patched_files_verdict": measured, "unmarked": left,
            "unmarked_files": names, "num_patched": d["patched"]}  # fmt: skip


def _options(timeout: float, ground_truth: Path | None, splat: bool, splat_budget: float,
             white_background: bool, subject_masks: Path | None, seeds: int = 1) -> Any:  # fmt: skip
    """The run's VerifyOptions from the command line (a --subject-masks that is no folder, --seeds
    out of range: one line)."""
    from daemon.config import seeds_problem
    from verifier.verification import VerifyOptions

    if subject_masks is not None and not subject_masks.is_dir():
        raise die(f"--subject-masks: {subject_masks} is not a folder", ExitStatus.USAGE)
    if why := seeds_problem(seeds):
        raise die(f"--seeds {why}", ExitStatus.USAGE)
    options = VerifyOptions(
        timeout_s=timeout, ground_truth=ground_truth, splat=splat, seeds=seeds,
        subject_masks=subject_masks.absolute() if subject_masks is not None else None,
    )  # fmt: skip
    options.splat_options.update(time_budget_s=splat_budget, white_background=white_background)
    return options


def verify(
    target: str | None = typer.Argument(
        None, help="A dataset, or a folder ppd patched (or any patched folder, with --clean)."
    ),
    dataset: str | None = dataset_option("Verify this dataset (explicit form)."),
    folder: Path | None = folder_option("Verify this folder (explicit form)."),
    profile: list[str] = typer.Option(
        ["all"], "--profile", "-p",
        help="Attacker profile: default, hardened, published, global (COLMAP's global mapper), "
        "masked (corners masked out) or all; repeat it for several.",
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
    subject_masks: Path | None = subject_masks_option(),
    seeds: int = typer.Option(
        1, "--seeds", metavar="N",
        help="COLMAP runs per attacker on the patched set (seeds 0..N-1 on the same features and raw "
        "matches): the weakest counts, as an attacker keeps the best.",
    ),
) -> None:
    """Run COLMAP (structure from motion) on the originals and on the patched set and say
    whether the patch protects: protected, weak, NOT protected, or could not be verified.

    The verdict is the weakest of default, hardened, published, global and masked (an attacker who
    masks the four corner regions: it defeats every corner (watermark-like) mark by construction, and
    its own line says so) among those whose COLMAP reconstructs the originals: one that does not is no
    threat measured, and the overall line names it. Each is one COLMAP run with seed 0 unless --seeds
    asks for more: an attacker may rerun with other seeds, and on a set near the line another seed can
    recover more cameras."""
    from rich.console import Console

    from daemon.cli.coerce import EMPTY_PATH
    from daemon.cli.targets import TargetError
    from daemon.cli.verify_tables import json_safe, print_report
    from verifier.verification import VerificationInputError

    console = Console(stderr=as_json, soft_wrap=True, highlight=False, emoji=False)  # names as typed
    profiles = checked_profiles(profile, "--profile")
    options = _options(timeout, ground_truth, splat, splat_budget, white_background, subject_masks, seeds)
    try:
        with TermAsInterrupt():  # SIGTERM ends it as Ctrl-C does: children ended, nothing left behind
            if clean is not None:
                if target == "":  # Path("") is '.', as no target means
                    raise TargetError(EMPTY_PATH)
                path = folder or Path(target or "")
                report = _verify_folder(path, clean, out, profiles, options, console).to_dict()
            else:
                report = _verify_stored(target, dataset, folder, profiles, options, console)
    except (VerificationInputError, TargetError, ValueError, OSError) as exc:
        raise die(str(exc), ExitStatus.USAGE) from None
    if as_json:
        print(json.dumps(json_safe(report), indent=1))
    else:
        print_report(report, console)
        console.print(f"models: {report['out_dir']}")
    raise typer.Exit(0 if report["verdict"] == Verdict.PROTECTED else 1)


def register(app: typer.Typer) -> None:
    app.command("verify", epilog=VERIFY_EXAMPLES)(verify)
