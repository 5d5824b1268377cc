"""`ppd auto TARGET`: run automatic mode's preflight now and print the decision with its evidence;
`ppd auto DATASET --show`: the decisions recorded for a dataset (docs/AUTO.md).

TARGET is a daemon dataset (its vault originals are the sample; the decision is recorded with
trigger 'manual' and applied when the dataset is automatic or --apply is given) or a folder of
images (measured only, nothing recorded). Exit status: 0 = a candidate was chosen; 1 = none
(over the budget, not protected, time budget, inconclusive); 2 = bad input (one line).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from daemon.cli.errors import die, one_line
from daemon.cli.output import console, err_console

if TYPE_CHECKING:
    from rich.table import Table

    from daemon.context import AppContext


def _fail(message: str, code: int = 2) -> typer.Exit:
    return die(message, code)


CANDIDATES_TITLE = "candidates (least visible first by measured budget use)"
METRICS = ("noticeable", "p99.9 vs JPEG", "SSIM min", "LPIPS max", "budget use")


def evidence_table(evidence: list[dict[str, Any]], profiles: list[str]) -> Table:
    """One row per candidate: measured visibility, budget use, status and per-profile verdicts."""
    from rich.table import Table

    table = Table(title=CANDIDATES_TITLE, show_lines=False)
    for col in ("candidate", "status", *METRICS):
        table.add_column(col, justify="left" if col in ("candidate", "status") else "right", overflow="fold")
    for p in profiles:
        table.add_column(f"{p}: verdict, within 5°", overflow="fold")
    table.add_column("s", justify="right", overflow="fold")
    for e in _by_budget_use(evidence):
        name, status, metrics, verdicts, seconds = _cells(e, profiles)
        table.add_row(name, status, *metrics, *verdicts, seconds)
    return table


def print_evidence(evidence: list[dict[str, Any]], profiles: list[str]) -> None:
    """The table where it fits the console; else one block per candidate, its values packed between
    spaces, as `ppd status` folds its columns: at 80 columns (a pipe, a log file) the table cut SSIM
    0.9938 into "0.993" and "8" a row below, and names over five rows (a black-box review, F8)."""
    from rich.measure import Measurement

    out = console()
    table = evidence_table(evidence, profiles)
    if Measurement.get(out, out.options.update_width(1 << 16), table).maximum <= out.width:  # unclamped
        out.print(table)
        return
    out.print(CANDIDATES_TITLE, markup=False)
    for e in _by_budget_use(evidence):
        name, status, metrics, verdicts, seconds = _cells(e, profiles)
        out.print(f"{name}: {status}, {seconds} s", markup=False, soft_wrap=True)
        items = [f"{label} {value}" for label, value in zip(METRICS, metrics, strict=True)]
        items += [f"{p}: {v}" for p, v in zip(profiles, verdicts, strict=True)]
        for line in _packed(items, out.width):
            out.print(line, markup=False, soft_wrap=True)


def _packed(items: list[str], width: int, indent: str = "  ") -> list[str]:
    """items joined by "; " into lines of at most width, an item never split (one longer than the
    width is a line of its own)."""
    lines: list[str] = []
    line = ""
    for item in items:
        if line and len(indent) + len(line) + 2 + len(item) > width:
            lines.append(indent + line + ";")
            line = ""
        line = f"{line}; {item}" if line else item
    return lines + ([indent + line] if line else [])


def _by_budget_use(evidence: list[dict[str, Any]]) -> list[dict[str, Any]]:
    def order(e: dict[str, Any]) -> float:
        return float("inf") if e.get("budget_use") is None else float(e["budget_use"])

    return sorted(evidence, key=order)


def _cells(e: dict[str, Any], profiles: list[str]) -> tuple[str, str, list[str], list[str], str]:
    """(candidate, status, METRICS' values, each profile's verdict, seconds) of one candidate."""
    vis = e.get("visibility") or {}
    metrics = [
        _pct(vis.get("noticeable_area_max"), 2),  # FLIP > 0.5, the budget (issue 14)
        _num(vis.get("p999_vs_jpeg_max"), 2),
        _num(vis.get("ssim_min"), 4),  # the paper's figures, reported
        _num(vis.get("lpips_max"), 4),
        _num(e.get("budget_use"), 2),
    ]
    verdicts = []
    for p in profiles:
        pr = (e.get("profiles") or {}).get(p)
        verdicts.append("—" if pr is None else f"{pr['verdict']}, {_pct(pr.get('frac_within_5deg'))}")
    status = e["status"] + (f" ({e['error']})" if e.get("error") else "")
    return e["name"], status, metrics, verdicts, f"{e.get('seconds', 0):.0f}"


def _num(x: Any, digits: int) -> str:
    return "n/a" if x is None else f"{float(x):.{digits}f}"


def _pct(x: Any, digits: int = 0) -> str:
    return "n/a" if x is None else f"{100 * float(x):.{digits}f}%"


def print_decision(decision: dict[str, Any]) -> None:
    """The choice and its reason; with none, the reason alone, which says why in words (the outcome's
    token, "time_budget", was a line of its own: a black-box review, F8)."""
    from rich.markup import escape

    chosen = decision.get("chosen")
    if chosen:
        console().print(f"[green]chosen: {escape(chosen)}[/green]", highlight=False)
        console().print(decision["reason"], markup=False, highlight=False)
    else:
        console().print(f"[red]{escape(decision['reason'])}[/red]", highlight=False)
    if not decision.get("lpips_checked"):
        console().print(f"[yellow]LPIPS not checked:[/yellow] {decision.get('lpips_note')}", highlight=False)
    print_evidence(decision["evidence"], list(decision["options"]["profiles"]))
    sample = f"sample: {len(decision['sample'])} images; {decision['elapsed_s']:.0f} s"
    console().print(sample, highlight=False)


def _show(target: str, as_json: bool) -> None:
    from daemon.cli.targets import TargetError, dataset_or_die
    from daemon.context import AppContext

    ctx = AppContext.open()
    try:
        try:
            dataset = dataset_or_die(ctx.store, target, err_console(), "--show needs a dataset")
        except TargetError as exc:
            raise _fail(one_line(exc)) from None
        rows = ctx.store.auto_decisions(dataset, limit=50)
    finally:
        ctx.close()
    if as_json:
        console().print_json(json.dumps(rows, default=str))
        return
    if not rows:
        console().print(f"{dataset}: no automatic decision recorded", highlight=False)
        return
    _print_decisions(dataset, rows)
    latest = rows[0]["evidence"]
    if isinstance(latest.get("evidence"), list):
        print_evidence(latest["evidence"], list(latest["options"]["profiles"]))


def _print_decisions(dataset: str, rows: list[dict[str, Any]]) -> None:
    if console().width < 100:  # a narrow terminal: one block per decision, words never cut
        console().print(f"automatic decisions for {dataset} (newest first)", markup=False)
        for r in rows:
            when = time.strftime("%Y-%m-%d %H:%M", time.localtime(r["decided_at"]))
            console().print(f"{when} {r['trigger']}: {r['candidate'] or 'none'} ({r['spec_id'] or '—'})",
                          markup=False)  # fmt: skip
            console().print(f"  {r['reason']}", markup=False, soft_wrap=False)
    else:
        from rich.table import Table

        table = Table(title=f"automatic decisions for {dataset} (newest first)")
        for col in ("when", "trigger", "candidate", "spec", "reason"):
            table.add_column(col, overflow="fold")
        for r in rows:
            when = time.strftime("%Y-%m-%d %H:%M", time.localtime(r["decided_at"]))
            table.add_row(when, r["trigger"], r["candidate"] or "none", r["spec_id"] or "—", r["reason"])
        console().print(table)


def _images(ctx: AppContext, target: str) -> tuple[list[Any], str | None]:
    """(the preflight sample's source images, the dataset of the store target names, or None for a
    plain folder). target: a dataset's name, its folder or a verification folder, or any folder."""
    from daemon.cli.targets import TargetError, resolve_target, say_note
    from daemon.verification import auto_mode as daemon_auto
    from verifier.auto_options import MIN_SAMPLE  # light: the preflight's modules load scipy

    try:
        chosen = resolve_target(ctx.store, target)
    except TargetError as exc:
        raise _fail(one_line(exc)) from None
    say_note(chosen, err_console())  # stderr: stdout may be --json
    if chosen.dataset is not None:
        images = daemon_auto.dataset_images(ctx, chosen.dataset)
        if len(images) < MIN_SAMPLE:  # restored ones have no vault pair: "got 0 images" said nothing
            raise _fail(f"dataset {chosen.dataset!r} has {len(images)} patched file(s) with their original "
                        f"in the vault; automatic mode measures at least {MIN_SAMPLE}: patch them first "
                        f"(`ppd poison`), or give a folder of originals")  # fmt: skip
        return images, chosen.dataset
    assert chosen.folder is not None
    folder = chosen.folder
    return sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")), None


def _scene_line(target: str, images: list[Any]) -> str | None:
    """The scene hint for the sample's source images (a dataset's vault originals are named by their
    pairs' file names, which say whether they are images)."""
    from daemon.cli.scene_note import scene_line
    from poisoner.media import is_image

    pairs = [item if isinstance(item, tuple) else (item, item.name) for item in images]
    return scene_line(Path(target).name or target, [Path(src) for src, name in pairs if is_image(name)])


def _settings(ctx: AppContext, given: dict[str, Any]) -> tuple[Any, Any]:
    """The config's [visibility] budget and [preflight] options with the command line's on top."""
    import msgspec

    from daemon.verification import auto_mode as daemon_auto

    budget, options = daemon_auto.settings_of(ctx)
    budget_keys = ("max_noticeable_area", "max_p999_vs_jpeg", "corner_only")
    budget = msgspec.structs.replace(budget, **{k: given[k] for k in budget_keys if given[k] is not None})
    wanted = {"sample_size": given["sample"], "time_budget_s": given["time_budget"],
              "profiles": tuple(given["profile"]) or None}  # fmt: skip
    options = msgspec.structs.replace(options, **{k: v for k, v in wanted.items() if v})
    # replace() does not check: a struct built anew runs its checks (a one-line PreflightInputError)
    return type(budget)(**msgspec.structs.asdict(budget)), type(options)(**msgspec.structs.asdict(options))


def _checked_settings(ctx: AppContext, given: dict[str, Any]) -> tuple[Any, Any]:
    """_settings, a bad value one line (exit 2) before any work: `--max-noticeable-area 2` analysed
    the photos and printed the scene hint first (a black-box review, F11)."""
    from verifier.auto_options import PreflightInputError

    try:
        return _settings(ctx, given)
    except PreflightInputError as exc:
        raise _fail(one_line(exc)) from None


def _preflight(ctx: AppContext, target: str, images: list[Any], is_dataset: bool,
               settings: tuple[Any, Any], out: Path | None) -> dict[str, Any]:  # fmt: skip
    """Run the preflight with the settings (_checked_settings)."""
    import msgspec

    from daemon.verification import auto_mode as daemon_auto
    from poisoner.errors import ImageFormatError
    from verifier.auto_options import PreflightInputError
    from verifier.auto_search import preflight

    budget, options = settings
    try:
        work = out or Path(ctx.paths.runs_dir) / (target if is_dataset else "_folders") / (
            f"auto-{time.strftime('%Y%m%dT%H%M%S')}"
        )
        return msgspec.to_builtins(preflight(images, daemon_auto.load_ladder(), budget, options, work))
    except (PreflightInputError, ImportError, ImageFormatError) as exc:  # a sample photo not decoded: input
        raise _fail(one_line(exc)) from None


def _record(ctx: AppContext, target: str, decision: dict[str, Any], apply: bool | None) -> None:
    """A dataset's decision goes in the store (trigger 'manual'); applied when asked or automatic."""
    from daemon.verification import auto_mode as daemon_auto
    from poisoner.spec import PatchSpec

    do_apply = apply if apply is not None else ctx.config.is_auto(target)
    spec = decision["spec"]
    ctx.store.add_auto_decision(
        target, decision["chosen"], PatchSpec.from_dict(spec) if spec else None,
        decision["reason"], decision, "manual",
    )  # fmt: skip
    if spec and do_apply:
        decision["reprotected"] = daemon_auto.apply_spec(ctx, target, PatchSpec.from_dict(spec))
    elif not spec:
        daemon_auto.surface_no_candidate(ctx, target, decision["reason"])


def _print_result(
    decision: dict[str, Any], as_json: bool, hint: str | None, dataset_line: str | None
) -> None:
    if as_json:
        console().print_json(json.dumps(decision | {"scene_hint": hint}, default=str))
        return
    print_decision(decision)
    if "reprotected" in decision:
        console().print(f"re-protected {decision['reprotected']} file(s) from the vault", highlight=False)
    if dataset_line:
        console().print(dataset_line, markup=False)


def auto(
    target: str = typer.Argument(
        ..., help="A dataset (its name, its folder, a verification folder of it), or a folder of images."
    ),
    max_noticeable_area: float | None = typer.Option(
        None, "--max-noticeable-area", metavar="FRACTION",
        help="Budget: most of the picture a viewer notices (FLIP > 0.5), e.g. 0.01 (config: [visibility]).",
    ),
    max_p999_vs_jpeg: float | None = typer.Option(
        None, "--max-p999-vs-jpeg", metavar="RATIO",
        help="Budget: FLIP p99.9 at most RATIO x a JPEG q85 re-encode's (0: not gated).",
    ),
    corner_only: bool | None = typer.Option(
        None, "--corner-only/--anywhere", help="Budget: every changed pixel in one corner region, or not."
    ),
    sample: int | None = typer.Option(None, "--sample", min=3, help="Images in the preflight sample."),
    time_budget: float | None = typer.Option(None, "--time-budget", min=1.0, help="Preflight seconds."),
    profile: list[str] = typer.Option([], "--profile", help="Profiles to confirm (repeat; default: config)."),
    show: bool = typer.Option(False, "--show", help="Print the recorded decisions instead of running."),
    apply: bool | None = typer.Option(
        None, "--apply/--no-apply", help="Re-protect the dataset with the choice (default: when it is auto)."
    ),
    out: Path | None = typer.Option(None, "--out", help="Working folder (default: a new one under runs)."),
    as_json: bool = typer.Option(False, "--json", help="Print the decision as JSON."),
) -> None:
    """Automatic mode's preflight now: the least visible candidate that COLMAP cannot use."""
    if show:
        _show(target, as_json)
        return
    from daemon.cli.status_queries import protection_line
    from daemon.config import ConfigError
    from daemon.context import AppContext

    given = {"max_noticeable_area": max_noticeable_area, "max_p999_vs_jpeg": max_p999_vs_jpeg,
             "corner_only": corner_only, "sample": sample, "time_budget": time_budget,
             "profile": profile}  # fmt: skip
    try:
        ctx = AppContext.open()
    except ConfigError as exc:
        raise _fail(one_line(exc)) from None
    dataset_line = None
    try:
        settings = _checked_settings(ctx, given)
        images, name = _images(ctx, target)
        is_dataset = name is not None
        target = name or target
        hint = _scene_line(target, images)  # up front: the preflight takes minutes
        if hint and not as_json:
            console().print(hint, markup=False)
        decision = _preflight(ctx, target, images, is_dataset, settings, out)
        if is_dataset:
            _record(ctx, target, decision, apply)
            dataset_line = protection_line(ctx, target)  # what its verifications say, not the sample's
    finally:
        ctx.close()
    _print_result(decision, as_json, hint, dataset_line)
    raise typer.Exit(0 if decision["chosen"] else 1)


def register(app: typer.Typer) -> None:
    app.command("auto")(auto)
