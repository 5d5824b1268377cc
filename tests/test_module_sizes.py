"""Issue 27: no module of the product, the shared test helpers or the benchmarks over 600 lines (a
module that grows past it is split by what its parts do, as placement.py's display orientation was)."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LIMIT = 600
PACKAGES = ("daemon", "poisoner", "verifier", "testkit", "bench")


def test_no_module_is_over_the_limit() -> None:
    sizes = {
        str(path.relative_to(REPO)): len(path.read_text(encoding="utf-8").splitlines())
        for package in PACKAGES
        for path in (REPO / package).rglob("*.py")
    }
    assert len(sizes) > 100  # the packages were found (a wrong root would pass vacuously)
    assert {name: n for name, n in sizes.items() if n > LIMIT} == {}
