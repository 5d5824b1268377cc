"""What `ppd status` says of the outbox as a whole, beside each dataset's row: the photos no dataset holds
yet (ppd's output among them, whose dataset was forgotten, told apart), those under names ppd does not
patch, those behind symlinked folders ppd does not follow, and the files that failed because the vault
reached its size limit: each one line, each a reason for `--check` (but ppd's output: it carries the
mark), each a key of `--json`.

Light at import (`ppd status` loads it).
"""

from __future__ import annotations

import os
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.datasets.linked_folders import LinkedFolder
from daemon.datasets.sealed_files import Sealed

if TYPE_CHECKING:
    from daemon.context import AppContext


@dataclass(frozen=True)
class VaultFull:
    """Files that failed because keeping their original would pass [vault] max_bytes."""

    failed: list[str]  # their paths
    used: int  # the vault's bytes now
    limit_then: int  # the limit they failed on (the one the daemon read at its start)
    limit_now: int  # the config's now (0: none)
    smallest: int  # the smallest of them, in bytes: whether the vault has room again

    @property
    def raised(self) -> bool:
        """The config's limit is no longer the one they failed on: a running `ppd watch` still has that."""
        return self.limit_now != self.limit_then

    @property
    def room(self) -> bool:
        """Room again under the limit they failed on (a shoot forgotten since)."""
        return self.used + self.smallest <= self.limit_then


@dataclass(frozen=True)
class OutboxAlerts:
    """The outbox's findings: unclaimed (not patched yet), misnamed, sealed, linked, vault."""

    unclaimed: list[Path] = field(default_factory=list)  # of no dataset, not patched yet
    misnamed: list[Path] = field(default_factory=list)  # under names ppd does not patch
    sealed: Sealed = field(default_factory=Sealed)  # of no dataset, ppd's output (its dataset forgotten)
    linked: list[LinkedFolder] = field(default_factory=list)  # symlinked folders of no dataset
    vault: VaultFull | None = None

    def unready(self) -> list[str]:
        """`--check`'s reasons, for "outbox"."""
        from daemon.datasets.unpatched_names import WORDS

        reasons = []
        if self.unclaimed:
            reasons.append(f"{len(self.unclaimed)} photo(s) or video(s) not patched yet")
        if self.misnamed:
            reasons.append(f"{len(self.misnamed)} photo(s) or video(s) {WORDS}")
        if photos := sum(link.photos for link in self.linked):
            reasons.append(f"{photos} photo(s) or video(s) in symlinked folders ppd does not follow")
        return reasons

    def lines(self, ctx: AppContext) -> list[str]:
        """The lines under the table, each whole (print_line wraps them at spaces)."""
        from daemon.cli.linked_lines import linked_status_line
        from daemon.datasets.sealed_files import sealed_phrase
        from daemon.datasets.unpatched_names import unpatched_line

        outbox = ctx.paths.outbox
        lines = [unclaimed_line(outbox, self.unclaimed)] if self.unclaimed else []
        if self.misnamed:
            lines.append(f"outbox: {unpatched_line(self.misnamed, 'the outbox')}")
        if self.sealed:
            lines.append(f"outbox: {sealed_phrase(self.sealed)} ({_names(outbox, self.sealed.files)})")
        if linked := linked_status_line(self.linked, Path(os.path.realpath(outbox))):
            lines.append(f"outbox: {linked}")
        if self.vault is not None:
            lines.append(vault_line(self.vault, ctx.paths.config_file))
        return lines

    def to_json(self, ctx: AppContext) -> dict[str, Any]:
        vault = self.vault
        return {
            # every photo of the outbox's no dataset holds, not patched yet: ppd's output left out
            "outbox_no_dataset": [str(p) for p in self.unclaimed],
            # in no dataset's folder, under names ppd does not patch (a hidden folder of the outbox's)
            "outbox_unpatched_names": [str(p) for p in self.misnamed],
            # of no dataset, ppd's output: its seal verifies (its dataset forgotten, or the store lost)
            "outbox_sealed": self.sealed.to_dict(),
            "outbox_linked_folders": [link.to_dict() for link in self.linked if link.photos],
            "vault_full": None if vault is None else {
                "failed": vault.failed, "used_bytes": vault.used, "limit_bytes": vault.limit_then,
                "config_limit_bytes": vault.limit_now, "config_file": str(ctx.paths.config_file),
            },
        }  # fmt: skip


def outbox_alerts(
    ctx: AppContext, names: list[str], whole: bool, report: list[dict[str, Any]] | None = None
) -> OutboxAlerts:
    """The outbox's findings for these datasets; whole: the whole outbox (not one dataset's status).
    report: the datasets' status, whose folders seen moved (the outbox moved) claim their patched files
    (daemon.cli.status_gone.followed_files): said with the dataset, not as "NOT protected"."""
    from daemon.cli.status_gone import followed_files
    from daemon.datasets.sealed_files import split_sealed

    vault = vault_full(ctx, names)
    if not whole:
        return OutboxAlerts(vault=vault)
    unclaimed = followed_files(ctx, report or [], outbox_unclaimed(ctx))
    unclaimed, sealed = split_sealed(unclaimed, ctx.paths.data_dir, ctx.paths.vault_dir)
    return OutboxAlerts(unclaimed, outbox_unpatched_names(ctx), sealed, outbox_linked(ctx), vault)


def outbox_folder_said(ctx: AppContext, name: str, as_json: bool) -> bool:
    """`ppd status NAME` of a folder of the outbox no dataset holds: False when there is none. Exit 2
    while it holds files not patched yet; else (ppd's output only: its dataset forgotten) one line, or
    --json's object, and exit 0 (it said "NOT protected" of marked files for good: a black-box review)."""
    from daemon.cli.errors import die
    from daemon.datasets.folder_count import folder_media
    from daemon.datasets.sealed_files import sealed_phrase, split_sealed

    folder = ctx.paths.outbox / name
    if not name or "/" in name or not folder.is_dir():
        return False
    rest, sealed = split_sealed(folder_media(folder), ctx.paths.data_dir, ctx.paths.vault_dir)
    if rest or not sealed:
        raise die(f"{name}: a folder of the outbox that ppd has not patched yet, NOT protected: `ppd watch` "
                  f"patches it, or `ppd poison {shlex.quote(str(folder))}`")  # fmt: skip
    if as_json:
        import json

        import typer

        typer.echo(json.dumps({"folder": str(folder), "dataset": None, "outbox_sealed": sealed.to_dict()}))
    else:
        from daemon.cli.output import console, print_line

        print_line(console(), f"{name}: a folder of the outbox no dataset holds: {sealed_phrase(sealed)}")
    return True


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


def outbox_unpatched_names(ctx: AppContext) -> list[Path]:
    """The outbox's photos under names ppd does not patch that no dataset counts (its hidden and
    unclaimed folders: daemon.datasets.unpatched_names), ppd's own folders left out."""
    from daemon.datasets.unpatched_names import outbox_unpatched

    own = [ctx.paths.data_dir, ctx.paths.cache_dir]
    return outbox_unpatched(ctx.paths.outbox, [d["root"] for d in ctx.store.datasets()], own)


def outbox_linked(ctx: AppContext) -> list[LinkedFolder]:
    """The outbox's symlinked folders no dataset counts: right in it (a "dataset" that is a link), and in
    its folders of no dataset; not hidden ones, nor links into the outbox (its files are counted there)."""
    from daemon.datasets.linked_folders import linked_folders_under

    box = Path(os.path.realpath(ctx.paths.outbox))
    if not box.is_dir():
        return []
    known = {Path(os.path.realpath(d["root"])) for d in ctx.store.datasets()}
    inside = [k for k in known if k != box and k.is_relative_to(box)]
    return linked_folders_under(box, [*inside, ctx.paths.data_dir, ctx.paths.cache_dir], own=[box])


def unclaimed_line(outbox: Path, unclaimed: list[Path]) -> str:
    """One line: how many, which (a few), and what patches them."""
    return (
        f"outbox: {len(unclaimed)} photo(s) or video(s) no dataset holds yet, NOT protected "
        f"({_names(outbox, unclaimed)}): `ppd watch` patches them, or `ppd poison {shlex.quote(str(outbox))}`"
    )


def _names(outbox: Path, paths: list[Path]) -> str:
    """The first three, from the outbox, then how many more."""
    from daemon.protect.job import shown_path

    real = Path(os.path.realpath(outbox))
    names = [shown_path(p.relative_to(real) if p.is_relative_to(real) else p) for p in paths[:3]]
    return ", ".join(names) + (f", and {len(paths) - 3} more" if len(paths) > 3 else "")


# the limit a file failed on, in its row's error (daemon.store.vault.limit_message)
_LIMIT = re.compile(r"(\d+)")


def vault_full(ctx: AppContext, names: list[str]) -> VaultFull | None:
    """The datasets' files that failed on the vault's size limit, with the vault's use and limits; None
    when none did. The vault is measured only then (a stat per original)."""
    from daemon.states import FileState
    from daemon.store.vault import LIMIT_WORDS

    failed, limits = [], []
    for name in names:
        for row in ctx.store.files(name, state=FileState.FAILED):
            error = str(row.get("error") or "")
            if LIMIT_WORDS in error and (limit := _LIMIT.match(error.split(LIMIT_WORDS, 1)[1].strip())):
                failed.append(row["path"])
                limits.append(int(limit.group(1)))
    if not failed:
        return None
    smallest = min((st.st_size for p in failed if (st := _stat(p)) is not None), default=0)
    return VaultFull(failed, ctx.vault.usage_bytes(), max(limits), ctx.config.vault.max_bytes, smallest)


def _stat(path: str) -> os.stat_result | None:
    try:
        return os.stat(path)
    except OSError:
        return None


def vault_line(full: VaultFull, config_file: Path) -> str:
    """ONE line for every file that failed on the limit (one per dataset said "3 failed", never why: a
    black-box review), with the whole way out. In bytes, as max_bytes is written."""
    left = f"{len(full.failed)} photo(s) or video(s) failed on it, NOT protected"
    restart = "restart ppd watch (`systemctl --user restart ppd` for the service)"
    if full.raised:  # changed in the config since: a running daemon still has the limit of its start
        now = f"{full.limit_now} bytes" if full.limit_now else "no limit"
        return (f"vault limit reached ({full.used} of {full.limit_then} bytes used): {left}; {config_file} "
                f"now says {now}: {restart}, which reads it at its start and patches them")  # fmt: skip
    if full.room:  # room made since (a shoot forgotten): a running daemon does not retry them on its own
        return (f"vault limit reached earlier ({full.used} of {full.limit_then} bytes used now): {left}: "
                f"{restart}, which retries them at its start")  # fmt: skip
    return (f"vault full: {full.used} of {full.limit_then} bytes used; {left}: raise [vault] max_bytes in "
            f"{config_file} and {restart}, or `ppd dataset forget` a finished shoot")  # fmt: skip
