"""Bytecode for the trees a start-up or whole-process bench times, compiled before the first run.

A pip install compiles its modules once. A checkout or a `git archive` tree without __pycache__,
run with PYTHONDONTWRITEBYTECODE set (as in this workplace's shells), compiles every module it
imports from source in each run: 0.1-0.3 s of CPU for `ppd poison`, more for the side that imports
more, which a creator's install never pays (bench/results/batch.md, round 9)."""

from __future__ import annotations

import compileall
from pathlib import Path

PACKAGES = ("daemon", "poisoner", "verifier", "bench", "testkit")


def compile_bytecode(trees: list[Path]) -> None:
    """Each tree's packages compiled to __pycache__ (py_compile writes them whatever the
    environment says)."""
    for tree in trees:
        for package in PACKAGES:
            if (tree / package).is_dir():
                compileall.compile_dir(tree / package, quiet=1)
