"""`ppd status [DATASET]`: each dataset's files, whether it is protected (a verification's
verdict) or only patched, what to run next; warnings on regressions and sync folders."""

from __future__ import annotations

import json
import os
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from daemon.cli.errors import die, open_ctx, warning
from daemon.cli.output import console, err_console, print_line
from poisoner.errors import ExitStatus
from verifier.verdict import Verdict

if TYPE_CHECKING:
    from rich.table import Table

    from daemon.context import AppContext

VERDICT_STYLE = {
    Verdict.PROTECTED: "green", Verdict.WEAK: "yellow", Verdict.NOT_PROTECTED: "bold red",
    Verdict.SFM_CRASHED: "magenta",
}  # fmt: skip


def verdict_text(profile: str, v: dict[str, Any], markup: bool = True) -> str:
    from daemon.cli.status_queries import age
    from daemon.states import verdict_words

    label = verdict_words(v["verdict"])
    frac = v.get("frac_within_5deg")
    decided = v["verdict"] in (Verdict.PROTECTED, Verdict.WEAK, Verdict.NOT_PROTECTED)
    # an inconclusive or crashed profile's fraction is of no reference: "0%" read as protection
    detail = f", {frac:.0%} of cameras within 5°" if decided and isinstance(frac, int | float) else ""
    shown = f"[{VERDICT_STYLE.get(v['verdict'], 'bold')}]{label}[/]" if markup else label
    return f"{profile}: {shown}{detail} ({age(v['finished_at'])})"


def _protection_cell(d: dict[str, Any]) -> str:
    from daemon.states import Protection

    style = {
        Protection.PROTECTED: "bold green",
        Protection.WEAK: "bold yellow",
        Protection.NOT_PROTECTED: "bold red",
        Protection.UNVERIFIABLE: "magenta",
        Protection.PATCHED_NOT_VERIFIED: "yellow",
    }.get(Protection(d["protection"]["state"]), "bold")
    return f"[{style}]{d['protection']['text']}[/]"


def _columns(width: int) -> list[str]:
    """Columns drop as the terminal narrows (files, then failed, then patched)."""
    columns = ["dataset", "files", "patched", "failed", "protection"]
    for column, below in (("files", 72), ("failed", 56), ("patched", 44)):
        if width < below:
            columns.remove(column)
    return columns


def status_table(report: list[dict[str, Any]], width: int, outbox: Path) -> Table:
    """One row per dataset; the dataset name and the protection words are folded, never cut."""
    from rich.table import Table

    columns = _columns(width)
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
            "failed": str(c.get("failed", 0)),
            "protection": _protection_cell(d),
        }
        if "failed" not in columns and c.get("failed"):  # a narrow terminal still shows a failure
            cells["protection"] += f"; [bold red]{c['failed']} failed[/]"
        table.add_row(*(cells[k] for k in columns))
    return table


# What a count key is called in the details line ("untracked": files in the folder without a row).
COUNT_WORDS = {
    "untracked": "not patched yet", "changed": "changed since patched", "waiting": "still being written",
    "gone": "deleted or moved away since patched",
    "restored_unrecorded": "restored (a restore was interrupted)",
}  # fmt: skip


def files_line(counts: dict[str, Any]) -> str:
    """`files 23: not patched yet 17, patched 6`: every count of the dataset, once."""
    from collections import Counter

    from daemon.states import state_word

    states: Counter[str] = Counter()
    for key, n in counts.items():
        if key != "files" and n:
            states[COUNT_WORDS.get(key) or state_word(key)] += n
    listed = ", ".join(f"{k} {n}" for k, n in sorted(states.items()))
    return f"files {counts['files']}: {listed}" if listed else f"files {counts['files']}"


def place_lines(d: dict[str, Any]) -> list[str]:
    """Where the dataset is: its folder (said when it is gone), where `--out` put its copies and
    where published files go."""
    folder = d.get("folder") or {}
    lines = []
    if folder and not folder.get("exists", True):
        lines.append(f"folder {d['root']} is gone; counts are the store's")
    if folder.get("copies"):
        lines.append(f"patched copies in {folder['copies']}")
    if d["publish_dir"]:
        lines.append(f"publish to {d['publish_dir']}")
    return lines


def _print_details(d: dict[str, Any]) -> None:
    """--long (or one dataset): where it is, the spec, each profile's verdict."""
    out = console()
    out.print(f"[bold]{d['name']}[/]  {d['root']}")
    lines = [files_line(d["counts"]), f"spec {d['spec_id'] or '-'}: {d['spec_summary'] or '-'}"]
    if d["auto"]:
        lines.append(d["auto"])
    lines += place_lines(d)
    lines += d.get("mark_notes") or []
    for line in lines:
        print_line(out, "  " + line)
    for profile, v in d["verdicts"].items():
        out.print("  " + verdict_text(profile, v), soft_wrap=False)
    if not d["verdicts"]:
        print_line(out, "  " + unverified_line(d.get("last_verification")))


def unverified_line(last: dict[str, Any] | None) -> str:
    """What a dataset with no verdict on its pixels as they are now says: never verified, or
    verified before its files last changed (issue 25: that verdict is history, not the verdict)."""
    from daemon.cli.status_queries import age
    from daemon.states import verdict_words

    if last is None:
        return "verified: never"
    verdict = f"{last['profile']}: {verdict_words(last['verdict'])}"
    return f"not verified since the files changed (last verification: {age(last['finished_at'])}, {verdict})"


def failed_lines(d: dict[str, Any]) -> list[str]:
    """`castle: 1 failed, 1 quarantined`, then one line per file: `PATH: reason` (mat2's habit),
    a quarantined one marked so: the same counts as the table's."""
    rows = d.get("failed_files") or []
    c = d["counts"]
    lines = [f"{d['name']}: {c.get('failed', 0)} failed, {c.get('quarantined', 0)} quarantined"]
    for r in rows:
        mark = ""
        if r.get("state") == "quarantined":
            mark = f" (quarantined: moved to {r['moved_to']})" if r.get("moved_to") else " (quarantined)"
        shown = r.get("source") or r["path"]  # --out: the file that failed, not the copy never written
        lines.append(f"  {shown}: {r['reason']}{mark}")
    return lines


def _print_failed(report: list[dict[str, Any]]) -> None:
    for d in report:
        for line in failed_lines(d):
            console().print(line, markup=False)


def _print_report_links(ctx: AppContext, names: list[str]) -> None:
    """One line per dataset that has a report (`ppd report DATASET` writes it)."""
    from daemon.verification.dataset_report import report_path  # light: no torch, no pycolmap

    for name in names:
        path = report_path(ctx.paths, name)
        if path.is_file():
            console().print(f"report {name}: file://{path}", markup=False)


def next_step_lines(d: dict[str, Any]) -> list[str]:
    """What to run next for one dataset: finish an interrupted run first (verifying half a
    dataset says nothing about the rest), else the protection's next step; then its failures."""
    from daemon.datasets.folder_count import resume_line

    c, name, lines = d["counts"], d["name"], []
    resume = resume_line(c, d["resume"]) if d.get("resume") else None
    if resume:
        lines.append(f"{name}: {resume}")
    elif d["protection"]["next"]:
        lines.append(f"{name}: {d['protection']['next']}")
    not_patched = [f"{c[k]} {k}" for k in ("failed", "quarantined") if c.get(k, 0)]
    if not_patched:
        lines.append(f"{name}: {', '.join(not_patched)}: ppd status {name} --failed")
    if c.get("waiting"):
        lines.append(f"{name}: {c['waiting']} still being written (incomplete), NOT protected yet: the "
                     "daemon patches each once complete, or quarantines it if it stays so")  # fmt: skip
    if c.get("changed"):  # another size or time than ppd wrote: an original copied back, an edit
        root = shlex.quote(str(d["root"]))
        lines.append(f"{name}: {c['changed']} changed since ppd patched them (size or time), maybe NOT "
                     f"protected now: `ppd poison {root}` checks them and patches what needs it")  # fmt: skip
    if c.get("unprotectable"):  # a reconstruction reads them all the same (a black-box review)
        lines.append(f"{name}: {c['unprotectable']} photo(s) or video(s) in a format ppd cannot protect, "
                     "NOT protected: convert them to JPEG, PNG, TIFF, WebP, HEIC or MP4, or move them "
                     "out")  # fmt: skip
    if d.get("restored_in_place"):  # originals back where they are published: said in the overview
        root = shlex.quote(str(d["root"]))
        lines.append(f"{name}: {d['restored_in_place']} restored by you, NOT protected: "
                     f"`ppd poison {root} --force` patches them again")  # fmt: skip
    lines += _stopped_run_lines(d)
    if d.get("other_spec"):
        lines.append(f"{name}: {d['other_spec']} patched with another spec than the dataset's (a "
                     "re-protect did not finish?): "
                     f"`ppd dataset set {shlex.quote(name)} --reprotect` gives them its spec")  # fmt: skip
    return lines


def _stopped_run_lines(d: dict[str, Any]) -> list[str]:
    """What a `ppd restore` (or poison) killed mid-file left: originals back but not recorded (not
    "changed since patched": they hold the original's bytes), and temporaries that could not be swept."""
    name, lines = d["name"], []
    if restored := d.get("restored_unrecorded"):
        command = f"ppd restore {shlex.quote(restored[0])}" if len(restored) == 1 else "ppd restore"
        them = "it" if len(restored) == 1 else "them"
        lines.append(f"{name}: {len(restored)} restored (a restore was interrupted: run `{command}` again to "
                     f"record {them}), NOT protected")  # fmt: skip
    if temps := d.get("leftover_temps"):
        shown = ", ".join(shlex.quote(t) for t in temps[:3]) + (", ..." if len(temps) > 3 else "")
        lines.append(f"{name}: {len(temps)} hidden temporary file(s) of a stopped ppd run, which ppd could "
                     f"not remove: delete them before the folder is published ({shown})")  # fmt: skip
    return lines


def _print_next_steps(report: list[dict[str, Any]]) -> None:
    """Word-wrapped to the terminal (soft_wrap off): these lines say what to run next."""
    for d in report:
        for line in next_step_lines(d):
            print_line(console(), line)


def _print_regressions(report: list[dict[str, Any]]) -> None:
    for d in report:
        if d["regression"]:
            err_console().print(
                f"[bold red]REGRESSION:[/] dataset {d['name']!r} went from protected to NOT protected "
                f"in its last {d['regression']['profile']!r} verification; its published images "
                "may reconstruct: check `ppd verify` and the spec."
            )


def _print_json(ctx: AppContext, report: list[dict[str, Any]], sync: Any, unclaimed: list[Path]) -> None:
    # --check's answer and reasons, per dataset: a script had to rebuild the rule (a black-box review)
    datasets = [{**d, "not_ready": [] if _gone(d) else unready_reasons(d)} for d in report]
    payload = {
        "outbox": str(ctx.paths.outbox),
        "sync_folder": None if sync is None else {"client": sync.client, "root": str(sync.root)},
        "datasets": datasets,
        "outbox_not_patched": [str(p) for p in unclaimed],  # in the outbox, no dataset's yet
        "ready_to_publish": bool(report) and not unclaimed
        and any(not _gone(d) for d in report) and not any(d["not_ready"] for d in datasets),
    }
    typer.echo(json.dumps(payload, indent=2, default=str))


def _print_report(
    ctx: AppContext, report: list[dict[str, Any]], sync: Any, failed: bool, detailed: bool
) -> None:
    if sync is not None:
        from daemon.watch.syncdirs import sync_warning

        warning(sync_warning(ctx.paths.outbox) or "")
    if failed:
        _print_failed(report)
    else:
        _print_text(ctx, report, detailed=detailed)


def _gone(d: dict[str, Any]) -> bool:
    """A dataset whose folder is gone and that holds no file now (all its rows removed)."""
    return not (d.get("folder") or {}).get("exists", True) and not d["counts"].get("files")


def _print_text(ctx: AppContext, report: list[dict[str, Any]], detailed: bool) -> None:
    from daemon.cli.status_queries import print_running

    if not report:
        console().print(f"no datasets yet; outbox {ctx.paths.outbox}", markup=False)
        return
    gone = [] if detailed else [d for d in report if _gone(d)]
    report = [d for d in report if d not in gone]
    if report:
        console().print(status_table(report, console().width, ctx.paths.outbox))
    if gone:  # a folder renamed or deleted: its old name stayed in the table forever (a black-box review)
        names = ", ".join(d["name"] for d in gone)
        print_line(console(), f"not shown: {len(gone)} dataset(s) whose folder is gone and that hold no "
                              f"file now ({names}); `ppd status NAME` shows one")  # fmt: skip
    if detailed:
        console().print(f"outbox {ctx.paths.outbox}", markup=False)
        for d in report:
            _print_details(d)
    _print_next_steps(report)
    print_running(report)  # issue 30: a verification running now, and how far it has got
    _print_report_links(ctx, [d["name"] for d in report])
    _print_regressions(report)


def status(
    dataset: str | None = typer.Argument(
        None, help="One dataset: its name, its folder or a verification folder (default: all)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
    long: bool = typer.Option(False, "--long", "-l", help="Also the spec and each profile's verdict."),
    failed: bool = typer.Option(False, "--failed", help="List each failed file with its reason."),
    check: bool = typer.Option(
        False, "--check", help="Exit 1 unless every file shown is patched and the verdict is 'protected'."
    ),
) -> None:
    """Each dataset: files patched and failed, and whether it is protected (a verification's
    verdict) or only patched; warns on regressions and on sync folders. Exits 0 (a report) unless
    --check: then 1 when a dataset is not ready to publish, with one line saying why.

    \b
    Examples:
      ppd status                  every dataset, one line each
      ppd status castle           one dataset in detail
      ppd status castle --failed  the files that failed, and why
      ppd status castle --check && publish castle
    """
    from daemon.cli.status_queries import dataset_status, failed_files
    from daemon.cli.targets import TargetError, dataset_or_die
    from daemon.watch.syncdirs import find_sync_folder

    ctx = open_ctx()
    try:
        names = [d["name"] for d in ctx.store.datasets()]
        if dataset is not None:  # a name, a folder or a verification folder ("" refused): one resolver
            say = err_console() if as_json else console()
            try:
                names = [dataset_or_die(ctx.store, dataset, say, "give a dataset (see `ppd status`)")]
            except TargetError as exc:
                in_outbox = ctx.paths.outbox / dataset
                if dataset and "/" not in dataset and in_outbox.is_dir():  # no dataset yet: say so
                    where = shlex.quote(str(in_outbox))
                    raise die(f"{dataset}: a folder of the outbox that ppd has not patched yet, NOT "
                              f"protected: `ppd watch` patches it, or `ppd poison {where}`") from None
                raise die(exc) from None
        report = [dataset_status(ctx, n) for n in names]
        unclaimed = [] if dataset is not None else outbox_unclaimed(ctx)
        if failed:
            for d in report:
                d["failed_files"] = failed_files(ctx, d["name"])
        sync = find_sync_folder(ctx.paths.outbox)
        if as_json:
            _print_json(ctx, report, sync, unclaimed)
        else:
            _print_report(ctx, report, sync, failed, detailed=long or bool(dataset))
            if unclaimed:
                print_line(console(), unclaimed_line(ctx.paths.outbox, unclaimed))
    finally:
        ctx.close()
    _exit_if_unready(report, check, unclaimed)


def unready_reasons(d: dict[str, Any]) -> list[str]:
    """Why a dataset is not ready to publish: files left unprotected, or a verdict other than
    'protected' (patched, not verified included: only a verification says it holds)."""
    from daemon.cli.status_queries import unprotected_files
    from daemon.states import Protection

    reasons = unprotected_files(d)
    if d.get("leftover_temps"):  # a hidden fragment of a photo, published with the folder
        reasons.append(f"{len(d['leftover_temps'])} leftover temporary file(s) of ppd")
    if d.get("other_spec"):  # a mix of marks: the verdict is of the dataset's spec alone
        reasons.append(f"{d['other_spec']} patched with another spec than the dataset's")
    if d["protection"]["state"] != Protection.PROTECTED:
        reasons.append(d["protection"]["text"])
    elif missing := d.get("profiles_not_verified"):
        reasons.append(f"{d['protection']['text']}, not verified under {', '.join(missing)}: "
                       f"`ppd verify {shlex.quote(d['name'])}`")  # fmt: skip
    return reasons


def outbox_unclaimed(ctx: AppContext) -> list[Path]:
    """The outbox's photos and videos no dataset holds yet (daemon.datasets.folder_count)."""
    from daemon.datasets.folder_count import outbox_unclaimed as unclaimed

    found = unclaimed(ctx.paths.outbox, [d["root"] for d in ctx.store.datasets()])
    if not found:
        return []
    # a row names it, by whichever spelling of the outbox it was patched through: some dataset's file
    spellings = {str(ctx.paths.outbox), os.path.realpath(ctx.paths.outbox)}
    named = {os.path.realpath(r["path"]) for where in spellings for r in ctx.store.files_under(where)}
    return [p for p in found if os.path.realpath(p) not in named]


def unclaimed_line(outbox: Path, unclaimed: list[Path]) -> str:
    """One line: how many, which (a few), and what patches them."""
    from daemon.protect.job import shown_path

    real = Path(os.path.realpath(outbox))
    names = [shown_path(p.relative_to(real) if p.is_relative_to(real) else p) for p in unclaimed[:3]]
    more = f", and {len(unclaimed) - 3} more" if len(unclaimed) > 3 else ""
    return (
        f"outbox: {len(unclaimed)} photo(s) or video(s) no dataset holds yet, NOT protected "
        f"({', '.join(names)}{more}): `ppd watch` patches them, or `ppd poison {shlex.quote(str(outbox))}`"
    )


def _exit_if_unready(report: list[dict[str, Any]], check: bool, unclaimed: Sequence[Path] = ()) -> None:
    """--check: one line per dataset not ready to publish (stderr), then exit 1. A dataset whose
    folder is gone and that holds no file now publishes nothing: it is not shown, and not waited for
    (a black-box review: after a folder was renamed, --check could never pass again)."""
    if not check:
        return
    shown = [d for d in report if not _gone(d)]
    unready = [(d["name"], unready_reasons(d)) for d in shown]
    unready = [(name, why) for name, why in unready if why]
    if unclaimed:
        unready.append(("outbox", [f"{len(unclaimed)} photo(s) or video(s) not patched yet"]))
    for name, why in unready:
        err_console().print(f"not ready to publish: {name}: {', '.join(why)}", markup=False, highlight=False)
    if not shown and not unready:  # exit 1 said nothing (a second black-box review): say why
        gone = [f"dataset {d['name']!r}'s folder {d['root']} is gone (moved or deleted?)" for d in report]
        said = "; ".join(gone) or "no dataset yet"
        err_console().print(f"nothing to publish: {said}", markup=False, highlight=False)
    if unready or not shown:
        raise typer.Exit(ExitStatus.FAILED)


def register(app: typer.Typer) -> None:
    app.command("status")(status)
