"""Reports on the daemon's datasets: what `ppd report DATASET` and `ppd status` show.

The page itself is the verifier's (verifier.html_report); this module gathers a dataset's Store rows,
its protection state and an (original, patched) pair for the patch preview, and owns where a
dataset's latest report lives: `<data_dir>/reports/<dataset>/latest.html`.

`ppd status` imports this module for `report_path`: the verifier's report (numpy, PIL) loads only
when a report is built.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from daemon.datasets.subject_masks import choice_text, latest_choice
from daemon.protect.one_file import dataset_pairs
from daemon.states import dataset_protection, next_step, protection_text

if TYPE_CHECKING:
    from daemon.context import AppContext
    from daemon.paths import AppPaths
    from verifier.html_report import ReportData


def report_path(paths: AppPaths, dataset: str) -> Path:
    """The convention for a dataset's latest report (what `ppd status` links to)."""
    return Path(paths.data_dir) / "reports" / dataset / "latest.html"


def build_dataset_report(ctx: AppContext, dataset: str, history: int = 50) -> ReportData:
    """A daemon dataset: latest verification per profile, its history, models, and a patch preview."""
    from verifier.html_report import ReportError, dataset_history_report, latest_run_group

    if ctx.store.dataset(dataset) is None:
        raise ReportError(f"no dataset {dataset!r} (see `ppd status`)")
    runs = ctx.store.verification_runs(dataset, limit=history)
    latest = latest_run_group(runs)
    current = {r["id"] for r in ctx.store.current_verification_runs(dataset, limit=history)}
    # the headline rests on runs that measured today's pixels (issue 25); older ones are history
    verdicts = {r["profile"]: r for r in latest if r["id"] in current}
    state, under = dataset_protection(ctx.store.counts(dataset), verdicts)
    step = next_step(state, dataset)
    data = dataset_history_report(
        f"ppd report — dataset {dataset}",
        runs,
        protection_text(state, under) + (f": {step}" if step else ""),
        dataset_pairs(ctx, dataset),
        ctx.store.dataset_spec(dataset),
        f"Dataset {dataset!r} has never been verified: run `ppd verify {dataset}`.",
    )
    if latest and not verdicts:  # the banner says today's state ("patched, not verified"), not an old verdict
        data.verdict, data.holding = None, None
        data.notes.insert(0, "The latest verification measured earlier pixels (files were patched or "
                          "restored since): it is history, not today's verdict.")  # fmt: skip
    spec = ctx.store.dataset_spec(dataset)
    if spec is not None and spec.per_photo:
        from daemon.protect.mark_notes import mark_note_lines

        # where marks found no plain place, in the words of ppd poison's summary and ppd status (issue 25)
        for line in reversed(mark_note_lines(ctx.store.patched_place_notes(dataset))):
            data.notes.insert(0, f"Placement: {line}.")
        data.notes.insert(0, "Placement: per photo, where each photo is plainest as shown (off the subject "
                          "masks when given); the preview below says where this file's mark is.")  # fmt: skip
    corner = choice_text(dataset, latest_choice(ctx, dataset))
    if corner is not None:  # where the mark went, and why (daemon.datasets.subject_masks)
        data.notes.insert(0, f"Placement: {corner}.")
    return data


def build_report(source: str, ctx: AppContext | None = None) -> ReportData:
    """source: an experiment folder, a verification folder, or a dataset name (needs ctx)."""
    from verifier.html_report import build_report as build_folder_or_dataset

    lookup = (lambda name: build_dataset_report(ctx, name)) if ctx is not None else None
    return build_folder_or_dataset(source, lookup)
