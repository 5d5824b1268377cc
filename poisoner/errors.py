"""The poisoner's one-line error for a file it cannot poison faithfully; its own module so that
poisoner.limits (header checks) and poisoner.formats (the codecs) both raise it without importing
each other. poisoner.formats re-exports it."""

from __future__ import annotations


class ImageFormatError(Exception):
    """A file that cannot be poisoned faithfully (message: one line)."""
