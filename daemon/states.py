"""The one vocabulary of states: what the store records per file and what a user is told per dataset.

A file ppd has written its mark into is *patched*; whether that protects anything is a dataset-level
question that only a verification verdict answers. "Protected" is never said of a file.
"""

from __future__ import annotations

from enum import StrEnum


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
