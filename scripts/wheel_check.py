"""Does a built wheel (and sdist) hold every module and data file of ppd's three packages?

    python scripts/wheel_check.py CHECKOUT WHEEL [SDIST]

Expected: every `*.py` under each folder of daemon/, poisoner/, verifier/ that has an
`__init__.py` (a package), every file pyproject's [tool.setuptools.package-data] names, and each C
source's compiled module (setup.py; the sdist holds the source). Prints
the packages found in the wheel; exit 1 naming each missing file (a package list in pyproject that
misses a subpackage, a data file not declared) and each file of the code ppd's packages never ship
(testkit/, tests/, bench/: the tests' and benchmarks' own). Used by scripts/wheel_smoke.sh and
tests/test_packaging.py.
"""

from __future__ import annotations

import sys
import tarfile
import tomllib
import zipfile
from pathlib import Path

TOP = ("daemon", "poisoner", "verifier")
NOT_SHIPPED = ("testkit/", "tests/", "bench/")  # test and bench code: a checkout's, never the wheel's


def expected_files(root: Path) -> list[str]:
    """Paths relative to the checkout, '/'-separated: every package's modules and declared data."""
    found: list[str] = []
    for top in TOP:
        for init in sorted((root / top).rglob("__init__.py")):
            if "__pycache__" in init.parts:
                continue
            found += [p.relative_to(root).as_posix() for p in sorted(init.parent.glob("*.py"))]
    data = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"].get("package-data", {})
    for package, patterns in data.items():
        base = root / package.replace(".", "/")
        for pattern in patterns:
            matches = sorted(base.glob(pattern))
            if not matches:
                found.append(f"{package.replace('.', '/')}/{pattern}")  # declared, absent: say so
            found += [p.relative_to(root).as_posix() for p in matches]
    return sorted(set(found))


def extension_sources(root: Path) -> list[str]:
    """The C sources of the packages' compiled modules (setup.py builds each into <its name>.*.so)."""
    return sorted(p.relative_to(root).as_posix() for top in TOP for p in (root / top).rglob("*.c"))


def holds_extension(names: set[str], source: str) -> bool:
    """Whether a wheel holds the compiled module of a C source (poisoner/_x.c: poisoner/_x.<tag>.so)."""
    stem = source[: -len(".c")] + "."
    return any(n.startswith(stem) and n.endswith((".so", ".pyd")) for n in names)


def wheel_names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as z:
        return set(z.namelist())


def sdist_names(sdist: Path) -> set[str]:
    """Member names without the leading `patchpoison-X.Y.Z/`."""
    with tarfile.open(sdist) as t:
        return {name.split("/", 1)[1] for name in t.getnames() if "/" in name}


def packages_in(names: set[str]) -> list[str]:
    return sorted(n.rsplit("/", 1)[0].replace("/", ".") for n in names if n.endswith("/__init__.py"))


def main(argv: list[str]) -> int:
    if len(argv) not in (2, 3):
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    root, wheel = Path(argv[0]), Path(argv[1])
    expected = expected_files(root)
    archives = {wheel.name: wheel_names(wheel)}
    if len(argv) == 3:
        archives[Path(argv[2]).name] = sdist_names(Path(argv[2]))
    missing = [f"{name}: {path}" for name, held in archives.items() for path in expected if path not in held]
    for source in extension_sources(root):  # the wheel holds it compiled, the sdist as source
        if not holds_extension(archives[wheel.name], source):
            missing.append(f"{wheel.name}: {source} compiled (no C compiler at build?)")
        sdists = [name for name in archives if name != wheel.name]
        missing += [f"{name}: {source}" for name in sdists if source not in archives[name]]
    extra = sorted(n for n in archives[wheel.name] if n.startswith(NOT_SHIPPED))
    print(f"{wheel.name}: packages " + " ".join(packages_in(archives[wheel.name])))
    for line in missing:
        print(f"missing from {line}", file=sys.stderr)
    for name in extra:
        print(f"not for the wheel: {name}", file=sys.stderr)
    if not missing:
        print(f"every one of {len(expected)} modules and data files is in " + " and ".join(archives))
    return 1 if missing or extra else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
