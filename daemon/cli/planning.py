"""`ppd poison`'s plan: one job per file (its dataset, the dataset's root, where its copy goes
with --out), checked before anything is written: one root per dataset, writable folders, the
spec each dataset gets."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from daemon.cli.errors import EXIT_ENVIRONMENT, die, one_line, os_error_text

if TYPE_CHECKING:
    from daemon.cli.options import SpecOptions
    from daemon.context import AppContext
    from poisoner.spec import PatchSpec


@dataclass(frozen=True)
class Job:
    path: Path
    dataset: str
    root: Path
    out_path: Path | None


def media_files(folder: Path) -> list[Path]:
    """Regular, non-hidden files under folder (hidden folders skipped too), sorted."""
    from daemon.protect import is_ignored_name

    files = []
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder)
        if any(part.startswith(".") for part in rel.parts) or is_ignored_name(p):
            continue
        if p.is_symlink() or p.is_file():  # symlinks are listed so protect_file refuses them loudly
            files.append(p)
    return files


def plan_jobs(ctx: AppContext, targets: list[Path], dataset: str | None, out: Path | None) -> list[Job]:
    """One job per file of the targets, each with its dataset by the one rule of attribution
    (daemon.dataset.attribute: a folder is one dataset, a file belongs to its outbox dataset or
    to one named after its parent; --dataset names it, and a known name keeps its root)."""
    from daemon.dataset import DatasetConflict, attribute

    jobs: list[Job] = []
    for target in targets:
        target = target.absolute()
        if not target.exists() and not target.is_symlink():
            raise die(f"{target} does not exist")
        try:
            name, root = attribute(ctx, target, dataset)
        except DatasetConflict as exc:
            raise die(one_line(exc)) from None
        files = media_files(target) if target.is_dir() else [target]
        for f in files:
            out_path = None
            if out is not None:
                rel = f.relative_to(target) if target.is_dir() else Path(f.name)
                out_path = (out.absolute() / name / rel) if target.is_dir() else out.absolute() / rel
            jobs.append(Job(f, name, root, out_path))
    return jobs


def check_dataset_roots(ctx: AppContext, jobs: list[Job]) -> None:
    seen: dict[str, Path] = {}
    for job in jobs:
        root = seen.setdefault(job.dataset, job.root)
        if root.absolute() != job.root.absolute():
            raise die(f"dataset {job.dataset!r} would cover both {root} and {job.root}; use --dataset")
        row = ctx.store.dataset(job.dataset)
        if row is not None and Path(row["root"]).absolute() != job.root.absolute():
            raise die(
                f"dataset {job.dataset!r} already belongs to {row['root']}; name this one with --dataset NAME"
            )


def check_writable(jobs: list[Job], dry_run: bool) -> None:
    """Refuse before touching anything when a folder ppd must write into is not writable
    (instead of one `[Errno 13] ... .ppd-tmp-x.jpg` per file)."""
    if dry_run:
        return
    folders = {job.path.parent for job in jobs if job.out_path is None}
    for folder in sorted(folders):
        if not os.access(folder, os.W_OK | os.X_OK):
            raise die(f"folder not writable: {folder}; use --out DIR", EXIT_ENVIRONMENT)
    for out_folder in sorted({job.out_path.parent for job in jobs if job.out_path is not None}):
        try:
            out_folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise die(os_error_text(exc, hint_out=False), EXIT_ENVIRONMENT) from None
        if not os.access(out_folder, os.W_OK | os.X_OK):
            raise die(f"folder not writable: {out_folder}", EXIT_ENVIRONMENT)


def apply_spec(ctx: AppContext, jobs: list[Job], options: SpecOptions, dry_run: bool) -> dict[str, PatchSpec]:
    """The spec each dataset will use when flags were given (set on new datasets now)."""
    from daemon.store import DatasetSpecLocked
    from poisoner.spec import SpecError

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
            raise die(one_line(exc)) from None
        wanted[job.dataset] = spec
        if not dry_run:
            try:
                ctx.store.set_dataset_spec(job.dataset, spec, root=job.root)
            except DatasetSpecLocked as exc:
                raise die(str(exc)) from None
    return wanted


def output_places(jobs: list[Job]) -> list[str]:
    """Where --out put the copies: one folder per dataset (a single file: its own path)."""
    by_dataset: dict[str, list[Path]] = {}
    for job in jobs:
        if job.out_path is not None:
            by_dataset.setdefault(job.dataset, []).append(job.out_path)
    places = []
    for paths in by_dataset.values():
        places.append(str(paths[0]) if len(paths) == 1 else str(Path(os.path.commonpath(paths))) + os.sep)
    return places
