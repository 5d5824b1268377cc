"""The poisoner's one-line error for a file it cannot poison faithfully; its own module so that
poisoner.limits (header checks) and poisoner.formats (the codecs) both raise it without importing
each other. poisoner.formats re-exports it."""

from __future__ import annotations

from enum import IntEnum


class ExitStatus(IntEnum):
    """ppd's exit statuses (the epilog of `ppd --help` lists them). Defined at the lowest layer so
    that every error, wherever it arises, can carry its own."""

    OK = 0
    FAILED = 1  # some files failed, or the verification verdict is not "protected"
    USAGE = 2  # bad input: unknown option, missing file, bad spec value, unknown dataset
    ENVIRONMENT = 3  # ppd cannot work here: folder not writable, disk full, damaged store, lock held
    INTERRUPTED = 130


class PpdError(Exception):
    """The one base of ppd's own errors: a one-line message and the exit status the CLI uses.
    Subclasses are defined where they arise; the CLI catches PpdError once, by type."""

    exit_status: ExitStatus = ExitStatus.USAGE


class ImageFormatError(PpdError):
    """A file that cannot be poisoned faithfully (message: one line)."""

    exit_status = ExitStatus.FAILED


class MarkNotWritten(ImageFormatError):
    """The mark would change no pixel of the file (a keep-out mask covers all of it, or its blocks
    match the photo's pixels where it lands): the file is not protected, so it is a failure, never
    "patched" (issue 25)."""


class SpecError(PpdError, ValueError):
    """A PatchSpec that cannot be built or cannot be placed on an image."""

    exit_status = ExitStatus.USAGE


def one_line(exc: BaseException) -> str:
    """An exception's first line (a decoder's messages can span several)."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
