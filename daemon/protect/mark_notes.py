"""The lines that say where marks found no plain place (issue 25: never silent): one wording for
`ppd poison`'s summary (this run's files), `ppd status` and `ppd report` (the dataset's patched files,
from the store), so a creator who lets the daemon work sees there what `ppd poison` would print."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable

# per-file notes of a patched file whose mark found no free place (daemon.protect.job.place_note)
NOT_FREE = {
    "mark on the subject: no plain region": "mark on the subject in {n} photo{s}: no plain region",
    "mark partly on the subject mask (left unwritten there): no free region":
        "mark partly on the subject mask in {n} photo{s} (left unwritten there): no free region",
}  # fmt: skip


def mark_note_lines(notes: Iterable[str | None]) -> list[str]:
    """Counted lines for the per-file notes of patched files ("mark on the subject in 2 photos: no
    plain region", "mark shrunk in 3 photos ..."); none for files whose mark found a free place."""
    from poisoner.mark_place import SHRUNK  # here, not at start-up: it loads numpy

    given = [n or "" for n in notes]
    counts = Counter(n for n in given if n in NOT_FREE)
    lines = [NOT_FREE[r].format(n=n, s="" if n == 1 else "s") for r, n in sorted(counts.items()) if r]
    shrunk = sum(n.startswith(SHRUNK) for n in given)  # round 3: squares cropped to fit a plain place
    if shrunk:
        s = "" if shrunk == 1 else "s"
        lines.append(f"{SHRUNK} in {shrunk} photo{s} (its squares cropped): no plain place held it whole")
    return lines
