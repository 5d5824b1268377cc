"""`ppd status [DATASET]`: each dataset's files, whether it is protected (a verification's
verdict) or only patched, what to run next; warnings on regressions and sync folders."""

from __future__ import annotations

import json
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from daemon.cli.errors import die, open_ctx, warning
from daemon.cli.output import console, err_console, print_line
from daemon.cli.status_gone import moved_words, print_gone
from poisoner.errors import ExitStatus
from verifier.verdict import Verdict

if TYPE_CHECKING:
    from rich.table import Table

    from daemon.cli.status_outbox import OutboxAlerts
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


NUMERIC = ("files", "patched", "failed")
DROPPED_FIRST = ("files", "failed", "patched")  # as the terminal narrows, and for a long name
PROTECTION_ROOM = len("patched, not verified")  # on one line, before a count column is shown


def _columns(width: int) -> list[str]:
    """Columns drop as the terminal narrows (files, then failed, then patched)."""
    columns = ["dataset", "files", "patched", "failed", "protection"]
    for column, below in zip(DROPPED_FIRST, (72, 56, 44), strict=True):
        if width < below:
            columns.remove(column)
    return columns


def print_status_rows(report: list[dict[str, Any]], width: int) -> None:
    """The table, or, where a dataset's name cannot be whole in it, each dataset as a list."""
    columns = _fitting_columns(report, width)
    if columns is None:
        _print_status_list(report)
    else:
        console().print(status_table(report, columns))


def _fitting_columns(report: list[dict[str, Any]], width: int) -> list[str] | None:
    """The table's columns at this width with every dataset name whole on one line: the name goes
    before the counts (they drop first), and None when it cannot be whole even beside the protection
    words alone. Folded inside its column, between the borders and the protection words, a name could
    not be copied, nor told from a similar one (a black-box review at 30 to 80 columns)."""
    from rich.cells import cell_len
    from rich.text import Text

    columns = _columns(width)
    name = max(cell_len(text) for text in ["dataset", *(d["name"] for d in report)])
    while True:
        cells = [_row_cells(d, columns) for d in report]
        plain = [Text.from_markup(c["protection"]).plain for c in cells]
        words = max(cell_len(word) for word in ["protection", *" ".join(plain).split()])  # each kept whole
        protection = max(words, min(PROTECTION_ROOM, max(cell_len(text) for text in plain)))
        counts = sum(max(len(k), *(len(c[k]) for c in cells)) for k in columns if k in NUMERIC)
        if name + protection + counts + 3 * len(columns) + 1 <= width:  # a cell's padding and border: 3
            return columns
        shown = [k for k in DROPPED_FIRST if k in columns]
        if not shown:
            return None
        columns.remove(shown[0])


def status_table(report: list[dict[str, Any]], columns: list[str]) -> Table:
    """One row per dataset; the dataset name whole (_fitting_columns), the protection words wrapped."""
    from rich.table import Table

    table = Table(expand=False)
    for column in columns:
        numeric = column in NUMERIC
        table.add_column(
            column, justify="right" if numeric else "left", overflow="fold",
            no_wrap=column != "protection", min_width=len(column) if numeric else None,
        )  # fmt: skip
    for d in report:
        cells = _row_cells(d, columns)
        table.add_row(*(cells[k] for k in columns))
    return table


def _print_status_list(report: list[dict[str, Any]]) -> None:
    """Each dataset's name on a line of its own, never broken (a terminal narrower than the name wraps
    it, and a copy of it is whole), then its protection words indented, wrapped at spaces."""
    from rich.padding import Padding
    from rich.text import Text

    for d in report:
        console().print(d["name"], markup=False)
        words = Text.from_markup(_row_cells(d, ["dataset", "protection"])["protection"])
        console().print(Padding(words, (0, 0, 0, 2), expand=False), soft_wrap=False)


def _row_cells(d: dict[str, Any], columns: list[str]) -> dict[str, str]:
    """One dataset's cells (rich markup); a count not in `columns` that matters joins the protection."""
    from rich.markup import escape

    from daemon.datasets.folder_count import not_patched_yet
    from daemon.states import Protection

    c = d["counts"]
    cells = {
        "dataset": escape(d["name"]),  # a name's own brackets are not rich's markup
        "files": str(c["files"]),
        "patched": str(d["patched"]),
        "failed": str(c.get("failed", 0)),
        "protection": _protection_cell(d),
    }
    unmarked = d["protection"].get("unmarked")  # the text leads with them: "NOT protected: 1 failed; ..."
    if (todo := not_patched_yet(c)) and not unmarked:  # "patched, not verified" read as done with 5 of 25
        if d["protection"]["state"] == Protection.PATCHED_NOT_VERIFIED:  # patched (a review)
            cells["protection"] = f"[yellow]{d['patched']} of {c['files']} patched, not verified[/]"
        else:
            cells["protection"] += f"; [bold yellow]{todo} not patched yet[/]"
    if "failed" not in columns and c.get("failed") and not unmarked:  # a narrow terminal shows a failure
        cells["protection"] += f"; [bold red]{c['failed']} failed[/]"
    if c.get("not_moved"):  # patched, but the publish folder never got them
        cells["protection"] += f"; [bold red]{c['not_moved']} not moved to the publish folder[/]"
    return cells


# What a count key is called in the details line ("untracked": files in the folder without a row).
COUNT_WORDS = {
    "untracked": "not patched yet", "changed": "changed since patched", "waiting": "still being written",
    "gone": "deleted or moved away since patched", "unprotectable": "in a format ppd cannot protect",
    "removed": "deleted or moved away earlier",  # a row ppd recorded so: a renamed file's old name too
    "restored_unrecorded": "holding the original again", "not_utf8": "named in bytes that are not UTF-8",
    "unpatched_names": "under names ppd does not patch", "linked": "in symlinked folders ppd does not follow",
    "sealed": "carrying ppd's mark with no record (their dataset forgotten?)",
    # a run killed mid-file: the next run finishes it ("pending" was never explained: a review, F15)
    "pending": "interrupted mid-patch",
}  # fmt: skip
NOT_MOVED_WORDS = "NOT moved to the publish folder: still in the outbox"
# Counts that are no part of "files": files no longer there (their rows history), files of a format ppd
# cannot patch; "renamed" is a part of "patched"
NOT_COUNTED = ("gone", "removed", "unprotectable", "unpatched_names", "linked")


def files_line(counts: dict[str, Any]) -> str:
    """`files 23: not patched yet 17, patched 6; not counted: removed 2`: every count of the dataset,
    once; the parts before ';' add up to the files (they added up to more: a black-box review)."""
    parts = _count_words({k: n for k, n in counts.items() if k not in NOT_COUNTED})
    others = _count_words({k: n for k, n in counts.items() if k in NOT_COUNTED})
    if counts.get("renamed") and "patched" in parts:
        parts["patched"] = f"{parts['patched']} ({counts['renamed']} renamed since)"
    if counts.get("not_moved") and "patched" in parts:  # patched, their move to the publish folder failed
        parts["patched"] = f"{parts['patched']} ({counts['not_moved']} {NOT_MOVED_WORDS})"
    line = f"files {counts['files']}"
    if parts:
        line += ": " + ", ".join(f"{k} {n}" for k, n in sorted(parts.items()))
    if others:
        line += "; not counted: " + ", ".join(f"{k} {n}" for k, n in sorted(others.items()))
    return line


def _count_words(counts: dict[str, Any]) -> dict[str, str]:
    """{word: count} of the counts but "files", "renamed" and "not_moved" (parts of patched), states of
    one word summed."""
    from collections import Counter

    from daemon.states import state_word

    words: Counter[str] = Counter()
    for key, n in counts.items():
        if key not in ("files", "renamed", "not_moved") and n:
            words[COUNT_WORDS.get(key) or state_word(key)] += n
    return {k: str(n) for k, n in words.items()}


def place_lines(d: dict[str, Any]) -> list[str]:
    """Where the dataset is: its folder (said when it is gone), where `--out` put its copies and
    where published files go."""
    folder = d.get("folder") or {}
    lines = []
    if folder and not folder.get("exists", True):
        lines.append(f"folder {d['root']} is gone; counts are the store's: {moved_words(d)}")
    elif folder.get("moved_to"):  # left empty: a running `ppd watch` made the outbox it watched again
        lines.append(f"folder {d['root']} holds none of its files now: {moved_words(d)}")
    if folder.get("copies"):
        lines.append(f"patched copies in {folder['copies']}")
    if d["publish_dir"]:
        lines.append(f"publish to {d['publish_dir']}")
    return lines


def _print_details(d: dict[str, Any]) -> None:
    """--long (or one dataset): where it is, the spec, each profile's verdict."""
    out = console()
    out.print(f"[bold]{d['name']}[/]  {d['root']}")
    spec = f"spec {d['spec_lost']}: not recovered" if d.get("spec_lost") else None  # its line below says more
    lines = [files_line(d["counts"]), spec or f"spec {d['spec_id'] or '-'}: {d['spec_summary'] or '-'}"]
    if d["auto"]:
        lines.append(d["auto"])
    lines += place_lines(d)
    lines += d.get("mark_notes") or []
    lines += [d["sealed_line"]] if d.get("sealed_line") else []  # ppd's output no row names
    for line in lines:
        print_line(out, "  " + line)
    for profile, v in d["verdicts"].items():
        out.print("  " + verdict_text(profile, v), soft_wrap=False)
    if d.get("not_measured"):
        print_line(out, "  " + not_measured_phrase(d["not_measured"]))
    if not d["verdicts"]:
        print_line(out, "  " + unverified_line(d.get("last_verification")))


def not_measured_phrase(names: Sequence[str]) -> str:
    """The photos no verdict covers: the verification's COLMAP did not read them."""
    shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    return f"{len(names)} photo(s) no verification measured ({shown}): COLMAP did not read them"


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
    head = f"{d['name']}: {c.get('failed', 0)} failed, {c.get('quarantined', 0)} quarantined"
    if d.get("not_reprotected"):  # patched, a re-protect failed on them: not failed files
        head += f", {d['not_reprotected']} not re-protected"
    if c.get("not_moved"):  # patched, not moved to the publish folder: not failed files either
        head += f", {c['not_moved']} not moved to the publish folder"
    if c.get("not_utf8"):  # refused by every run, no row: named from the folder (F7)
        head += f", {c['not_utf8']} named in bytes that are not UTF-8"
    from daemon.protect.job import shown_path

    lines = [head] + not_utf8_lines(d)
    for r in rows:
        mark = " (quarantined)" if r.get("state") == "quarantined" else ""
        if mark and r.get("moved_to"):
            mark = f" (quarantined: moved to {shown_path(Path(r['moved_to']))})"
        shown = r.get("source") or r["path"]  # --out: the file that failed, not the copy never written
        lines.append(f"  {shown_path(Path(shown))}: {r['reason']}{mark}")  # a newline in a name: escaped
    return lines


def not_utf8_lines(d: dict[str, Any]) -> list[str]:
    """--failed's lines for the files whose names are not UTF-8, which no row names: in the folder, and
    moved to the quarantine folder by the daemon (it said "0 quarantined" and named neither: F7)."""
    from daemon.protect.job import shown_path

    why = "the file name is not valid UTF-8 (ppd records names as UTF-8)"
    lines = [f"  {shown_path(Path(p))}: {why}: rename it to protect it" for p in d.get("not_utf8_files", [])]
    return lines + [f"  {shown_path(Path(p))}: {why}: rename it and move it back into the outbox "
                    "(quarantined)" for p in d.get("quarantined_not_utf8", [])]  # fmt: skip


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


def _print_regressions(report: list[dict[str, Any]]) -> None:
    for d in report:
        if d["regression"]:
            err_console().print(
                f"[bold red]REGRESSION:[/] dataset {d['name']!r} went from protected to NOT protected "
                f"in its last {d['regression']['profile']!r} verification; its published images "
                "may reconstruct: check `ppd verify` and the spec."
            )


def _outbox_not_patched(outbox: Path, report: list[dict[str, Any]], unclaimed: list[Path]) -> list[str]:
    """The outbox's files no dataset holds, and its datasets' files not patched yet."""
    held = [f for d in report for f in d.get("not_patched_files", []) if Path(f).is_relative_to(outbox)]
    return sorted({*map(str, unclaimed), *held})


def _print_json(ctx: AppContext, report: list[dict[str, Any]], sync: Any, alerts: OutboxAlerts) -> None:
    # --check's answer and reasons, per dataset: a script had to rebuild the rule (a black-box review)
    datasets = [{**d, "not_ready": [] if _gone(d) else unready_reasons(d)} for d in report]
    payload = {
        "outbox": str(ctx.paths.outbox),
        "sync_folder": None if sync is None else {"client": sync.client, "root": str(sync.root)},
        "datasets": datasets,
        # every photo in the outbox not patched yet: of no dataset, or of one (a script read [] as a
        # clean outbox while the "default" dataset had a new photo: a black-box review); sorted
        "outbox_not_patched": _outbox_not_patched(ctx.paths.outbox, report, alerts.unclaimed),
        **alerts.to_json(ctx),  # the outbox's own findings (daemon.cli.status_outbox)
        "ready_to_publish": bool(report) and not alerts.unready()
        and any(not _gone(d) for d in report) and not any(d["not_ready"] for d in datasets),
    }
    typer.echo(json.dumps(payload, indent=2, default=str))


def _print_report(
    ctx: AppContext, report: list[dict[str, Any]], sync: Any, failed: bool, detailed: bool
) -> None:
    if sync is not None:
        from daemon.watch.syncdirs import sync_warning

        warning(sync_warning(ctx.paths.outbox) or "")
    from daemon.cli.config_warnings import status_warnings

    for line in status_warnings(ctx, [d["name"] for d in report]):  # a mask folder gone, a misspelt table
        warning(line)
    if failed:
        _print_failed(report)
    else:
        _print_text(ctx, report, detailed=detailed)


def _gone(d: dict[str, Any]) -> bool:
    """A dataset whose folder is gone (moved or deleted), or left empty with its files seen moved, and
    none of whose files is at its path now; the files may be elsewhere (a folder renamed, the outbox
    moved), which ppd sees beside the old folder and where the outbox's rule puts it now."""
    folder = d.get("folder") or {}
    left = not folder.get("exists", True) or bool(folder.get("moved_to"))
    return left and not d["counts"].get("files")


def _print_text(ctx: AppContext, report: list[dict[str, Any]], detailed: bool) -> None:
    from daemon.cli.status_queries import print_running
    from daemon.cli.status_steps import print_next_steps

    if not report:
        console().print(f"no datasets yet; outbox {ctx.paths.outbox}", markup=False)
        return
    gone = [] if detailed else [d for d in report if _gone(d)]
    report = [d for d in report if d not in gone]
    if report:
        print_status_rows(report, console().width)
    if gone:  # a folder renamed or deleted: its old name stayed in the table forever (a black-box review)
        print_gone(gone, ctx.paths.outbox)
    if detailed:
        console().print(f"outbox {ctx.paths.outbox}", markup=False)
        for d in report:
            _print_details(d)
    print_next_steps(report)
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
    from daemon.cli.status_outbox import outbox_alerts, outbox_folder_said
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
                if not outbox_folder_said(ctx, dataset, as_json):  # a folder of the outbox: said so
                    raise die(exc) from None
                return
        report = [dataset_status(ctx, n) for n in names]
        # a moved dataset's patched files (the outbox moved): said with it, not "NOT protected" (F2)
        alerts = outbox_alerts(ctx, names, whole=dataset is None, report=report)
        if failed:
            for d in report:
                d["failed_files"] = failed_files(ctx, d["name"])
        sync = find_sync_folder(ctx.paths.outbox)
        if as_json:
            _print_json(ctx, report, sync, alerts)
        else:
            _print_report(ctx, report, sync, failed, detailed=long or bool(dataset))
            for line in alerts.lines(ctx):
                print_line(console(), line)
    finally:
        ctx.close()
    _exit_if_unready(report, check, alerts.unready())


def unready_reasons(d: dict[str, Any]) -> list[str]:
    """Why a dataset is not ready to publish: files left unprotected, or a verdict other than
    'protected' (patched, not verified included: only a verification says it holds)."""
    from daemon.cli.status_queries import unprotected_files
    from daemon.states import Protection

    reasons = unprotected_files(d)
    if n := d["counts"].get("not_moved"):  # patched, never published: the publish folder lacks them
        reasons.append(f"{n} patched but {NOT_MOVED_WORDS}")
    if d.get("leftover_temps"):  # a hidden fragment of a photo, published with the folder
        reasons.append(f"{len(d['leftover_temps'])} leftover temporary file(s) of ppd")
    if d.get("other_spec"):  # a mix of marks: the verdict is of the dataset's spec alone
        reasons.append(f"{d['other_spec']} patched with another spec than the dataset's")
    if d.get("not_measured"):
        reasons.append(not_measured_phrase(d["not_measured"]))
    measured = d["protection"]["patched_files"]  # the files left unmarked are named above
    if measured["state"] != Protection.PROTECTED:
        reasons.append(measured["text"])
    elif missing := d.get("profiles_not_verified"):
        reasons.append(f"{measured['text']}, not verified under {', '.join(missing)}: "
                       f"`ppd verify {shlex.quote(d['name'])}`")  # fmt: skip
    return reasons


def _exit_if_unready(report: list[dict[str, Any]], check: bool, outbox: Sequence[str] = ()) -> None:
    """--check: one line per dataset not ready to publish (stderr), then exit 1. A dataset whose
    folder is gone and that holds no file now publishes nothing: it is not shown, and not waited for
    (a black-box review: after a folder was renamed, --check could never pass again)."""
    if not check:
        return
    shown = [d for d in report if not _gone(d)]
    unready = [(d["name"], unready_reasons(d)) for d in shown]
    unready = [(name, why) for name, why in unready if why]
    unready += [("outbox", [why]) for why in outbox]  # the outbox's own (daemon.cli.status_outbox)
    for name, why in unready:
        err_console().print(f"not ready to publish: {name}: {', '.join(why)}", markup=False, highlight=False)
    if not shown and not unready:  # exit 1 said nothing (a second black-box review): say why
        gone = [f"the folder of dataset {d['name']!r}, {d['root']}, is gone ({moved_words(d)})"
                for d in report]  # fmt: skip
        said = "; ".join(gone) or "no dataset yet"
        err_console().print(f"nothing to publish: {said}", markup=False, highlight=False)
    if unready or not shown:
        raise typer.Exit(ExitStatus.FAILED)


def register(app: typer.Typer) -> None:
    app.command("status")(status)
