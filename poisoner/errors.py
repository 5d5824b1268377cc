"""The poisoner's one-line error for a file it cannot poison faithfully; its own module so that
poisoner.limits (header checks) and poisoner.formats (the codecs) both raise it without importing
each other. poisoner.formats re-exports it."""

from __future__ import annotations


class ImageFormatError(Exception):
    """A file that cannot be poisoned faithfully (message: one line)."""


class MarkNotWritten(ImageFormatError):
    """The mark would change no pixel of the file (a keep-out mask covers all of it): the file is
    not protected, so it is a failure, never "patched" (issue 25)."""
