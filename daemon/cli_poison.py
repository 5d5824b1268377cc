"""`ppd poison`, `ppd restore`, `ppd preview`, `ppd status`, `ppd dataset`, `ppd config`.

Light imports only: no pycolmap, no torch (the poisoners load lazily inside protect_file).
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from daemon.cli_common import (
    EXIT_ENVIRONMENT,
    EXIT_FAILED,
    EXIT_USAGE,
    console,
    die,
    err_console,
    os_error_text,
    reason_text,
    verbosity,
    warning,
)
from daemon.cli_spec import SpecOptions, spec_options
from daemon.config import ConfigError
from daemon.dataset import dataset_of, dataset_root
from daemon.protect import (
    AppContext,
    ProtectOutcome,
    is_ignored_name,
    protect_file,
    reprotect_dataset,
    restore_file,
)
from daemon.states import (
    PATCHED_VALUES,
    FileState,
    Protection,
    dataset_protection,
    next_step,
    patched_count,
    protection_text,
    state_word,
    verdict_words,
)
from daemon.store import DatasetSpecLocked, StoreError
from daemon.syncdirs import find_sync_folder
from poisoner.spec import PatchSpec, SpecError

# verifier.verdict's names (kept as strings so status does not import the verifier).
VERDICT_PROTECTED = "protected"
VERDICT_NOT_PROTECTED = "not_protected"

# The outcome state of protect_file for a file it wrote its mark into (daemon.pipeline.Outcome).
OUTCOME_PATCHED = frozenset({"patched"})
RESTORED_BY_USER = "restored by the user"


def _die(message: str, code: int = EXIT_USAGE) -> typer.Exit:
    return die(message, code)


def _open_ctx() -> AppContext:
    try:
        return AppContext.open()
    except (ConfigError, StoreError) as exc:
        raise _die(str(exc).splitlines()[0]) from None
    except OSError as exc:
        raise _die(
            f"cannot set up ppd's folders: {os_error_text(exc, hint_out=False)}", EXIT_ENVIRONMENT
        ) from None


def spec_summary(spec: PatchSpec) -> str:
    def length(v: int | float) -> str:
        return f"{v * 100:g}%" if isinstance(v, float) and v < 1 else f"{v:g}px"

    text = f"{spec.pattern} {length(spec.patch_size)} block {length(spec.block_size)} α{spec.alpha:g}"
    text += f" Δc{spec.contrast} {spec.position}"
    if any(spec.offset):
        text += f" +({length(spec.offset[0])}, {length(spec.offset[1])})"
    if spec.moves:
        text += f" {spec.motion} {length(spec.motion_step)}/image"
    if spec.ratio < 1:
        text += f" ratio {spec.ratio:g}"
    return text


def _age(ts: float) -> str:
    seconds = max(0.0, time.time() - ts)
    for unit, size in (("d", 86400), ("h", 3600), ("m", 60)):
        if seconds >= size:
            return f"{seconds / size:.0f}{unit} ago"
    return f"{seconds:.0f}s ago"


# ---- ppd poison ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Job:
    path: Path
    dataset: str
    root: Path
    out_path: Path | None


def _media_files(folder: Path) -> list[Path]:
    """Regular, non-hidden files under folder (hidden folders skipped too), sorted."""
    files = []
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder)
        if any(part.startswith(".") for part in rel.parts) or is_ignored_name(p):
            continue
        if p.is_symlink() or p.is_file():  # symlinks are listed so protect_file refuses them loudly
            files.append(p)
    return files


def plan_jobs(ctx: AppContext, targets: list[Path], dataset: str | None, out: Path | None) -> list[Job]:
    """One job per file. A folder is one dataset (named after it, or its outbox dataset); a
    file belongs to its outbox dataset, else to a dataset named after its parent folder."""
    outbox = ctx.paths.outbox.absolute()
    jobs: list[Job] = []
    for target in targets:
        target = target.absolute()
        if not target.exists() and not target.is_symlink():
            raise _die(f"{target} does not exist")
        in_outbox = target.is_relative_to(outbox) and target != outbox
        if target.is_dir():
            if dataset:
                name, root = dataset, target
            elif in_outbox:
                name = dataset_of(outbox, target / "x")
                root = dataset_root(outbox, name)
            else:
                name, root = (target.name or "default"), target
            files = _media_files(target)
        else:
            if dataset:
                name, root = dataset, target.parent
            elif in_outbox:
                name = dataset_of(outbox, target)
                root = dataset_root(outbox, name)
            else:
                name, root = target.parent.name or "default", target.parent
            files = [target]
        for f in files:
            out_path = None
            if out is not None:
                rel = f.relative_to(target) if target.is_dir() else Path(f.name)
                out_path = (out.absolute() / name / rel) if target.is_dir() else out.absolute() / rel
            jobs.append(Job(f, name, root, out_path))
    return jobs


def _check_dataset_roots(ctx: AppContext, jobs: list[Job]) -> None:
    seen: dict[str, Path] = {}
    for job in jobs:
        root = seen.setdefault(job.dataset, job.root)
        if root.absolute() != job.root.absolute():
            raise _die(f"dataset {job.dataset!r} would cover both {root} and {job.root}; use --dataset")
        row = ctx.store.dataset(job.dataset)
        if row is not None and Path(row["root"]).absolute() != job.root.absolute():
            raise _die(
                f"dataset {job.dataset!r} already belongs to {row['root']}; name this one with --dataset NAME"
            )


def _apply_spec(
    ctx: AppContext, jobs: list[Job], options: SpecOptions, dry_run: bool
) -> dict[str, PatchSpec]:
    """The spec each dataset will use when flags were given (set on new datasets now)."""
    wanted: dict[str, PatchSpec] = {}
    if not options.given():
        return wanted
    for job in jobs:
        if job.dataset in wanted:
            continue
        base = ctx.store.dataset_spec(job.dataset) or ctx.config.spec_for(job.dataset)
        try:
            spec = options.build(base)
        except (SpecError, OSError, ValueError) as exc:
            raise _die(str(exc).splitlines()[0]) from None
        wanted[job.dataset] = spec
        if not dry_run:
            try:
                ctx.store.set_dataset_spec(job.dataset, spec, root=job.root)
            except DatasetSpecLocked as exc:
                raise _die(str(exc)) from None
    return wanted


def _check_writable(jobs: list[Job], dry_run: bool) -> None:
    """Refuse before touching anything when a folder ppd must write into is not writable
    (instead of one `[Errno 13] ... .ppd-tmp-x.jpg` per file)."""
    if dry_run:
        return
    folders = {job.path.parent for job in jobs if job.out_path is None}
    for folder in sorted(folders):
        if not os.access(folder, os.W_OK | os.X_OK):
            raise _die(f"folder not writable: {folder}; use --out DIR", EXIT_ENVIRONMENT)
    for out_folder in sorted({job.out_path.parent for job in jobs if job.out_path is not None}):
        try:
            out_folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise _die(os_error_text(exc, hint_out=False), EXIT_ENVIRONMENT) from None
        if not os.access(out_folder, os.W_OK | os.X_OK):
            raise _die(f"folder not writable: {out_folder}", EXIT_ENVIRONMENT)


def file_reason(path: Path | str, reason: str | None) -> str:
    """reason_text without the file name the core's reasons often start with (the line has it)."""
    text = reason_text(reason)
    name = Path(path).name
    return text[len(name) + 2 :] if text.startswith(f"{name}: ") else text


def outcome_word(outcome: ProtectOutcome) -> str:
    """The word for one file's outcome: patched / would patch / unchanged / skipped / failed."""
    if outcome.state in OUTCOME_PATCHED:
        return "would patch" if outcome.dry_run else "patched"
    return outcome.state


def _restored_left(outcomes: list[ProtectOutcome]) -> list[ProtectOutcome]:
    return [o for o in outcomes if o.state == "unchanged" and (o.reason or "").startswith(RESTORED_BY_USER)]


def _output_places(jobs: list[Job]) -> list[str]:
    """Where --out put the copies: one folder per dataset (a single file: its own path)."""
    by_dataset: dict[str, list[Path]] = {}
    for job in jobs:
        if job.out_path is not None:
            by_dataset.setdefault(job.dataset, []).append(job.out_path)
    places = []
    for paths in by_dataset.values():
        places.append(str(paths[0]) if len(paths) == 1 else str(Path(os.path.commonpath(paths))) + os.sep)
    return places


def _summary(ctx: AppContext, jobs: list[Job], outcomes: list[ProtectOutcome], dry_run: bool) -> None:
    """exiftool-style counts, then what each dataset is now and the command that says more."""
    counts = Counter(outcome_word(o) for o in outcomes)
    first = "would patch" if dry_run else "patched"
    words = [first, "unchanged", "skipped", "failed"]
    line = ", ".join(f"{w} {counts.get(w, 0)}" for w in words)
    console.print(("dry run, nothing changed: " if dry_run else "") + line)
    left = _restored_left(outcomes)
    if left:
        console.print(f"left unprotected (restored by you): {len(left)}; use --force to protect them again")
    failed = [o for o in outcomes if o.state == "failed"]
    for o in failed:
        err_console.print(f"ppd: failed: {o.path}: {file_reason(o.path, o.reason)}", markup=False)
    if dry_run:
        return
    for place in _output_places(jobs):
        console.print(f"written to {place}", markup=False)
    for name in sorted({job.dataset for job in jobs}):
        if ctx.store.dataset(name) is None:
            continue
        protection, profiles = dataset_protection(
            ctx.store.counts(name), latest_by_profile(ctx.store.verification_runs(name, limit=50))
        )
        step = next_step(protection, name)
        text = protection_text(protection, profiles)
        console.print(f"{name}: {text}" + (f": {step}" if step else ""), markup=False)
    if failed:
        names = sorted({o.dataset for o in failed if o.dataset})
        if names:
            console.print(f"failed files and reasons: ppd status {names[0]} --failed", markup=False)


POISON_HELP = """Patch photos and videos so 3D reconstruction from them fails.

A folder is one dataset. In place by default (each original is kept in the vault,
`ppd restore` puts it back); with --out the inputs stay as they are. Re-running is a
no-op. Whether the patch protects is a verification's answer: `ppd verify DATASET`.

\b
Examples:
  ppd poison ~/shoots/castle              patch in place
  ppd poison ~/shoots/castle --out ~/pub  patched copies in ~/pub/castle/
  ppd poison castle --design paper --dry-run
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
    spec_options: SpecOptions = SpecOptions(),
) -> None:
    ctx = _open_ctx()
    verbose = verbosity() > 0
    try:
        jobs = plan_jobs(ctx, paths, dataset, out)
        if not jobs:
            raise _die("no files to patch in " + ", ".join(str(p) for p in paths))
        _check_dataset_roots(ctx, jobs)
        _check_writable(jobs, dry_run)
        wanted = _apply_spec(ctx, jobs, spec_options, dry_run)
        outcomes = _run_jobs(ctx, jobs, wanted, dry_run, force, verbose)
        _summary(ctx, jobs, outcomes, dry_run)
        if any(o.state == "failed" for o in outcomes):
            raise typer.Exit(EXIT_FAILED)
    finally:
        ctx.close()


def _run_jobs(
    ctx: AppContext,
    jobs: list[Job],
    wanted: dict[str, PatchSpec],
    dry_run: bool,
    force: bool,
    verbose: bool = False,
) -> list[ProtectOutcome]:
    """Every job through protect_file on the config's workers. A progress bar only on a terminal
    (nothing per file unless -v, which names each file with its outcome)."""
    outcomes: list[ProtectOutcome] = []
    lock = threading.Lock()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    show_bar = err_console.is_terminal and not err_console.is_dumb_terminal
    with Progress(*columns, console=err_console, transient=True, disable=not show_bar) as progress:
        task = progress.add_task("patching", total=len(jobs))

        def run(job: Job) -> None:
            outcome = protect_file(
                job.path, ctx, job.dataset, root=job.root, out_path=job.out_path,
                dry_run=dry_run, force=force, spec=wanted.get(job.dataset),
            )  # fmt: skip
            with lock:
                outcomes.append(outcome)
                if verbose:
                    where = f" -> {outcome.output}" if outcome.output and outcome.output != job.path else ""
                    why = f" ({outcome.reason})" if outcome.reason and outcome.state != "failed" else ""
                    progress.console.print(f"{outcome_word(outcome)} {job.path}{where}{why}", markup=False)
            progress.advance(task)

        workers = max(1, min(ctx.config.workers, len(jobs)))
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="ppd-poison") as pool:
            list(pool.map(run, jobs))
    return sorted(outcomes, key=lambda o: str(o.path))


# ---- ppd restore ---------------------------------------------------------------------------
def restore(
    target: str = typer.Argument(..., help="A dataset name or a patched file."),
    force: bool = typer.Option(False, "--force", help="Overwrite even if the file changed since."),
) -> None:
    """Put originals back from the vault (atomic). Files in an --out or publish folder are
    removed there, never replaced by originals. The daemon does not patch restored files again.

    \b
    Examples:
      ppd restore castle                 every patched file of the dataset
      ppd restore ~/shoots/castle/a.jpg  one file
    """
    ctx = _open_ctx()
    try:
        as_path = Path(target).absolute()
        if ctx.store.file(as_path) is not None:
            paths = [as_path]
        elif ctx.store.dataset(target) is not None:
            paths = [Path(r["path"]) for r in ctx.store.files(target, state=FileState.PATCHED)]
        else:
            raise _die(f"{target!r} is neither a dataset nor a file in the store")
        outcomes = [restore_file(ctx, p, force=force) for p in sorted(set(paths))]
        counts = Counter(o.state for o in outcomes)
        console.print(
            ", ".join(f"{k} {counts.get(k, 0)}" for k in ("restored", "removed", "unchanged", "failed"))
        )
        for o in outcomes:
            if o.state == "failed":
                err_console.print(f"ppd: not restored: {o.path}: {reason_text(o.reason)}", markup=False)
            elif o.state not in ("restored", "unchanged") and o.reason:
                console.print(f"{o.state} {o.path}: {o.reason}", markup=False)
        if counts.get("failed"):
            raise typer.Exit(EXIT_FAILED)
    finally:
        ctx.close()


# ---- ppd preview ---------------------------------------------------------------------------
@spec_options(with_ratio=False)
def preview(
    file: Path = typer.Argument(..., help="A photo or a video (original or patched)."),
    out: Path | None = typer.Option(
        None, "--out", metavar="PNG", help="PNG to write (default: ./NAME.ppd-preview.png)."
    ),
    spec_options: SpecOptions = SpecOptions(),
    display_width: int = typer.Option(
        1920, "--display-width", metavar="PX", help="Screen width the visibility is judged at."
    ),
    visibility: bool = typer.Option(
        True, "--visibility/--no-visibility", help="Measure how visible the mark is (FLIP; a few seconds)."
    ),
) -> None:
    """Original and patched side by side, with a zoom on the patch, and how visible the mark is
    at display size (FLIP, next to a JPEG q85 re-encode of the same picture). A patched file is
    shown against its vault original; any other photo with its dataset's spec (or the flags').

    \b
    Examples:
      ppd preview IMG_0042.jpg                   the spec this file would get
      ppd preview IMG_0042.jpg --design paper    the paper's static patch
      ppd preview clip.mp4 --out clip.png        a frame of a video
    """
    from PIL import Image

    from poisoner.preview import orient, oriented_placement, render_preview

    if not file.exists():
        raise _die(f"{file} does not exist")
    if file.is_dir():
        raise _die(f"{file} is a folder; give one photo or video")
    ctx = _open_ctx()
    try:
        file = file.absolute()
        row = ctx.store.file(file)

        def load(path: Path):  # -> np.ndarray
            try:
                return load_picture(path)
            except (OSError, ValueError) as exc:
                raise _die(f"cannot read {path.name}: {str(exc).splitlines()[0]}") from None

        try:
            if row is not None and row["state"] in PATCHED_VALUES and not spec_options.given():
                spec = ctx.store.get_spec(row["spec_id"])
                original, _ = load(ctx.vault.path_for(row["original_sha256"]))
                poisoned, orientation = load(file)
                placement = _placement(spec, original, file)
                labels = ("original (vault)", f"patched ({file.name})")
            else:
                from poisoner.blend import apply_patch, poison_array

                base = ctx.config.spec
                if file.is_relative_to(ctx.paths.outbox.absolute()):
                    name = dataset_of(ctx.paths.outbox, file)
                    base = ctx.store.dataset_spec(name) or ctx.config.spec_for(name)
                spec = spec_options.build(base)
                original, orientation = load(file)
                if _is_video(file):  # the first frame, as poison_video patches it
                    placement = _placement(spec, original, file)
                    poisoned = apply_patch(original, placement)
                else:
                    poisoned, placement = poison_array(original, spec, image_key=file.name)
                labels = (f"original ({file.name})", "patched (preview, not written)")
            h, w = original.shape[:2]
            placement = oriented_placement(placement, orientation, w, h)
            original, poisoned = orient(original, orientation), orient(poisoned, orientation)
            image = render_preview(original, poisoned, placement, labels=labels)
        except (SpecError, ValueError) as exc:
            raise _die(str(exc).splitlines()[0]) from None
        target = (out or Path.cwd() / f"{file.stem}.ppd-preview.png").absolute()
        try:
            Image.fromarray(image).save(target, format="PNG")
        except OSError as exc:
            raise _die(os_error_text(exc, hint_out=False), EXIT_ENVIRONMENT) from None
        console.print(f"preview written to {target}", markup=False)
        if visibility:
            console.print(_visibility_line(original, poisoned, display_width), markup=False, soft_wrap=True)
    finally:
        ctx.close()


def _visibility_line(original, poisoned, display_width: int) -> str:  # arrays: (H, W, C)
    from verifier.visibility import VisibilityError, visibility_report

    try:
        with console.status("measuring visibility"):
            # A picture narrower than the screen is shown at its own size, not magnified (magnifying
            # would make a JPEG re-encode's artefacts, the budget, look larger than any viewer sees them).
            width = min(display_width, original.shape[1])
            return visibility_report(original, poisoned, display_width=width).summary()
    except VisibilityError as exc:
        raise _die(str(exc).splitlines()[0]) from None


def _is_video(path: Path) -> bool:
    from poisoner.media import is_video

    return is_video(path)


def _placement(spec: PatchSpec, original: Any, file: Path) -> Any:
    h, w = original.shape[:2]
    if _is_video(file):
        return spec.resolve(w, h, index=0.0)
    return spec.resolve(w, h, image_key=file.name)


def load_picture(path: Path) -> tuple[Any, int | None]:
    """(stored RGB pixels, EXIF orientation or None); a video's first frame. ppd patches the
    stored pixels, so the preview works in them and orients only what it shows."""
    import numpy as np
    from PIL import Image

    if _is_video(path):
        import av

        from poisoner.video import frame_to_rgb

        with av.open(str(path)) as container:
            for frame in container.decode(video=0):
                return frame_to_rgb(frame), None
        raise ValueError("no video frame")
    with Image.open(path) as im:
        orientation = im.getexif().get(0x0112)
        return np.asarray(im.convert("RGB")), orientation if isinstance(orientation, int) else None


# ---- ppd status ----------------------------------------------------------------------------
def regression_of(runs: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The newest run per profile that went protected → not_protected since its previous run."""
    by_profile: dict[str, list[dict[str, Any]]] = {}
    for run in runs:  # newest first
        by_profile.setdefault(run["profile"], []).append(run)
    for profile_runs in by_profile.values():
        if len(profile_runs) >= 2:
            latest, previous = profile_runs[0], profile_runs[1]
            if previous["verdict"] == VERDICT_PROTECTED and latest["verdict"] == VERDICT_NOT_PROTECTED:
                return latest
    return None


def latest_by_profile(runs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The newest verdict of each profile, with the number it rests on. One newest row would
    hide a hardened failure behind a default pass (or the reverse)."""
    latest: dict[str, dict[str, Any]] = {}
    for run in runs:  # newest first
        if run["profile"] in latest:
            continue
        vs_clean = (run.get("metrics") or {}).get("vs_clean") or {}
        latest[run["profile"]] = {
            "verdict": run["verdict"],
            "frac_within_5deg": vs_clean.get("frac_within_5deg"),
            "finished_at": run["finished_at"],
            "error": run["error"],
        }
    return latest


def verdict_text(profile: str, v: dict[str, Any], markup: bool = True) -> str:
    style = {"protected": "green", "weak": "yellow", "not_protected": "bold red", "sfm_crashed": "magenta"}
    label = verdict_words(v["verdict"])
    frac = v.get("frac_within_5deg")
    detail = f", {frac:.0%} of cameras within 5°" if isinstance(frac, int | float) else ""
    shown = f"[{style.get(v['verdict'], 'bold')}]{label}[/]" if markup else label
    return f"{profile}: {shown}{detail} ({_age(v['finished_at'])})"


PROTECTION_STYLE = {
    Protection.PROTECTED: "bold green",
    Protection.WEAK: "bold yellow",
    Protection.NOT_PROTECTED: "bold red",
    Protection.UNVERIFIABLE: "magenta",
    Protection.PATCHED_NOT_VERIFIED: "yellow",
}


def dataset_status(ctx: AppContext, name: str) -> dict[str, Any]:
    from daemon.auto import status_text as auto_status_text  # light: no torch, no pycolmap

    row = ctx.store.dataset(name)
    if row is None:
        raise _die(f"no dataset {name!r}")
    spec = ctx.store.get_spec(row["spec_id"]) if row["spec_id"] else None
    runs = ctx.store.verification_runs(name, limit=50)
    latest = runs[0] if runs else None
    regression = regression_of(runs)
    counts = ctx.store.counts(name)
    verdicts = latest_by_profile(runs)
    protection, profiles = dataset_protection(counts, verdicts)
    return {
        "name": name,
        "root": row["root"],
        "publish_dir": row["publish_dir"],
        "spec_id": row["spec_id"],
        "spec": spec.to_dict() if spec else None,
        "spec_summary": spec_summary(spec) if spec else None,
        "auto": auto_status_text(ctx, name),  # automatic mode's decision in force (None: not decided)
        "counts": counts,
        "patched": patched_count(counts),
        "protection": {
            "state": protection.value,
            "profiles": profiles,
            "text": protection_text(protection, profiles),
            "next": next_step(protection, name),
        },
        "last_verification": None
        if latest is None
        else {
            "profile": latest["profile"],
            "verdict": latest["verdict"],
            "finished_at": latest["finished_at"],
            "age_s": round(time.time() - latest["finished_at"], 1),
            "error": latest["error"],
        },
        "verdicts": verdicts,
        "regression": None
        if regression is None
        else {
            "profile": regression["profile"],
            "run_id": regression["id"],
            "finished_at": regression["finished_at"],
        },
    }


def failed_files(ctx: AppContext, name: str) -> list[dict[str, Any]]:
    """Each failed file of a dataset with its one-line reason (the store row's error)."""
    return [
        {"path": r["path"], "reason": file_reason(r["path"], r.get("error"))}
        for r in ctx.store.files(name, state=FileState.FAILED.value)
    ]


def _protection_cell(d: dict[str, Any]) -> str:
    state = Protection(d["protection"]["state"])
    return f"[{PROTECTION_STYLE.get(state, 'bold')}]{d['protection']['text']}[/]"


def status_table(report: list[dict[str, Any]], width: int, outbox: Path) -> Table:
    """One row per dataset. Columns drop as the terminal narrows (files, then failed, then
    patched); the dataset name and the protection words are folded, never cut."""
    columns = ["dataset", "files", "patched", "failed", "protection"]
    if width < 72:
        columns.remove("files")
    if width < 56:
        columns.remove("failed")
    if width < 44:
        columns.remove("patched")
    table = Table(expand=False)
    for column in columns:
        numeric = column in ("files", "patched", "failed")
        table.add_column(
            column, justify="right" if numeric else "left", overflow="fold", no_wrap=numeric,
            min_width=len(column) if numeric else None, ratio=None if numeric else 1,
        )  # fmt: skip
    for d in report:
        c = d["counts"]
        cells = {
            "dataset": d["name"],
            "files": str(c["files"]),
            "patched": str(d["patched"]),
            "failed": str(c.get(FileState.FAILED.value, 0)),
            "protection": _protection_cell(d),
        }
        table.add_row(*(cells[k] for k in columns))
    return table


def _print_details(d: dict[str, Any]) -> None:
    """--long (or one dataset): where it is, the spec, each profile's verdict."""
    c = d["counts"]
    console.print(f"[bold]{d['name']}[/]  {d['root']}")
    states: Counter[str] = Counter()
    for key, n in c.items():
        if key != "files" and n:
            states[state_word(key)] += n
    listed = ", ".join(f"{k} {n}" for k, n in sorted(states.items()))
    console.print(f"  files {c['files']}: {listed}", markup=False, soft_wrap=False)
    console.print(f"  spec {d['spec_id'] or '-'}: {d['spec_summary'] or '-'}", markup=False, soft_wrap=False)
    if d["auto"]:
        console.print(f"  {d['auto']}", markup=False, soft_wrap=False)
    if d["publish_dir"]:
        console.print(f"  publish to {d['publish_dir']}", markup=False, soft_wrap=False)
    for profile, v in d["verdicts"].items():
        console.print("  " + verdict_text(profile, v), soft_wrap=False)
    if not d["verdicts"]:
        console.print("  verified: never", markup=False, soft_wrap=False)


def status(
    dataset: str | None = typer.Argument(None, help="One dataset (default: all)."),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
    long: bool = typer.Option(False, "--long", "-l", help="Also the spec and each profile's verdict."),
    failed: bool = typer.Option(False, "--failed", help="List each failed file with its reason."),
) -> None:
    """Each dataset: files patched and failed, and whether it is protected (a verification's
    verdict) or only patched; warns on regressions and on sync folders.

    \b
    Examples:
      ppd status                  every dataset, one line each
      ppd status castle           one dataset in detail
      ppd status castle --failed  the files that failed, and why
    """
    ctx = _open_ctx()
    try:
        names = [dataset] if dataset else [d["name"] for d in ctx.store.datasets()]
        report = [dataset_status(ctx, n) for n in names]
        if failed:
            for d in report:
                d["failed_files"] = failed_files(ctx, d["name"])
        sync = find_sync_folder(ctx.paths.outbox)
        if as_json:
            payload = {
                "outbox": str(ctx.paths.outbox),
                "sync_folder": None if sync is None else {"client": sync.client, "root": str(sync.root)},
                "datasets": report,
            }
            typer.echo(json.dumps(payload, indent=2, default=str))
            return
        if sync is not None:
            warning(
                f"the outbox {ctx.paths.outbox} is inside a {sync.client} folder ({sync.root}): "
                "originals may be uploaded before ppd patches them"
            )
        if failed:
            _print_failed(report)
            return
        if not report:
            console.print(f"no datasets yet; outbox {ctx.paths.outbox}", markup=False)
            return
        console.print(status_table(report, console.width, ctx.paths.outbox))
        if long or dataset:
            console.print(f"outbox {ctx.paths.outbox}", markup=False)
            for d in report:
                _print_details(d)
        for d in report:
            # word-wrapped to the terminal (soft_wrap off): these lines say what to run next
            if d["protection"]["next"]:
                console.print(f"{d['name']}: {d['protection']['next']}", markup=False, soft_wrap=False)
            n_failed = d["counts"].get(FileState.FAILED.value, 0)
            if n_failed:
                console.print(
                    f"{d['name']}: {n_failed} failed: ppd status {d['name']} --failed",
                    markup=False,
                    soft_wrap=False,
                )
        _print_report_links(ctx, names)
        for d in report:
            if d["regression"]:
                err_console.print(
                    f"[bold red]REGRESSION:[/] dataset {d['name']!r} went from protected to NOT protected "
                    f"in its last {d['regression']['profile']!r} verification; its published images "
                    "may reconstruct: check `ppd verify` and the spec."
                )
    finally:
        ctx.close()


def _print_failed(report: list[dict[str, Any]]) -> None:
    """One line per failed file: `PATH: reason` (mat2's habit), grouped by dataset."""
    for d in report:
        rows = d.get("failed_files") or []
        console.print(f"{d['name']}: {len(rows)} failed", markup=False)
        for r in rows:
            console.print(f"  {r['path']}: {r['reason']}", markup=False)


def _print_report_links(ctx: AppContext, names: list[str]) -> None:
    """One line per dataset that has a report (`ppd report DATASET` writes it)."""
    from daemon.report import report_path  # light: no torch, no pycolmap

    for name in names:
        path = report_path(ctx.paths, name)
        if path.is_file():
            console.print(f"report {name}: file://{path}", markup=False)


# ---- ppd dataset ---------------------------------------------------------------------------
dataset_app = typer.Typer(help="Show or set a dataset's patch spec.", no_args_is_help=True)


@dataset_app.command("show")
def dataset_show(name: str, as_json: bool = typer.Option(False, "--json")) -> None:
    """A dataset's spec and counts."""
    ctx = _open_ctx()
    try:
        info = dataset_status(ctx, name)
        if as_json:
            typer.echo(json.dumps(info, indent=2, default=str))
            return
        console.print(f"[bold]{name}[/] at {info['root']}  spec {info['spec_id']}: {info['spec_summary']}")
        if info["spec"]:
            console.print(PatchSpec.from_dict(info["spec"]).to_toml(), end="")
        console.print(" ".join(f"{k}={v}" for k, v in info["counts"].items()))
    finally:
        ctx.close()


@dataset_app.command("set")
@spec_options()
def dataset_set(
    name: str = typer.Argument(..., help="The dataset."),
    root: Path | None = typer.Option(None, "--root", help="Dataset folder (default: OUTBOX/NAME)."),
    publish_dir: Path | None = typer.Option(None, "--publish-dir", help="Move patched files here."),
    reprotect: bool = typer.Option(False, "--reprotect", help="Patch again from the vault originals."),
    spec_options: SpecOptions = SpecOptions(),
) -> None:
    """Set a dataset's spec. Once files are patched, a new spec needs --reprotect (every
    image must carry the same patch).

    \b
    Examples:
      ppd dataset set castle --design paper
      ppd dataset set castle --patch-size 8% --reprotect
    """
    options = spec_options
    ctx = _open_ctx()
    try:
        existing = ctx.store.dataset(name)
        base = ctx.store.dataset_spec(name) or ctx.config.spec_for(name)
        try:
            spec = options.build(base)
        except (SpecError, OSError, ValueError) as exc:
            raise _die(str(exc).splitlines()[0]) from None
        folder = root.absolute() if root else (Path(existing["root"]) if existing else None)
        folder = folder or dataset_root(ctx.paths.outbox.absolute(), name)
        if reprotect and existing is not None:
            outcomes = reprotect_dataset(ctx, name, spec)
            counts = Counter(o.state for o in outcomes)
            console.print(
                f"patched again {name}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
            )
            for o in outcomes:
                if o.state == "failed":
                    err_console.print(f"ppd: failed: {o.path}: {file_reason(o.path, o.reason)}", markup=False)
        else:
            try:
                ctx.store.set_dataset_spec(name, spec, root=folder)
            except DatasetSpecLocked as exc:
                raise _die(str(exc)) from None
        if publish_dir is not None:
            ctx.store.set_dataset_publish_dir(name, publish_dir.absolute())
        console.print(f"{name}: spec {spec.spec_id} ({spec_summary(spec)})", markup=False)
    finally:
        ctx.close()


# ---- ppd config ----------------------------------------------------------------------------
config_app = typer.Typer(help="Show the configuration or where it lives.", no_args_is_help=True)


@config_app.command("show")
def config_show() -> None:
    """The effective configuration (defaults + config.toml) as TOML."""
    from daemon.config import Config
    from daemon.paths import AppPaths

    paths = AppPaths.from_env()
    try:
        config = Config.load(paths)
    except ConfigError as exc:
        raise _die(str(exc)) from None
    typer.echo(f"# {paths.config_file}{'' if config.source else ' (not present: defaults)'}")
    typer.echo(config.to_toml(), nl=False)


@config_app.command("path")
def config_path() -> None:
    """Where config.toml, the data, the vault and the outbox are."""
    from daemon.paths import AppPaths

    paths = AppPaths.from_env()
    typer.echo(f"config   {paths.config_file}")
    typer.echo(f"data     {paths.data_dir}")
    typer.echo(f"store    {paths.db_path}")
    typer.echo(f"vault    {paths.vault_dir}")
    typer.echo(f"outbox   {paths.outbox}")
    typer.echo(f"cache    {paths.cache_dir}")


def register(app: typer.Typer) -> None:
    app.command("poison", help=POISON_HELP)(poison)
    app.command("restore")(restore)
    app.command("preview")(preview)
    app.command("status")(status)
    app.add_typer(dataset_app, name="dataset")
    app.add_typer(config_app, name="config")
