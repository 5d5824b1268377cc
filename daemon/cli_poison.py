"""`ppd poison`, `ppd restore`, `ppd preview`, `ppd status`, `ppd dataset`, `ppd config`.

Light imports only: no pycolmap, no torch (the poisoners load lazily inside protect_file).
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from daemon.config import ConfigError, parse_length, spec_from_table
from daemon.dataset import dataset_of, dataset_root
from daemon.protect import (
    AppContext,
    ProtectOutcome,
    is_ignored_name,
    protect_file,
    reprotect_dataset,
    restore_file,
)
from daemon.store import DatasetSpecLocked, StoreError
from daemon.syncdirs import find_sync_folder
from poisoner.spec import POSITIONS, PatchSpec, SpecError

console = Console()
err_console = Console(stderr=True)

# verifier.verdict's names (kept as strings so status does not import the verifier).
VERDICT_PROTECTED = "protected"
VERDICT_NOT_PROTECTED = "not_protected"


# ---- shared option plumbing ----------------------------------------------------------------
@dataclass(frozen=True)
class SpecOptions:
    """The spec flags of a command; all None means "not given"."""

    spec_file: Path | None = None
    patch_size: str | None = None
    block: str | None = None
    alpha: float | None = None
    contrast: int | None = None
    pattern: str | None = None
    position: str | None = None
    ratio: float | None = None
    seed: int | None = None

    def given(self) -> bool:
        return any(v is not None for v in vars(self).values())

    def build(self, base: PatchSpec) -> PatchSpec:
        """base (or the --spec file) with the given flags applied."""
        if self.spec_file is not None:
            base = PatchSpec.load(self.spec_file)
        changes: dict[str, Any] = {}
        if self.patch_size is not None:
            changes["patch_size"] = parse_length(self.patch_size)
        if self.block is not None:
            changes["block_size"] = parse_length(self.block)
        for name in ("alpha", "contrast", "pattern", "position", "ratio", "seed"):
            value = getattr(self, name)
            if value is not None:
                changes[name] = value
        return spec_from_table(changes, base)


def _spec_options(
    spec_file: Path | None,
    patch_size: str | None,
    block: str | None,
    alpha: float | None,
    contrast: int | None,
    pattern: str | None,
    position: str | None,
    ratio: float | None,
    seed: int | None,
) -> SpecOptions:
    return SpecOptions(spec_file, patch_size, block, alpha, contrast, pattern, position, ratio, seed)


SPEC_FILE = typer.Option(None, "--spec", help="PatchSpec file (TOML [patch] table or JSON).", exists=True)
PATCH_SIZE = typer.Option(None, "--patch-size", help="Pixels (48), fraction of width (0.06) or percent (6%).")
BLOCK = typer.Option(None, "--block", help="Checker block: pixels (4), fraction of width or percent.")
ALPHA = typer.Option(None, "--alpha", help="Blend strength 0..1.")
CONTRAST = typer.Option(None, "--contrast", help="Bright-minus-dark difference 0..255.")
PATTERN = typer.Option(None, "--pattern", help="checkerboard, circles, ... (poisoner.spec.PATTERNS).")
POSITION = typer.Option(None, "--position", help=f"One of {', '.join(POSITIONS)}.")
RATIO = typer.Option(None, "--ratio", help="Fraction of the dataset's images that get the patch.")
SEED = typer.Option(None, "--seed", help="Seed for random patterns and the ratio selection.")


def _die(message: str, code: int = 2) -> typer.Exit:
    err_console.print(f"[bold red]error:[/] {message}")
    return typer.Exit(code)


def _open_ctx() -> AppContext:
    try:
        return AppContext.open()
    except (ConfigError, StoreError) as exc:
        raise _die(str(exc)) from None


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


def _summary(outcomes: list[ProtectOutcome], dry_run: bool) -> None:
    counts = Counter(o.state for o in outcomes)
    table = Table(title="ppd poison (dry run)" if dry_run else "ppd poison")
    for column in ("would protect" if dry_run else "protected", "unchanged", "skipped", "failed"):
        table.add_column(column, justify="right")
    table.add_row(*(str(counts.get(s, 0)) for s in ("protected", "unchanged", "skipped", "failed")))
    console.print(table)
    failed = [o for o in outcomes if o.state == "failed"]
    for o in failed[:20]:
        err_console.print(f"[red]failed[/] {o.path}: {o.reason}")
    if len(failed) > 20:
        err_console.print(f"... and {len(failed) - 20} more failed (see `ppd status`)")


def poison(
    paths: list[Path] = typer.Argument(..., help="Files or folders; a folder is one dataset."),
    spec_file: Path | None = SPEC_FILE,
    patch_size: str | None = PATCH_SIZE,
    block: str | None = BLOCK,
    alpha: float | None = ALPHA,
    contrast: int | None = CONTRAST,
    pattern: str | None = PATTERN,
    position: str | None = POSITION,
    ratio: float | None = RATIO,
    seed: int | None = SEED,
    dry_run: bool = typer.Option(False, "--dry-run", help="Say what would happen; change nothing."),
    out: Path | None = typer.Option(None, "--out", help="Write protected copies here; leave the inputs."),
    dataset: str | None = typer.Option(None, "--dataset", help="Dataset name (default: the folder's)."),
    force: bool = typer.Option(False, "--force", help="Protect again files you restored."),
) -> None:
    """Protect photos/videos in place (originals go to the vault) or into --out. Re-running is a no-op."""
    ctx = _open_ctx()
    try:
        options = _spec_options(spec_file, patch_size, block, alpha, contrast, pattern, position, ratio, seed)
        jobs = plan_jobs(ctx, paths, dataset, out)
        _check_dataset_roots(ctx, jobs)
        wanted = _apply_spec(ctx, jobs, options, dry_run)
        outcomes = _run_jobs(ctx, jobs, wanted, dry_run, force)
        _summary(outcomes, dry_run)
        if any(o.state == "failed" for o in outcomes):
            raise typer.Exit(1)
    finally:
        ctx.close()


def _run_jobs(
    ctx: AppContext, jobs: list[Job], wanted: dict[str, PatchSpec], dry_run: bool, force: bool
) -> list[ProtectOutcome]:
    outcomes: list[ProtectOutcome] = []
    lock = threading.Lock()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=err_console, transient=True) as progress:
        task = progress.add_task("protecting", total=len(jobs))

        def run(job: Job) -> None:
            outcome = protect_file(
                job.path, ctx, job.dataset, root=job.root, out_path=job.out_path,
                dry_run=dry_run, force=force, spec=wanted.get(job.dataset),
            )  # fmt: skip
            with lock:
                outcomes.append(outcome)
            progress.advance(task)

        workers = max(1, min(ctx.config.workers, len(jobs)))
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="ppd-poison") as pool:
            list(pool.map(run, jobs))
    return sorted(outcomes, key=lambda o: str(o.path))


# ---- ppd restore ---------------------------------------------------------------------------
def restore(
    target: str = typer.Argument(..., help="A dataset name or a protected file."),
    force: bool = typer.Option(False, "--force", help="Overwrite even if the file changed since."),
) -> None:
    """Put originals back from the vault (atomic). The daemon will not re-poison restored files."""
    ctx = _open_ctx()
    try:
        as_path = Path(target).absolute()
        if ctx.store.file(as_path) is not None:
            paths = [as_path]
        elif ctx.store.dataset(target) is not None:
            paths = [Path(r["path"]) for r in ctx.store.files(target, state="protected")]
        else:
            raise _die(f"{target!r} is neither a dataset nor a file in the store")
        outcomes = [restore_file(ctx, p, force=force) for p in paths]
        counts = Counter(o.state for o in outcomes)
        console.print(f"restored {counts.get('restored', 0)}, unchanged {counts.get('unchanged', 0)}, "
                      f"failed {counts.get('failed', 0)}")  # fmt: skip
        for o in outcomes:
            if o.state == "failed":
                err_console.print(f"[red]failed[/] {o.path}: {o.reason}")
        if counts.get("failed"):
            raise typer.Exit(1)
    finally:
        ctx.close()


# ---- ppd preview ---------------------------------------------------------------------------
def preview(
    file: Path = typer.Argument(..., exists=True, dir_okay=False, help="An image (original or protected)."),
    out: Path | None = typer.Option(None, "--out", help="PNG to write (default: ./NAME.ppd-preview.png)."),
    spec_file: Path | None = SPEC_FILE,
    patch_size: str | None = PATCH_SIZE,
    block: str | None = BLOCK,
    alpha: float | None = ALPHA,
    contrast: int | None = CONTRAST,
    pattern: str | None = PATTERN,
    position: str | None = POSITION,
    seed: int | None = SEED,
) -> None:
    """Original | poisoned side by side with a zoom on the patch. A protected file is shown
    against its vault original; any other image with its dataset's (or the given) spec."""
    import numpy as np
    from PIL import Image

    from poisoner.blend import poison_array
    from poisoner.preview import render_preview

    ctx = _open_ctx()
    try:
        options = _spec_options(spec_file, patch_size, block, alpha, contrast, pattern, position, None, seed)
        file = file.absolute()
        row = ctx.store.file(file)

        def load(path: Path) -> np.ndarray:
            try:
                with Image.open(path) as im:
                    return np.asarray(im.convert("RGB"))
            except (OSError, ValueError) as exc:
                raise _die(f"cannot read {path.name} as an image: {str(exc).splitlines()[0]}") from None

        try:
            if row is not None and row["state"] == "protected" and not options.given():
                spec = ctx.store.get_spec(row["spec_id"])
                original, poisoned = load(ctx.vault.path_for(row["original_sha256"])), load(file)
                placement = spec.resolve(original.shape[1], original.shape[0], image_key=file.name)
            else:
                base = ctx.config.spec
                if file.is_relative_to(ctx.paths.outbox.absolute()):
                    name = dataset_of(ctx.paths.outbox, file)
                    base = ctx.store.dataset_spec(name) or ctx.config.spec_for(name)
                spec = options.build(base)
                original = load(file)
                poisoned, placement = poison_array(original, spec, image_key=file.name)
            image = render_preview(original, poisoned, placement)
        except (SpecError, ValueError) as exc:
            raise _die(str(exc).splitlines()[0]) from None
        target = out or Path.cwd() / f"{file.stem}.ppd-preview.png"
        Image.fromarray(image).save(target)
        console.print(f"preview written to {target}")
    finally:
        ctx.close()


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


def verdict_text(profile: str, v: dict[str, Any]) -> str:
    style = {"protected": "green", "weak": "yellow", "not_protected": "bold red", "sfm_crashed": "magenta"}
    label = "NOT protected" if v["verdict"] == "not_protected" else v["verdict"]
    frac = v.get("frac_within_5deg")
    detail = f" {frac:.0%}<5°" if isinstance(frac, int | float) else ""
    return f"{profile}: [{style.get(v['verdict'], 'bold')}]{label}[/]{detail} ({_age(v['finished_at'])})"


def dataset_status(ctx: AppContext, name: str) -> dict[str, Any]:
    from daemon.auto import status_text as auto_status_text  # light: no torch, no pycolmap

    row = ctx.store.dataset(name)
    if row is None:
        raise _die(f"no dataset {name!r}")
    spec = ctx.store.get_spec(row["spec_id"]) if row["spec_id"] else None
    runs = ctx.store.verification_runs(name, limit=50)
    latest = runs[0] if runs else None
    regression = regression_of(runs)
    return {
        "name": name,
        "root": row["root"],
        "publish_dir": row["publish_dir"],
        "spec_id": row["spec_id"],
        "spec": spec.to_dict() if spec else None,
        "spec_summary": spec_summary(spec) if spec else None,
        "auto": auto_status_text(ctx, name),  # automatic mode's decision in force (None: not decided)
        "counts": ctx.store.counts(name),
        "last_verification": None
        if latest is None
        else {
            "profile": latest["profile"],
            "verdict": latest["verdict"],
            "finished_at": latest["finished_at"],
            "age_s": round(time.time() - latest["finished_at"], 1),
            "error": latest["error"],
        },
        "verdicts": latest_by_profile(runs),
        "regression": None
        if regression is None
        else {
            "profile": regression["profile"],
            "run_id": regression["id"],
            "finished_at": regression["finished_at"],
        },
    }


def status(
    dataset: str | None = typer.Argument(None, help="One dataset (default: all)."),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
) -> None:
    """Per dataset: files by state, the spec, the last verification; warns on regressions and sync folders."""
    ctx = _open_ctx()
    try:
        names = [dataset] if dataset else [d["name"] for d in ctx.store.datasets()]
        report = [dataset_status(ctx, n) for n in names]
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
            err_console.print(
                f"[bold yellow]warning:[/] the outbox {ctx.paths.outbox} is inside a {sync.client} folder "
                f"({sync.root}): originals may be uploaded before ppd protects them."
            )
        table = Table(title=f"ppd status — outbox {ctx.paths.outbox}")
        for column in ("dataset", "files", "protected", "pending", "failed", "restored", "spec", "verified"):
            table.add_column(
                column, justify="right" if column not in ("dataset", "spec", "verified") else "left"
            )
        for d in report:
            c, v = d["counts"], d["last_verification"]
            verdicts = d["verdicts"]
            verified = "never" if v is None else "\n".join(verdict_text(p, x) for p, x in verdicts.items())
            counts = [str(c[k]) for k in ("files", "protected", "pending", "failed", "restored")]
            spec_text = "\n".join(x for x in (d["spec_summary"] or "-", d["auto"]) if x)
            table.add_row(d["name"], *counts, spec_text, verified)
        console.print(table)
        _print_report_links(ctx, names)
        for d in report:
            if d["regression"]:
                err_console.print(
                    f"[bold red]REGRESSION:[/] dataset {d['name']!r} went from protected to NOT PROTECTED "
                    f"in its last {d['regression']['profile']!r} verification; its published images "
                    f"may reconstruct — check `ppd verify` and the spec."
                )
    finally:
        ctx.close()


def _print_report_links(ctx: AppContext, names: list[str]) -> None:
    """One line per dataset that has a report (`ppd report DATASET` writes it)."""
    from verifier.report import report_path  # light: no torch, no pycolmap

    for name in names:
        path = report_path(ctx.paths, name)
        if path.is_file():
            console.print(f"report {name}: file://{path}")


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
def dataset_set(
    name: str,
    spec_file: Path | None = SPEC_FILE,
    patch_size: str | None = PATCH_SIZE,
    block: str | None = BLOCK,
    alpha: float | None = ALPHA,
    contrast: int | None = CONTRAST,
    pattern: str | None = PATTERN,
    position: str | None = POSITION,
    ratio: float | None = RATIO,
    seed: int | None = SEED,
    root: Path | None = typer.Option(None, "--root", help="Dataset folder (default: OUTBOX/NAME)."),
    publish_dir: Path | None = typer.Option(None, "--publish-dir", help="Move protected files here."),
    reprotect: bool = typer.Option(False, "--reprotect", help="Re-poison protected files from the vault."),
) -> None:
    """Set a dataset's spec. Once files are protected, a new spec needs --reprotect (every
    image must carry the same patch)."""
    ctx = _open_ctx()
    try:
        options = _spec_options(spec_file, patch_size, block, alpha, contrast, pattern, position, ratio, seed)
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
            console.print(f"re-protected {name}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
            for o in outcomes:
                if o.state == "failed":
                    err_console.print(f"[red]failed[/] {o.path}: {o.reason}")
        else:
            try:
                ctx.store.set_dataset_spec(name, spec, root=folder)
            except DatasetSpecLocked as exc:
                raise _die(str(exc)) from None
        if publish_dir is not None:
            ctx.store.set_dataset_publish_dir(name, publish_dir.absolute())
        console.print(f"{name}: spec {spec.spec_id} ({spec_summary(spec)})")
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
    app.command("poison")(poison)
    app.command("restore")(restore)
    app.command("preview")(preview)
    app.command("status")(status)
    app.add_typer(dataset_app, name="dataset")
    app.add_typer(config_app, name="config")
