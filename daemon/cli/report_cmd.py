"""`ppd report DATASET|FOLDER`: a self-contained HTML report (verdict, reasons, history,
metrics, camera paths, a preview of the patch)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from daemon.cli.errors import die, one_line, refuse_missing_folder
from daemon.cli.options import dataset_option, folder_option
from daemon.cli.output import console
from poisoner.errors import PpdError

if TYPE_CHECKING:
    from daemon.context import AppContext


def _open_store(source: str | None, dataset: str | None) -> AppContext | None:
    """ppd's store, or None when it cannot be opened and a folder can still have its report."""
    import sqlite3

    from daemon.context import AppContext

    try:
        return AppContext.open()
    except (PpdError, OSError, sqlite3.Error) as exc:  # no store: folders still have reports
        if dataset is not None or (source is not None and not Path(source).expanduser().is_dir()):
            raise die(f"ppd's store cannot be opened: {one_line(exc)}") from None
        return None


def _write(ctx: AppContext | None, source: str | None, dataset: str | None, folder: Path | None,
           out: Path | None) -> Path:  # fmt: skip
    from daemon.cli.targets import resolve_target, say_note
    from daemon.verification.dataset_report import build_dataset_report, build_report, report_path
    from verifier.html_report import write_report

    if ctx is not None:
        chosen = resolve_target(ctx.store, source, dataset=dataset, folder=folder)
        say_note(chosen, console())
        name, path = chosen.dataset, chosen.folder
    else:
        name, path = None, (folder or Path(source or ".")).expanduser()
    if name is not None:  # the dataset, never its folder read as a verification folder
        assert ctx is not None
        return write_report(build_dataset_report(ctx, name), out or report_path(ctx.paths, name))
    assert path is not None
    return write_report(build_report(str(path)), out or path / "report.html")


def report(
    source: str | None = typer.Argument(
        None, help="A dataset, the folder `ppd poison` patched, or a verification/experiment folder."
    ),
    dataset: str | None = dataset_option("Report this dataset (explicit form)."),
    folder: Path | None = folder_option("Report this folder (explicit form)."),
    out: Path | None = typer.Option(None, "--out", help="HTML file (default: the dataset's latest.html)."),
) -> None:
    """Write a self-contained HTML report: verdict, reasons, history, metrics, camera paths,
    a preview of the patch. It shows a clean original beside the patched photo: keep it to
    yourself, never publish it with the photos.

    \b
    Examples:
      ppd report castle                a dataset
      ppd report ~/shoots/castle       the folder `ppd poison` patched
      ppd report runs/exp1 --out r.html
    """
    from daemon.cli.targets import TargetError
    from verifier.html_report import ReportError

    if out is not None:  # the default is ppd's own folder or the one reported on: there
        refuse_missing_folder(out)
        _refuse_published(out)
    try:
        ctx = _open_store(source, dataset)
        try:
            written = _write(ctx, source, dataset, folder, out)
        finally:
            if ctx is not None:
                ctx.close()
    except (ReportError, TargetError, OSError, ValueError) as exc:
        raise die(one_line(exc)) from None
    console().print(f"report written: {written}  (file://{written.resolve()})", markup=False)


def register(app: typer.Typer) -> None:
    app.command("report")(report)


def _refuse_published(out: Path) -> None:
    """The page shows a clean original: never written among what is published (as `ppd preview`'s
    picture; a privacy review found nothing saying the report was not for sharing)."""
    from daemon.cli.published import published_folder_holding
    from daemon.paths import AppPaths

    if (published := published_folder_holding(out, AppPaths.from_env())) is not None:
        raise die(f"{out} is inside {published}; the report shows an original and would be published with "
                  "the photos: write it elsewhere (or leave out --out)")  # fmt: skip
