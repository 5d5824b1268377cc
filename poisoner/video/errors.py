"""The video poisoner's one-line error; its own module so that catching it (daemon.protect.stages)
imports neither PyAV nor numpy."""

from __future__ import annotations

from poisoner.errors import ExitStatus, PpdError


class VideoFormatError(PpdError):
    """A video that cannot be poisoned; the message is one clear line."""

    exit_status = ExitStatus.FAILED


def one_line(exc: BaseException) -> str:
    """An exception's message folded onto one line (FFmpeg's messages span several). An FFmpeg error
    is its words alone: "[Errno 1094995529] Invalid data ...: '<a scratch path>'" named an internal
    file and a number no creator can use (a second black-box review)."""
    words = getattr(exc, "strerror", None) if type(exc).__module__ == "av.error" else None
    return " ".join(str(words or exc).split()) or type(exc).__name__
