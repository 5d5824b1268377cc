"""The video poisoner's one-line error; its own module so that catching it (daemon.protect.stages)
imports neither PyAV nor numpy."""

from __future__ import annotations

from poisoner.errors import ExitStatus, PpdError


class VideoFormatError(PpdError):
    """A video that cannot be poisoned; the message is one clear line."""

    exit_status = ExitStatus.FAILED


def one_line(exc: BaseException) -> str:
    """An exception's message folded onto one line (FFmpeg's messages span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__
