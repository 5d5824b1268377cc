"""`ppd poison PATHS...`: patch files and folders (a folder is one dataset), in place with each
original in the vault, or as copies with --out; one summary, then what each dataset is now."""

from __future__ import annotations

import contextlib
import os
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from daemon.cli.errors import die, file_reason, open_ctx
from daemon.cli.interrupt import SAME_STOP_S, StopOnSignal
from daemon.cli.options import SpecOptions, spec_options, subject_masks_option, workers_option
from daemon.cli.output import console, err_console, interactive, print_line, verbosity
from daemon.protect.job import shown_name, shown_path
from daemon.states import FileState
from poisoner.errors import ExitStatus

if TYPE_CHECKING:
    from daemon.cli.planning import Job
    from daemon.context import AppContext
    from daemon.datasets.linked_folders import LinkedFolder
    from daemon.protect.one_file import ProtectOutcome
    from poisoner.spec import PatchSpec

# The outcome state of protect_file for a file it wrote its mark into (daemon.protect.job.Outcome).
OUTCOME_PATCHED = frozenset({"patched"})
RESTORED_BY_USER = "restored by the user"


def outcome_word(outcome: ProtectOutcome) -> str:
    """The word for one file's outcome: patched / would patch / unchanged / skipped / failed."""
    if outcome.state in OUTCOME_PATCHED:
        return "would patch" if outcome.dry_run else "patched"
    return outcome.state


def unprotected_media(outcomes: list[ProtectOutcome]) -> list[ProtectOutcome]:
    """The skipped files that are photos or videos in a format ppd does not write (a GIF, a BMP, a
    camera's raw file, by its suffix or its first bytes: poisoner.media.media_class): skipped like a
    sidecar, but publishing them gives a reconstruction away."""
    from daemon.states import UNPROTECTED_PREFIX

    return [o for o in outcomes if o.state == "skipped" and (o.reason or "").startswith(UNPROTECTED_PREFIX)]


def still_open(outcomes: list[ProtectOutcome]) -> list[ProtectOutcome]:
    """The files skipped because another process still writes them (daemon.states.STILL_OPEN_PREFIX)."""
    from daemon.states import STILL_OPEN_PREFIX

    return [o for o in outcomes if o.state == "skipped" and (o.reason or "").startswith(STILL_OPEN_PREFIX)]


def linked_folders(ctx: AppContext, outcomes: list[ProtectOutcome]) -> list[LinkedFolder]:
    """The symlinked sub-folders skipped (never followed), with the photos and videos reached through
    each (daemon.datasets.linked_folders: read, not patched): a folder of them was one 'failed' file,
    its photos neither counted nor named."""
    from daemon.datasets.linked_folders import linked_folders as with_photos
    from daemon.states import LINKED_FOLDER_PREFIX

    said = [o for o in outcomes if o.state == "skipped" and (o.reason or "").startswith(LINKED_FOLDER_PREFIX)]
    return with_photos([o.path for o in said], own=[ctx.paths.outbox])


def _linked_line(linked: list[LinkedFolder]) -> str | None:
    """One line for the symlinked folders that hold photos; None when none does."""
    from daemon.cli.linked_lines import LINKED_ADVICE, linked_phrase

    phrase = linked_phrase(linked)
    return None if phrase is None else f"not protected: {phrase}; {LINKED_ADVICE}"


def _restored_left(outcomes: list[ProtectOutcome]) -> list[ProtectOutcome]:
    return [o for o in outcomes if o.state == "unchanged" and (o.reason or "").startswith(RESTORED_BY_USER)]


def place_lines(outcomes: list[ProtectOutcome]) -> list[str]:
    """The summary's lines for marks that found no free place ("mark on the subject in 2 photos:
    no plain region") or were shrunk to fit one (round 3): never silent (issue 25)."""
    from daemon.protect.mark_notes import mark_note_lines

    return mark_note_lines(o.reason for o in outcomes if o.state in OUTCOME_PATCHED)


# Notes that change a file beyond its mark, which a creator would not assume (the rest, e.g. the JPEG
# splice's own, say how and are for `ppd -v poison` only).
CHANGE_NOTES = (
    ("re-encoded at quality", "re-encoded (lossy: one more generation of its codec's loss)"),
    (" written as ", "written in another pixel layout (e.g. a full palette widened to RGB)"),
    ("location removed", "location (GPS) removed"),
    # a camera's EXIF, Photoshop or XMP thumbnail: an unmarked copy of the original (poisoner.image.previews)
    (
        "replaced by the patched picture's",
        "embedded thumbnail replaced by the patched picture's (it showed the unmarked original)",
    ),
    ("thumbnail removed", "embedded thumbnail removed (it showed the unmarked original)"),
    (
        "Extended XMP holding a picture",
        "embedded copy of the original picture (Extended XMP: Google's GImage:Data) removed",
    ),
    ("FlashPix data", "FlashPix data removed (FPXR APP2: cameras keep a preview of the original there)"),
    (
        "could hold a thumbnail",
        "metadata block dropped (unreadable, it could hold a thumbnail of the original)",
    ),
    # a video's cover picture (MP4 covr, a Matroska image attachment): poisoner.video.cover
    (
        "cover picture marked",
        "video cover picture marked (copied as it was, it showed an unmarked picture beside the marked "
        "frames)",
    ),
    (
        "cover picture removed",
        "video cover picture removed (ppd could not mark it; copied as it was, it showed an unmarked "
        "picture beside the marked frames)",
    ),
)


def change_lines(outcomes: list[ProtectOutcome]) -> list[str]:
    """One summary line per kind of change beyond the mark (CHANGE_NOTES), naming the files: they were
    only in the store's notes (a black-box review). `ppd -v poison` gives each file's notes."""
    patched = [(o, o.report.notes) for o in outcomes if o.state in OUTCOME_PATCHED and o.report is not None]
    lines = []
    for needle, words in CHANGE_NOTES:
        files = [shown_name(o.path) for o, notes in patched if any(needle in n for n in notes)]
        if files:
            shown = ", ".join(files[:3]) + (f" and {len(files) - 3} more" if len(files) > 3 else "")
            lines.append(f"{words}: {len(files)} file(s) ({shown}); `ppd -v poison` says how")
    return lines


def remarked_lines(outcomes: list[ProtectOutcome]) -> list[str]:
    """One line for the files marked again with this dataset's spec that were moved or copied in from
    another dataset, one for its own files that carried an earlier spec of it: said only with -v before
    (a diff review), then every such file was said to come from another dataset, its own too (a
    black-box review, after a store rebuild)."""
    from daemon.states import EARLIER_SPEC_WORDS, REMARKED_PREFIX

    remarked = [o for o in outcomes if (o.reason or "").startswith(REMARKED_PREFIX)]
    own = [shown_name(o.path) for o in remarked if EARLIER_SPEC_WORDS in (o.reason or "")]
    came = [shown_name(o.path) for o in remarked if EARLIER_SPEC_WORDS not in (o.reason or "")]
    lines = []
    for files, what in ((came, "moved or copied in from another dataset"),
                        (own, "of its own that carried an earlier spec of it")):  # fmt: skip
        if files:
            shown = ", ".join(files[:3]) + (f" and {len(files) - 3} more" if len(files) > 3 else "")
            said = f"{len(files)} file(s) {what} ({shown})"
            lines.append(f"{REMARKED_PREFIX}: {said}; `ppd -v poison` says which")
    return lines


def video_size_lines(outcomes: list[ProtectOutcome]) -> list[str]:
    """One line for the videos a run made noticeably larger (poisoner.video.model.NOTICEABLE_GROWTH),
    with the files' sizes: a creator with an upload limit must know (a black-box review: 1.85x, unsaid).
    `ppd -v poison` gives each video's size."""
    from poisoner.video.model import NOTICEABLE_GROWTH, size_text

    grown: list[tuple[float, str, int, int]] = []  # (ratio, name, bytes before, bytes after)
    for o in outcomes:
        before, after = getattr(o.report, "source_bytes", 0), getattr(o.report, "output_bytes", 0)
        if o.state in OUTCOME_PATCHED and before and after >= before * NOTICEABLE_GROWTH:
            grown.append((after / before, o.path.name, before, after))
    if not grown:
        return []
    grown.sort(key=lambda g: (-g[0], g[1]))  # the largest growth first
    span = f"{grown[0][0]:.2f}x" if len(grown) == 1 else f"up to {grown[0][0]:.2f}x"
    each = ", ".join(f"{name} {ratio:.2f}x" for ratio, name, _, _ in grown[:3])
    more = f" and {len(grown) - 3} more" if len(grown) > 3 else ""
    total = f"{size_text(sum(g[2] for g in grown))} -> {size_text(sum(g[3] for g in grown))}"
    return [f"videos grew {span} in size (the mark costs bits): {len(grown)} video(s), {total} "
            f"({each}{more}); `ppd -v poison` gives each file's size"]  # fmt: skip


def verbose_notes(outcome: ProtectOutcome) -> list[str]:
    """-v: a patched file's notes worth a line (the JPEG splice's own note, on every JPEG, is not)."""
    if outcome.state not in OUTCOME_PATCHED or outcome.report is None:
        return []
    return [n for n in outcome.report.notes if not n.startswith("DCT splice: only MCU box")]


def jpeg_lines(outcomes: list[ProtectOutcome]) -> list[str]:
    """The summary's lines for JPEGs written otherwise than a photographer would assume: re-encoded
    whole (every pixel one JPEG generation more; their sampling possibly changed) and data after the
    picture left out. Never silent (they were in the store's notes only)."""

    def names(files: list[ProtectOutcome]) -> str:
        shown = ", ".join(shown_name(o.path) for o in files[:3])
        return shown + (f" and {len(files) - 3} more" if len(files) > 3 else "")

    patched = [(o, o.report) for o in outcomes if o.state in OUTCOME_PATCHED and o.report is not None]
    whole = [o for o, r in patched if getattr(r, "method", "") == "jpeg-reencode-same-tables"]
    resampled = [o for o, r in patched if any("not reproducible by Pillow" in n for n in r.notes)]
    trailer = [o for o, r in patched if getattr(r, "trailer_bytes", 0)]
    lines = []
    if whole:
        s = "" if len(whole) == 1 else "s"
        line = (f"JPEG re-encoded whole in {len(whole)} photo{s} ({names(whole)}): ppd could not copy the "
                "blocks outside the mark (damaged data, padding, or a layout it cannot splice), so every "
                "pixel went through one more JPEG generation")  # fmt: skip
        if resampled:
            line += f"; {len(resampled)} of them now 4:2:0 (their chroma sampling Pillow cannot write)"
        lines.append(line)
    if trailer:
        s = "" if len(trailer) == 1 else "s"
        lines.append(f"data after the picture left out of {len(trailer)} photo{s} ({names(trailer)}): an "
                     "appended image or trailer, never published; `ppd restore` brings the file back "
                     "whole")  # fmt: skip
    return lines


def _print_counts(ctx: AppContext, outcomes: list[ProtectOutcome], dry_run: bool) -> None:
    """exiftool-style counts, the files left restored, each failed file with its reason."""
    counts = Counter(outcome_word(o) for o in outcomes)
    words = ["would patch" if dry_run else "patched", "unchanged", "skipped", "failed"]
    line = ", ".join(f"{w} {counts.get(w, 0)}" for w in words)
    console().print(("dry run, nothing changed: " if dry_run else "") + line)
    lines = place_lines(outcomes) + jpeg_lines(outcomes) + change_lines(outcomes) + video_size_lines(outcomes)
    lines += remarked_lines(outcomes)
    for line in lines:
        console().print(line, markup=False)
    if unread := unprotected_media(outcomes):
        shown = ", ".join(shown_name(o.path) for o in unread[:5]) + (", ..." if len(unread) > 5 else "")
        err_console().print(
            f"not protected: {len(unread)} photo(s) or video(s) ppd cannot read ({shown}); a reconstruction "
            "can still use them: convert them to JPEG, PNG, WebP, HEIC, MP4 or a TIFF named .tif first, "
            "or leave them out",
            markup=False,
        )
    if linked := _linked_line(linked_folders(ctx, outcomes)):
        err_console().print(linked, markup=False)
    if still := still_open(outcomes):  # the daemon patches them once closed; this run does not
        shown = ", ".join(shown_name(o.path) for o in still[:5]) + (", ..." if len(still) > 5 else "")
        err_console().print(f"not patched: {len(still)} file(s) still being written by another program "
                            f"({shown}): run ppd poison again once they are complete",
                            markup=False)  # fmt: skip
    left = _restored_left(outcomes)
    if left:
        console().print(f"left unprotected (restored by you): {len(left)}; use --force to protect them again")
    _print_failed(outcomes)


def _print_failed(outcomes: list[ProtectOutcome]) -> None:
    """`ppd: failed: PATH: REASON` per failed file, in natural order (x2 before x10: a black-box review
    read them sorted as text)."""
    from daemon.store.datasets import natural_key

    for o in sorted((o for o in outcomes if o.state == "failed"), key=lambda o: natural_key(str(o.path))):
        said = f"ppd: failed: {shown_path(o.path)}: {file_reason(o.path, o.reason)}"
        err_console().print(said, markup=False)


def summary(
    ctx: AppContext, jobs: list[Job], outcomes: list[ProtectOutcome], dry_run: bool,
    scene_notes: Callable[[], bool] = lambda: True,
) -> None:  # fmt: skip
    """The counts, then where copies went, what each dataset is now and the command that says
    more (a verification's verdict, or that there is none yet: never "protected" by default).
    scene_notes(): whether to judge the scenes (not once the user pressed Ctrl-C: it takes seconds)."""
    from daemon.cli.planning import output_places
    from daemon.cli.status_queries import protection_line

    _print_counts(ctx, outcomes, dry_run)
    # the scene's hint with the run that patches (or would): a rerun that changes nothing said it
    # again each time (a black-box review), and judging the scene costs a few photos' decode
    if scene_notes() and any(o.state in OUTCOME_PATCHED for o in outcomes):
        _print_scene_notes(ctx, jobs, outcomes)
    if dry_run:
        return
    # where copies are now: not for a file that failed, whose --out copy was never written
    copied = {o.path for o in outcomes if o.output is not None and o.state in ("patched", "unchanged")}
    for place in output_places([job for job in jobs if job.path in copied]):
        console().print(f"written to {place}", markup=False)
    headlined = set()  # the datasets whose line leads with their failures, and `--failed`
    for name in sorted({job.dataset for job in jobs}):
        if ctx.store.dataset(name) is not None:
            console().print(protection_line(ctx, name), markup=False)
            counts = ctx.store.counts(name)
            headlined |= {name} if counts.get("failed") or counts.get("quarantined") else set()
    from daemon.protect.job import storable  # a name that is not UTF-8 has no row: only its line says why

    failed = {o.dataset for o in outcomes if o.state == "failed" and o.dataset and storable(o.path)}
    names = sorted(failed - headlined)
    if names:
        console().print(f"failed files and reasons: ppd status {names[0]} --failed", markup=False)


def interrupted_line(outcomes: list[ProtectOutcome], total: int, dry_run: bool, command: str) -> str:
    """The one line a stopped run ends with: what it did, what is left, the command that finishes."""
    counts = Counter(outcome_word(o) for o in outcomes)
    words = ["would patch" if dry_run else "patched", "unchanged", "skipped", "failed"]
    done = ", ".join(f"{w} {counts.get(w, 0)}" for w in words)
    left = total - len(outcomes)
    return f"interrupted: {done}; {left} of {total} not patched yet: run `{command}` to finish"


def interrupted_summary(outcomes: list[ProtectOutcome], total: int, dry_run: bool) -> None:
    """Ctrl-C or SIGTERM stopped the run between files: the one line, then each failed file."""
    import shlex
    import sys

    command = shlex.join(["ppd", *sys.argv[1:]])  # as typed: same folders, same --out and --dataset
    out = console()  # word-wrapped on a terminal (never mid-word), one line into a pipe
    line = interrupted_line(outcomes, total, dry_run, command)
    print_line(out, line)
    _print_failed(outcomes)


def _print_scene_notes(ctx: AppContext, jobs: list[Job], outcomes: list[ProtectOutcome]) -> None:
    """One line per dataset saying what kind of scene it looks like (poisoner.scene): what ppd can
    and cannot protect, up front; it never claims protection. It reads each file's original where
    the vault holds it (the file itself carries ppd's mark by now), else the file."""
    from daemon.cli.scene_note import print_scene_notes  # numpy/PIL only when it runs

    by_dataset: dict[str, list[Path]] = {}
    for job in jobs:
        by_dataset.setdefault(job.dataset, []).append(job.path)
    kept = {o.path: o.original_sha256 for o in outcomes if o.original_sha256 and not o.dry_run}

    def original(path: Path) -> Path:
        sha = kept.get(path)
        if sha is None:  # patched by an earlier run (a rerun, a dry run): its row names the original
            row = ctx.store.file(path)
            sha = row["original_sha256"] if row and row["state"] == FileState.PATCHED else None
        return ctx.vault.path_for(sha) if sha and ctx.vault.has(sha) else path

    print_scene_notes(console(), by_dataset, original)


def _say_outcome(progress_console: Any, outcome: ProtectOutcome) -> None:
    """-v: one line per file with its outcome (above the progress bar)."""
    where = f" -> {outcome.output}" if outcome.output and outcome.output != outcome.path else ""
    said = outcome.reason if outcome.reason != outcome_word(outcome) else None  # "would patch (would patch)"
    why = f" ({said})" if said and outcome.state != "failed" else ""
    if still_open([outcome]):  # what the summary says: nothing patches it after this run
        why = f" ({said}; not patched: run ppd poison again once it is complete)"
    place = getattr(outcome.report, "place", None)
    if place is not None and outcome.state in OUTCOME_PATCHED:  # a per-photo mark: where it shows
        why = f" (mark at the {place.words}{'; ' + outcome.reason if outcome.reason else ''})"
    progress_console.print(f"{outcome_word(outcome)} {shown_path(outcome.path)}{where}{why}", markup=False)
    for note in verbose_notes(outcome):
        progress_console.print(f"  note: {note}", markup=False)


def run_jobs(
    ctx: AppContext,
    jobs: list[Job],
    wanted: dict[str, PatchSpec],
    *,
    dry_run: bool,
    force: bool,
    workers: int | None = None,
    subject_masks: Path | None = None,
    stop: StopOnSignal | None = None,
) -> list[ProtectOutcome]:
    """Every job through protect_many on `workers` processes (default: the config's). A progress
    bar only on a terminal (nothing per file unless -v, which names each file with its outcome);
    the outcomes sorted by path for the summary. stop: once it is true (Ctrl-C), no file starts
    any more and those in progress finish: fewer outcomes than jobs."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from daemon.protect.pool import protect_many

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    said_before = stop._on_stop if stop is not None else None  # said again once the bar is gone
    with Progress(*columns, console=err_console(), transient=True, disable=not interactive()) as progress:
        task = progress.add_task("patching", total=len(jobs))
        if stop is not None and interactive():  # the bar says why it waits: the files in progress finish

            def on_stop(name: str) -> None:
                progress.update(task, description=f"stopping ({stop_key(name)} again: now)")

            stop._on_stop = on_stop

        def finished(outcome: ProtectOutcome) -> None:
            if verbosity() > 0:
                _say_outcome(progress.console, outcome)
            progress.advance(task)

        outcomes = protect_many(
            ctx, [(job.path, job.dataset, job.root, job.out_path) for job in jobs], workers=workers,
            force=force, dry_run=dry_run, spec=wanted, on_outcome=finished, subject_masks=subject_masks,
            stop=stop,
        )  # fmt: skip
    if stop is not None:
        stop._on_stop = said_before
    return sorted(outcomes, key=lambda o: str(o.path))


POISON_HELP = """Patch photos and videos so 3D reconstruction from them fails.

A folder is one dataset. In place by default (each original is kept in the vault,
`ppd restore` puts it back); with --out the inputs stay as they are. Re-running is a
no-op. Whether the patch protects is a verification's answer: `ppd verify DATASET`.

\b
Examples:
  ppd poison ~/shoots/castle              patch in place
  ppd poison ~/shoots/castle --out ~/pub  patched copies in ~/pub/castle/
  ppd poison castle --design paper --dry-run
  ppd poison dtu/image --design watermark --subject-masks dtu/mask
"""


@spec_options()
def poison(
    paths: list[Path] = typer.Argument(..., help="Files or folders; a folder is one dataset."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Say what would be patched; change nothing."),
    out: Path | None = typer.Option(
        None, "--out", metavar="DIR", help="Write patched copies to DIR/DATASET/; leave the inputs."
    ),
    dataset: str | None = typer.Option(None, "--dataset", help="Dataset name (default: the folder's)."),
    force: bool = typer.Option(False, "--force", help="Patch again files you restored."),
    workers: int | None = workers_option(),
    subject_masks: Path | None = subject_masks_option(),
    spec_options: SpecOptions = SpecOptions(),
) -> None:
    one_blas_thread()
    # From here Ctrl-C / SIGTERM stop between files: the one in progress finishes, one line says
    # what is left and how to finish (a second signal stops at once).
    with StopOnSignal(say_stopping) as stop:
        ctx = open_ctx(needs_key=True)
        try:
            _poison(ctx, paths, dataset, out, subject_masks, spec_options, dry_run, force, workers, stop)
        finally:
            ctx.close()


def stop_key(signal_name: str) -> str:
    return "Ctrl-C" if signal_name == "SIGINT" else signal_name


def say_stopping(signal_name: str) -> None:
    """At the first Ctrl-C (SIGINT) or SIGTERM, at once: a long video's file could run on for minutes
    with nothing said (a black-box review). Written straight to stderr: this runs in the handler.
    Not while all the run has in progress, here or in its workers, is waits for files other ppd
    processes work on: no file of its own is in progress, each wait ends now and says so
    (daemon.protect.one_file)."""
    locks = sys.modules.get("daemon.locks")  # loaded by then; nothing is imported in a handler
    if locks is not None and locks.waiting_to_leave():
        return
    key = stop_key(signal_name)
    with contextlib.suppress(OSError):
        later = f"{key} again (after {SAME_STOP_S:g} s) stops now"
        os.write(2, f"\nppd: {key}: stopping after the file in progress; {later}\n".encode())


def one_blas_thread() -> None:
    """numpy's OpenBLAS on one thread in this process and its patch workers (a user's own setting
    stands): the patch pass makes no BLAS call worth a thread, and OpenBLAS's idle threads spin at
    numpy's import and after each call: 0.11 s of CPU a 24-photo run (bench/results/batch.md round
    18). Set before numpy is imported, or it has no effect; `ppd poison` runs no COLMAP, whose
    bundled OpenBLAS keeps its threads in the commands that do."""
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _poison(
    ctx: AppContext, paths: list[Path], dataset: str | None, out: Path | None, subject_masks: Path | None,
    spec_options: SpecOptions, dry_run: bool, force: bool, workers: int | None, stop: StopOnSignal,
) -> None:  # fmt: skip
    from daemon.cli import planning

    jobs = planning.plan_jobs(ctx, paths, dataset, out, dry_run)
    if not jobs:
        raise die("no files to patch in " + ", ".join(str(p) for p in paths))
    planning.check_dataset_roots(ctx, jobs)
    if dataset is not None:  # a folder's files are one dataset's (the rule attribute keeps without it)
        planning.refuse_held_elsewhere(ctx, jobs)
    made = planning.check_writable(jobs, dry_run)
    try:
        _run_planned(ctx, jobs, spec_options, dry_run, force, workers, subject_masks, stop, paths)
    finally:
        planning.remove_if_empty(made)


def _run_planned(
    ctx: AppContext, jobs: list[Job], spec_options: SpecOptions, dry_run: bool, force: bool,
    workers: int | None, subject_masks: Path | None, stop: StopOnSignal, paths: list[Path],
) -> None:  # fmt: skip
    from daemon.cli import planning

    masks = planning.dataset_masks(ctx, jobs, subject_masks)
    jobs, notes = planning.without_masks(jobs, masks)
    jobs, nested = planning.without_nested(ctx, jobs)
    jobs, published = planning.without_published(ctx, jobs)
    notes += nested + published
    if not jobs and published:  # all published copies: nothing left to patch, which is no error
        for line in notes:
            console().print(line, markup=False)
        return
    if not jobs:
        raise die("no files to patch besides the subject masks in " + ", ".join(str(p) for p in paths))
    wanted, placement_lines = planning.apply_spec(ctx, jobs, spec_options, dry_run, masks)
    for line in notes:
        console().print(line, markup=False)
    outcomes = run_jobs(
        ctx, jobs, wanted, dry_run=dry_run, force=force, workers=workers, subject_masks=subject_masks,
        stop=stop,
    )  # fmt: skip
    # where the marks went, for datasets that got one (it was said of a set whose every file failed)
    marked = {o.dataset for o in outcomes if o.state in OUTCOME_PATCHED}
    for dataset, line in placement_lines:
        if dataset in marked:
            console().print(line, markup=False)
    if stop() and len(outcomes) < len(jobs):
        interrupted_summary(outcomes, len(jobs), dry_run)
        raise typer.Exit(ExitStatus.INTERRUPTED)
    summary(ctx, jobs, outcomes, dry_run, scene_notes=lambda: not stop())  # a Ctrl-C there skips the notes
    done = {o.path for o in outcomes if o.state in OUTCOME_PATCHED}
    capped = planning.capped_lines(outcomes, wanted, spec_options, ctx.store.dataset_spec)
    turned = planning.turned_mask_lines(outcomes, masks) + planning.small_mark_lines(outcomes)
    for line in planning.missing_mask_lines(jobs, done, masks) + turned + capped:
        console().print(line, markup=False)
    # a photo ppd cannot write (BMP, GIF, raw) left beside the patched ones: not protected, as a failure
    # (with --out it is not copied where the patched ones go: nothing unprotected is published there)
    in_place = {j.path for j in jobs if j.out_path is None}
    left = [o.path for o in unprotected_media(outcomes) if o.path in in_place]
    left += [link.path for link in linked_folders(ctx, outcomes) if link.photos and link.path in in_place]
    misnamed = unpatched_in_place(ctx, jobs, outcomes, paths, masks)
    failed = [o for o in outcomes if o.state == "failed"]
    if failed and disk_full(failed):  # `--help`: 3 = cannot work here, disk full (a black-box review: 1)
        full = "ppd: a disk is full (or over its quota): free space, then run the same command again"
        err_console().print(f"{full}; what was patched stays patched", markup=False, highlight=False)
        raise typer.Exit(ExitStatus.ENVIRONMENT)
    if failed or left or misnamed or still_open(outcomes):
        raise typer.Exit(ExitStatus.FAILED)


def unpatched_in_place(
    ctx: AppContext, jobs: list[Job], outcomes: list[ProtectOutcome], paths: list[Path],
    masks: dict[str, Path | None],
) -> list[Path]:  # fmt: skip
    """The photos under names ppd does not patch (hidden, backups, partial downloads) in the folders
    patched in place, and such files named on the command line: said in one line (a black-box review:
    poison called three of them "not a supported image or video" and left out the hidden one)."""
    from daemon.cli.targets import user_path
    from daemon.datasets.unpatched_names import (
        NAME_PREFIX,
        unpatched_line,
        unpatched_media,
        unpatched_name_reason,
    )
    from poisoner.media import read_head

    if any(j.out_path is not None for j in jobs):  # --out: such a file is not copied where it publishes
        return []
    skip = [m for m in masks.values() if m is not None]
    named = {o.path for o in outcomes if o.state == "skipped" and (o.reason or "").startswith(NAME_PREFIX)}
    for given in (user_path(p) for p in paths):
        if given.is_symlink():
            continue
        if given.is_dir():
            named |= set(unpatched_media(given, skip))
        elif given.is_file() and unpatched_name_reason(given.name, False, read_head(given)):
            named.add(given.absolute())  # `ppd poison .IMG_1.jpg`: skipped in silence, exit 0 (a diff review)
    found = sorted(named)
    if found:
        where = "the outbox" if all(p.is_relative_to(ctx.paths.outbox) for p in found) else "the folder"
        err_console().print(unpatched_line(found, where), markup=False, highlight=False)
    return found


def disk_full(failed: list[ProtectOutcome]) -> bool:
    """Whether a failure was for lack of space: the run cannot work here, not a file's fault."""
    from daemon.watch.outcomes import is_no_space

    return any(is_no_space(o.reason) for o in failed)


def register(app: typer.Typer) -> None:
    app.command("poison", help=POISON_HELP)(poison)
