"""What the daemon counts and says per file: the counts behind the stop summary and systemd's
STATUS= line (one count per file), the one key=value line per file, and the small judgements the
catch-up scan and the retry after a full disk rest on."""

from __future__ import annotations

import errno
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.protect.job import NO_SPACE_WORDS, Outcome, shown_name, shown_path
from daemon.states import NOT_MOVED_PREFIX, REMARKED_PREFIX, STILL_OPEN_PREFIX, FileState
from daemon.watch.workers import PoolStats

log = logging.getLogger("daemon.watch.watcher")  # the daemon's lines keep the logger they always had


@dataclass
class DaemonCounts:
    patched: int = 0
    unchanged: int = 0
    skipped: int = 0
    failed: int = 0
    removed: int = 0
    quarantined: int = 0


def status_line(counts: DaemonCounts, stats: PoolStats, armed: int) -> str:
    """The one-line STATUS= systemd shows in `systemctl --user status ppd`."""
    return (
        f"patched {counts.patched}, failed {counts.failed}, quarantined {counts.quarantined}, "
        f"unchanged {counts.unchanged}, removed {counts.removed}; queued {stats.queued + stats.pending}, "
        f"in flight {stats.in_flight}, settling {armed}"
    )


def say_outcome(event: str, path: Path, outcome: Any, state: str, seconds: float, moved: Path | None) -> None:
    """The daemon's one line per file, on the terminal and in the journal: `msg="patched IMG_1.jpg"
    event=new dataset=kitchen file=/outbox/kitchen/IMG_1.jpg outcome=patched seconds=0.84`, plus
    the reason when it was not patched (or was re-marked: daemon.protect.remark) and where a
    quarantined file went."""
    say(event, path, outcome.dataset, state, seconds, outcome.reason, moved)


def say(
    event: str, path: Path, dataset: str | None, state: str, seconds: float, reason: str | None = None,
    moved: Path | None = None,
) -> None:  # fmt: skip
    """say_outcome's line from its fields (a symlink quarantined has no protect outcome)."""
    failed = state in (Outcome.FAILED, Outcome.QUARANTINED)
    # the name one way in msg, file, to and reason: bytes that are not UTF-8 as \xe9 (shown_name), not
    # caf\udce9 beside the reason's caf\xe9 (a black-box review, F7)
    extra: dict[str, Any] = {"event": event, "dataset": dataset, "file": shown_path(path), "outcome": state,
                             "seconds": round(seconds, 2)}  # fmt: skip
    if reason and reason.startswith(STILL_OPEN_PREFIX):
        reason += "; patched once it is closed"  # its close re-arms the watcher
    if reason and (state != Outcome.PATCHED or reason.startswith(REMARKED_PREFIX)):
        extra["reason"] = reason
    if moved is not None:
        extra["to"] = shown_path(moved)
    log.log(logging.WARNING if failed else logging.INFO, "%s %s", state, shown_name(path), extra=extra)


def say_removed(path: Path, dataset: str | None, reason: str | None = None) -> None:
    """The line for a file gone from the outbox (its row, if any, recorded removed)."""
    extra: dict[str, Any] = {"event": "removed", "dataset": dataset, "file": str(path), "outcome": "removed"}
    if reason:
        extra["reason"] = reason
    log.info("removed %s", path.name, extra=extra)


NO_SPACE_MESSAGES = (
    os.strerror(errno.ENOSPC), os.strerror(errno.EDQUOT), "database or disk is full", NO_SPACE_WORDS
)  # fmt: skip


def is_no_space(reason: str | None) -> bool:
    """Whether a failure's one-line reason says the disk (or quota) was full."""
    return reason is not None and any(m.lower() in reason.lower() for m in NO_SPACE_MESSAGES)


def row_matches_disk(row: dict[str, Any], path: Path) -> bool:
    """A patched row, or a restored one (the user's restore stands), whose recorded size and mtime
    are the file's: nothing to do (but a patched file its publish folder could not take)."""
    if row["state"] not in (FileState.PATCHED, FileState.RESTORED):
        return False
    if row.get("published_path") or row.get("size") is None:
        return False
    if str(row.get("error") or "").startswith(NOT_MOVED_PREFIX):  # patched, its move out failed: again
        return False
    try:
        st = path.stat()
    except OSError:
        return False
    return (st.st_size, st.st_mtime_ns) == (row["size"], row["mtime_ns"])


def is_under(outbox: Path, path_text: str) -> bool:
    return path_text.startswith(str(outbox) + os.sep)
