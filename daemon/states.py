"""The one vocabulary of states: what the store records per file and what a user is told per dataset.

A file ppd has written its mark into is *patched*; whether that protects anything is a dataset-level
question that only a verification verdict answers. "Protected" is never said of a file.
"""

from __future__ import annotations

import shlex
from collections.abc import Iterable, Mapping
from enum import StrEnum
from pathlib import Path
from typing import Any

from verifier.verdict import NOT_PROTECTED as _VERDICT_NOT_PROTECTED
from verifier.verdict import PROTECTED as _VERDICT_PROTECTED
from verifier.verdict import SFM_CRASHED as _VERDICT_SFM_CRASHED
from verifier.verdict import VERDICT_WORDS as VERDICT_WORDS  # re-exported: the verifier's words
from verifier.verdict import WEAK as _VERDICT_WEAK
from verifier.verdict import headline
from verifier.verdict import verdict_words as verdict_words


class FileState(StrEnum):
    """One file's row in the store."""

    PENDING = "pending"  # original kept in the vault; the patched file may or may not be in place yet
    PATCHED = "patched"  # the mark is in the file (stores before schema 4 said "protected"; migrated)
    SKIPPED = "skipped"  # left as it is (the spec's ratio did not select it)
    FAILED = "failed"  # could not be patched; the row's error says why
    RESTORED = "restored"  # the user asked for the original back
    REMOVED = "removed"  # gone from disk (deleted or moved away)
    QUARANTINED = "quarantined"  # could not be patched and was moved out of the outbox; error says why


class Protection(StrEnum):
    """A dataset's protection as the user reads it (CLI, status, --json, report)."""

    PATCHED_NOT_VERIFIED = "patched, not verified"
    PROTECTED = "protected"  # always shown with the profiles it holds under
    WEAK = "weak"
    NOT_PROTECTED = "NOT protected"
    UNVERIFIABLE = "could not be verified"
    NOTHING_PATCHED = "nothing patched"


# A skipped row's error while the daemon waits for a file's writer (an incomplete file): `ppd status`
# counts these apart, as "still being written", not as skipped by the spec's ratio.
WAITING_PREFIX = "incomplete, waiting for its writer"
STILL_OPEN_PREFIX = "still open for writing"  # a file another process writes: skipped, not patched
# A patched row's error when its move to the publish folder failed (daemon.protect.publishing): the file
# is patched but still in the outbox; `ppd status` counts these apart ("not moved to the publish folder").
NOT_MOVED_PREFIX = "patched, but not moved to"
# a photo or video in a format ppd does not write (GIF, BMP, raw): skipped, named as not protected
UNPROTECTED_PREFIX = "not protected"
# a symlinked sub-folder of a dataset: ppd never follows a symlink inside one, so its photos stay as they are
LINKED_FOLDER_PREFIX = "symlinked folder, not followed"
# ppd's output moved or copied in from a dataset of another spec, patched again with this one's
# (daemon.protect.remark): the daemon's line says it, as it says no other patched file's note
REMARKED_PREFIX = "re-marked with this dataset's spec"
# ... or a file of the dataset's own that carried an earlier spec of it (a re-protect or re-mark stopped)
EARLIER_SPEC_WORDS = "it carried an earlier spec of this dataset"

# The value a store row holds for a patched file (older stores said "protected"; the store's
# migration renamed them, so no other spelling reaches this code).
PATCHED_VALUES = frozenset({FileState.PATCHED.value})

def state_word(state: str) -> str:
    """A store row's state as the user reads it."""
    return "patched" if state in PATCHED_VALUES else state


def patched_count(store_counts: Mapping[str, int]) -> int:
    """Files whose mark is in place, from Store.counts()."""
    return sum(int(store_counts.get(value, 0)) for value in PATCHED_VALUES)


def newest_per_profile(runs: Iterable[Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    """The newest run of each profile (runs newest first, as the store lists them): what a verdict
    rests on. The newest run alone would hide a masked failure behind a later default pass."""
    newest: dict[str, Mapping[str, Any]] = {}
    for run in runs:
        newest.setdefault(run["profile"], run)
    return newest


# Folder counts (daemon.datasets.folder_count) of files a verification did not measure.
UNVERIFIED_FILES = ("changed", "restored_unrecorded", "untracked", "waiting", "not_utf8")


def run_left_out(run: Mapping[str, Any]) -> list[str]:
    """The photos a verification run's COLMAP did not read (its verdict does not cover them):
    a summarised run's "left_out", or a Store row's metrics'."""
    return list(run.get("left_out") or (run.get("metrics") or {}).get("left_out") or ())


def left_out_photos(latest_runs_by_profile: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The photos some headline profile's newest run did not measure, in name order."""
    counted = headline(dict.fromkeys(latest_runs_by_profile, ""))
    return sorted({n for p in counted for n in run_left_out(latest_runs_by_profile[p])})


def dataset_protection(
    store_counts: Mapping[str, int], latest_runs_by_profile: Mapping[str, Mapping[str, Any]]
) -> tuple[Protection, list[str]]:
    """What a user may be told about a dataset, and under which verification profiles it holds.

    store_counts is Store.counts(dataset); latest_runs_by_profile maps each profile to its newest
    verification run (a mapping with a "verdict"). The weakest profile decides: one NOT protected
    profile makes the dataset NOT protected, whatever the others say. The profiles returned are
    the ones the state is about (those that failed, or those it holds under). Only the headline
    profiles count (verifier.verdict.headline): `masked` is reported on its own line.
    """
    if patched_count(store_counts) == 0:
        return Protection.NOTHING_PATCHED, []
    verdicts = headline({p: str(run.get("verdict") or "") for p, run in latest_runs_by_profile.items()})
    if not verdicts:
        return Protection.PATCHED_NOT_VERIFIED, []
    # files the verification never saw: changed since patched, new, still being written (the folder's
    # counts, daemon.datasets.folder_count): a verdict that holds is not today's (a black-box review:
    # an original copied back still read "protected"); one that does not hold still warns
    unseen = any(int(store_counts.get(k, 0)) for k in UNVERIFIED_FILES)
    # photos COLMAP never read (verifier.sfm_images): "protected" would be said of them too
    short = sorted(p for p in verdicts if run_left_out(latest_runs_by_profile[p]))
    for verdict, protection in (
        (_VERDICT_NOT_PROTECTED, Protection.NOT_PROTECTED),
        (_VERDICT_WEAK, Protection.WEAK),
        (_VERDICT_PROTECTED, Protection.PROTECTED),
    ):
        profiles = sorted(p for p, v in verdicts.items() if v == verdict)
        if profiles and unseen and protection in (Protection.PROTECTED, Protection.WEAK):
            return Protection.PATCHED_NOT_VERIFIED, []
        crashed = sorted(p for p, v in verdicts.items() if v == _VERDICT_SFM_CRASHED)
        if profiles and protection is Protection.PROTECTED and crashed:
            # as verifier.verdict.overall: a crash is no protection, so the set is not called protected
            return Protection.UNVERIFIABLE, crashed
        if profiles and protection is Protection.PROTECTED and short:
            return Protection.UNVERIFIABLE, short  # as VerificationReport.verdict
        if profiles:
            return protection, profiles
    return Protection.UNVERIFIABLE, sorted(verdicts)


def protection_text(protection: Protection, profiles: list[str]) -> str:
    """One phrase: "protected under default, hardened", "NOT protected (hardened)", ..."""
    if protection is Protection.PROTECTED:
        return f"protected under {', '.join(profiles)}"
    if profiles and protection in (Protection.NOT_PROTECTED, Protection.WEAK, Protection.UNVERIFIABLE):
        return f"{protection.value} ({', '.join(profiles)})"
    return protection.value


# The states a verification decided: its verdict on the dataset's patched files.
VERIFIED_STATES = frozenset(
    {Protection.PROTECTED, Protection.WEAK, Protection.NOT_PROTECTED, Protection.UNVERIFIABLE}
)


def unmarked_text(unmarked: str, patched: str, measured: str) -> str:
    """`NOT protected: 1 failed, unmarked: a.tif; the 7 patched: protected under default`: a dataset
    with files left without the mark, whatever a verification measured on its patched ones."""
    return f"NOT protected: {unmarked}; {patched}: {measured}"


def unmarked_decide(protection: Protection, unmarked: list[str]) -> bool:
    """Whether files left without the mark make the dataset NOT protected whatever its verdict: any
    such file, once a verification decided (before, the state says no verdict already)."""
    return bool(unmarked) and protection in VERIFIED_STATES


def published_protection(
    protection: Protection, profiles: list[str], unmarked: list[str], patched: int
) -> tuple[Protection, list[str], str]:
    """(state, profiles, text) of the dataset as it is published. A verification measures the patched
    files only: its verdict is the dataset's while none of its files is left without the mark
    (unmarked: daemon.datasets.folder_count.unprotected_phrases, what `ppd status --check` names);
    otherwise NOT protected, and why (a black-box review: "protected", exit 0, with an unmarked photo
    in the folder that is published)."""
    text = protection_text(protection, profiles)
    if not unmarked_decide(protection, unmarked):
        return protection, profiles, text
    return Protection.NOT_PROTECTED, [], unmarked_text(", ".join(unmarked), f"the {patched} patched", text)


def next_step(protection: Protection, dataset: str) -> str | None:
    """The command that moves a dataset's state on, said after `ppd poison` and in `ppd status`."""
    if protection is Protection.PATCHED_NOT_VERIFIED:
        return f"run `ppd verify {shlex.quote(dataset)}`"
    if protection in (Protection.NOT_PROTECTED, Protection.WEAK):
        return f"find a design that holds: `ppd auto {shlex.quote(dataset)}`"
    if protection is Protection.UNVERIFIABLE:
        return f"see `ppd report {shlex.quote(dataset)}`"
    return None


def storable(path: Path) -> bool:
    """Whether the store can record this path: SQLite text is UTF-8, and a name with bytes
    that are not UTF-8 (surrogate-escaped by Python) cannot be written to it."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True
