"""`ppd verify`'s progress on a terminal: per profile, the stage, how far, elapsed and an estimate
(verifier.progress reads them from the SfM children's logs). Quiet when stderr is not a terminal."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from daemon.cli.output import interactive

if TYPE_CHECKING:
    from rich.console import Console

    from verifier.progress import BoardState


def board_text(state: BoardState, now: float | None = None) -> str:
    """The lines shown while a verification runs: a heading, then one line per profile."""
    from verifier.progress import profile_words

    now = time.time() if now is None else now
    lines = [f"verifying {state.label}, {now - state.started_at:.0f} s"]
    lines += [f"  {p.profile:<9} {profile_words(p, now)}" for p in state.profiles]
    return "\n".join(lines)


@contextlib.contextmanager
def progress_display(console: Console, label: str) -> Iterator[Callable[[BoardState], None] | None]:
    """Yields the callback a verification reports its progress to (None when nobody watches: no
    terminal); on a terminal the lines are redrawn in place (rich Live) and cleared at the end."""
    if not interactive():
        yield None
        return
    from rich.live import Live
    from rich.text import Text

    with Live(Text(f"verifying {label}…"), console=console, transient=True, refresh_per_second=2) as live:
        yield lambda state: live.update(Text(board_text(state)))
