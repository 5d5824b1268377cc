"""Reports on the daemon's datasets: what `ppd report DATASET` and `ppd status` show.

The page itself is the verifier's (verifier.html_report); this module gathers a dataset's Store rows,
its protection state and an (original, patched) pair for the patch preview, and owns where a
dataset's latest report lives: `<data_dir>/reports/<dataset>/latest.html`.

`ppd status` imports this module for `report_path`: the verifier's report (numpy, PIL) loads only
when a report is built.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.datasets.subject_masks import choice_text, latest_choice
from daemon.protect.one_file import dataset_pairs
from daemon.states import (
    Protection,
    dataset_protection,
    newest_per_profile,
    next_step,
    patched_count,
    protection_text,
    published_protection,
    unmarked_decide,
    unmarked_text,
)
from verifier.verdict import Verdict

if TYPE_CHECKING:
    from daemon.context import AppContext
    from daemon.paths import AppPaths
    from verifier.html_report import ReportData


def report_path(paths: AppPaths, dataset: str) -> Path:
    """The convention for a dataset's latest report (what `ppd status` links to)."""
    return Path(paths.data_dir) / "reports" / dataset / "latest.html"


def build_dataset_report(ctx: AppContext, dataset: str, history: int = 50) -> ReportData:
    """A daemon dataset: latest verification per profile, its history, models, and a patch preview."""
    from daemon.datasets.folder_count import (
        current_counts,
        dataset_folder,
        restored_in_place,
        unmarked_names,
        unmarked_why,
        unprotected_phrases,
    )
    from verifier.html_report import ReportError, dataset_history_report, has_patch_preview, latest_run_group

    row = ctx.store.dataset(dataset)
    if row is None:
        raise ReportError(f"no dataset {dataset!r} (see `ppd status`)")
    runs = ctx.store.verification_runs(dataset, limit=history)
    latest = latest_run_group(runs)
    # The headline rests on the newest run of each profile that measured today's pixels (issue 25),
    # as `ppd status` judges it: the newest run alone let a default pass hide a masked failure
    # measured minutes before on the same pixels (a black-box review: "Verdict: PROTECTED" where
    # status said NOT protected). Older runs are history.
    verdicts = newest_per_profile(ctx.store.current_verification_runs(dataset, limit=history))
    # and on the folder as it is now: files changed since patched, new, or being written were not
    # measured (daemon.states.dataset_protection)
    counts = current_counts(ctx, dataset, dataset_folder(ctx, dataset, row["root"]))
    state, under = dataset_protection(counts, verdicts)
    step = next_step(state, dataset)
    # the files left unprotected, in `ppd status --check`'s words: the page headlined "patched, not
    # verified" with restored and new files in the folder, and said nothing of them (a black-box review)
    restored = restored_in_place(ctx, dataset, row["root"]) if counts.get("restored") else 0
    left = unprotected_phrases(counts, restored)
    # and its verdict, the patched files', is not the dataset's while one of its files is left unmarked:
    # the banner said PROTECTED with a failed photo in the published folder (a black-box review)
    text = published_protection(state, under, left, patched_count(counts))[2]
    data = dataset_history_report(
        f"ppd report — dataset {dataset}",
        runs,
        text + (f": {step}" if step else ""),
        dataset_pairs(ctx, dataset),
        ctx.store.dataset_spec(dataset),
        f"Dataset {dataset!r} has never been verified: run `ppd verify {dataset}`.",
        current=list(verdicts.values()),
        mark_of=_recorded_mark(ctx, dataset),
    )
    if verdicts and state is Protection.PATCHED_NOT_VERIFIED:  # verified, then files changed or came
        data.verdict, data.holding = None, None
        data.notes.insert(0, "Files changed, were added or are being written since the last verification: "
                          "its verdict is history, not today's.")  # fmt: skip
    if latest and not verdicts:  # the banner says today's state ("patched, not verified"), not an old verdict
        data.verdict, data.holding = None, None
        data.notes.insert(0, "The latest verification measured earlier pixels (files were patched or "
                          "restored since): it is history, not today's verdict.")  # fmt: skip
    if unmarked_decide(state, left):  # the banner says why, and what the patched files' verdict is
        why = unmarked_why(left, unmarked_names(ctx, dataset, row["root"]))
        banner = unmarked_text(why, f"the {patched_count(counts)} patched", protection_text(state, under))
        data.verdict, data.unmarked = Verdict.NOT_PROTECTED, banner
    if left:
        data.notes.insert(0, f"NOT protected: {', '.join(left)} (`ppd status {dataset}` lists them).")
    spec = ctx.store.dataset_spec(dataset)
    if spec is not None and spec.per_photo:
        from daemon.protect.mark_notes import mark_note_lines

        # where marks found no plain place, in the words of ppd poison's summary and ppd status (issue 25)
        for line in reversed(mark_note_lines(ctx.store.patched_place_notes(dataset))):
            data.notes.insert(0, f"Placement: {line}.")
        # the preview is said only where the page has one (it pointed at none for a HEIC set: a review)
        shown = "; the preview below says where its file's mark is" if has_patch_preview(data) else ""
        data.notes.insert(0, "Placement: per photo, where each photo is plainest as shown (off the subject "
                          f"masks when given){shown}.")  # fmt: skip
    corner = choice_text(dataset, latest_choice(ctx, dataset))
    if corner is not None:  # where the mark went, and why (daemon.datasets.subject_masks)
        data.notes.insert(0, f"Placement: {corner}.")
    return data


def _recorded_mark(ctx: AppContext, dataset: str) -> Callable[[Path], dict[str, Any]]:
    """What ppd recorded of the mark of a patched file of the dataset, named as dataset_pairs names it
    (its publish-folder copy, or itself): where the report's preview zooms (a whole-file re-encode,
    HEIC, changes every pixel, so the pixels that differ do not say where the mark is)."""
    from daemon.states import FileState

    def mark_of(patched: Path) -> dict[str, Any]:
        for row in ctx.store.files(dataset, state=FileState.PATCHED):
            if Path(row["published_path"] or row["path"]) == patched:
                return ctx.store.mark_detail(row["path"])
        return {}

    return mark_of


def build_report(source: str, ctx: AppContext | None = None) -> ReportData:
    """source: an experiment folder, a verification folder, or a dataset name (needs ctx)."""
    from verifier.html_report import build_report as build_folder_or_dataset

    lookup = (lambda name: build_dataset_report(ctx, name)) if ctx is not None else None
    return build_folder_or_dataset(source, lookup)
