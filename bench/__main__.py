"""Run every benchmark: `python -m bench [NAME ...]` (names without the `bench_` prefix).

Each bench module is a script with a `main()` that measures and writes its Markdown table to
bench/results/NAME.md. Benchmarks are where speed and memory are measured; the test suite
never times anything.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
import time
from pathlib import Path


def main(argv: list[str]) -> int:
    here = Path(__file__).parent
    names = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))
    wanted = [f"bench_{n.removeprefix('bench_')}" for n in argv] or names
    failed = []
    for name in wanted:
        if name not in names:
            print(f"bench: no benchmark {name!r} (have: {', '.join(names)})", file=sys.stderr)
            return 2
        started = time.monotonic()
        print(f"== {name}", flush=True)
        try:
            importlib.import_module(f"bench.{name}").main()
        except Exception as exc:  # one failing benchmark must not hide the others' figures
            print(f"!! {name} failed: {exc!r}", file=sys.stderr)
            failed.append(name)
        print(f"== {name} took {time.monotonic() - started:.0f} s", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
