"""Results pages in bench/results/: the measured part is rewritten, the hand-written analysis below
ANALYSIS_MARKER is kept."""

from __future__ import annotations

from pathlib import Path

ANALYSIS_MARKER = "<!-- analysis below is kept across rewrites -->"


def rewrite_keeping_analysis(path: Path, lines: list[str]) -> None:
    old = path.read_text() if path.exists() else ""
    tail = old[old.index(ANALYSIS_MARKER) :] if ANALYSIS_MARKER in old else ANALYSIS_MARKER + "\n"
    path.write_text("\n".join(lines) + "\n\n" + tail)
