"""ppd as an installed package (issue 26): the wheel holds every package and data file, one
version source, the private typer and watchdog behaviour ppd relies on is still there (the upper
bounds in pyproject.toml say which releases were checked), and no product code reads a path of
the repository. The full install-and-run check is scripts/wheel_smoke.sh (CI, .ci/run)."""

from __future__ import annotations

import inspect
import re
import shutil
import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path

from packaging.requirements import Requirement

REPO = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())


def _requirement(name: str) -> Requirement:
    reqs = [Requirement(r) for r in PYPROJECT["project"]["dependencies"]]
    return next(r for r in reqs if r.name == name)


def test_the_wheel_holds_every_package_and_data_file(tmp_path: Path) -> None:
    """A real build (setuptools, no isolation: no download) of a copy of the sources, checked by
    the script CI uses; a `packages = [...]` list that misses daemon/cli, or a discovery that takes
    testkit (the tests' and benchmarks' helpers) in, fails here."""
    src = tmp_path / "src"
    skip = shutil.ignore_patterns("__pycache__", "*.pyc", "*.so")  # the build compiles its own
    for top in ("daemon", "poisoner", "verifier", "testkit"):  # testkit: found by discovery, yet not shipped
        shutil.copytree(REPO / top, src / top, ignore=skip)
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy(REPO / name, src / name)
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-v", "--no-deps", "--no-build-isolation", "-w", str(tmp_path),
         "."],
        cwd=src, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-2000:]
    said = built.stdout + built.stderr  # -v: the backend's own warnings
    assert "Building wheel" in said and "`project.license` as a TOML table is deprecated" not in said
    (wheel,) = tmp_path.glob("patchpoison-*.whl")
    checked = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "wheel_check.py"), str(REPO), str(wheel)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert checked.returncode == 0, checked.stderr
    for package in ("daemon.cli", "daemon.store", "poisoner.image", "poisoner.video", "verifier.splat"):
        assert f" {package}" in checked.stdout
    import zipfile

    with zipfile.ZipFile(wheel) as z:
        assert "daemon/ppd.service.in" in z.namelist()
        # the bit-level JPEG splice, compiled (wheel_check names it too): without it ppd runs, slower
        assert any(n.startswith("poisoner/_jpeg_entropy.") and n.endswith(".so") for n in z.namelist())
        # and the scene hint's filter (else the hint takes its numpy loop, slower)
        assert any(n.startswith("poisoner/_scene_filter.") and n.endswith(".so") for n in z.namelist())
        entry = z.read(next(n for n in z.namelist() if n.endswith("entry_points.txt"))).decode()
    assert "ppd = daemon.cli:app" in entry


def test_one_version_source_the_package_metadata() -> None:
    from daemon.protect.job import tool_version
    from daemon.version import ppd_version

    assert ppd_version() == version("patchpoison") == PYPROJECT["project"]["version"]
    assert tool_version() == f"ppd {ppd_version()}"
    done = subprocess.run([sys.executable, "-m", "daemon.cli", "--version"], capture_output=True, text=True)
    assert done.stdout.strip() == f"ppd {version('patchpoison')}"
    number = re.escape(PYPROJECT["project"]["version"])
    for top in ("daemon", "poisoner", "verifier"):
        for path in (REPO / top).rglob("*.py"):  # no copy of the number to drift
            assert not re.search(rf'__version__|"ppd {number}"', path.read_text()), path


def test_typer_private_apis_ppd_patches_are_there() -> None:
    """daemon/cli/coerce.py replaces typer's pydantic converter for plain values, and does nothing
    (silently) when typer's internals moved: this catches that, and the bound in pyproject says
    which typer releases were checked."""
    typer_req = _requirement("typer")
    assert any(s.operator == "<" for s in typer_req.specifier), "typer needs an upper bound"
    assert version("typer") in typer_req.specifier
    from typer._coercion import RuntimeParam, build_runtime_param  # noqa: F401
    from typer.core import _TyperParameter

    from daemon.cli import coerce, group

    assert callable(_TyperParameter.get_runtime_param)
    assert {"parameter_info", "annotation"} <= set(inspect.signature(RuntimeParam).parameters)
    coerce.install()
    assert getattr(_TyperParameter, "_ppd_plain", False), "coerce.install() found no typer internals to patch"
    import typer._click.exceptions as typer_click

    assert group.UsageError is typer_click.UsageError  # the exceptions typer raises, not click's
    from typer.testing import CliRunner

    from daemon.cli import app

    shown = CliRunner().invoke(app, ["poison", "--workers", "x"])  # typer's own converter still answers
    assert shown.exit_code == 2 and "--workers" in shown.output


def test_watchdog_inotify_api_ppd_hooks_is_there() -> None:
    """daemon/platform/linux.py learns of an inotify queue overflow from the event itself: it
    subclasses watchdog's InotifyFD (handle_event, InotifyEvent.is_queue_overflow) and builds the
    observer as InotifyObserver does; a release that renames these breaks rescans."""
    watchdog_req = _requirement("watchdog")
    assert any(s.operator == "<" for s in watchdog_req.specifier), "watchdog needs an upper bound"
    assert version("watchdog") in watchdog_req.specifier
    from watchdog.observers.inotify import InotifyFullEmitter, InotifyObserver
    from watchdog.observers.inotify_c import InotifyConstants, InotifyEvent, InotifyFD

    assert "generate_full_events" in inspect.signature(InotifyObserver).parameters
    assert "inotify_fd" in inspect.signature(InotifyFullEmitter).parameters
    assert list(inspect.signature(InotifyFD.handle_event).parameters) == ["self", "event"]
    overflow = InotifyEvent(-1, InotifyConstants.IN_Q_OVERFLOW, 0, b"")
    assert overflow.is_queue_overflow
    assert "_inotify_fd" in inspect.getsource(InotifyObserver.__init__)


def test_no_product_code_reads_a_path_of_the_repository() -> None:
    """The installed package has no checkout beside it: no `Path(__file__)...parents` walk, no
    ../shared, no docs/ or pyproject read. verifier/childenv.py locates the package itself."""
    offenders = []
    for top in ("daemon", "poisoner", "verifier"):
        for path in (REPO / top).rglob("*.py"):
            rel = path.relative_to(REPO).as_posix()
            text = path.read_text()
            if rel != "verifier/childenv.py" and "Path(__file__)" in text:
                offenders.append(f"{rel}: Path(__file__)")
            if re.search(r'["/]shared["/]|pyproject\.toml"|"docs"', text):
                offenders.append(f"{rel}: a repository path")
    assert not offenders, offenders


def test_a_child_imports_the_same_ppd_as_its_parent() -> None:
    """From a source tree (this run), the tree goes first on the child's PYTHONPATH; the child
    module then imports from it, whatever the working folder."""
    from verifier.childenv import child_env, import_root

    env = child_env({"PYTHONPATH": "/elsewhere"})
    assert env["PYTHONPATH"].split(":") == [str(REPO), "/elsewhere"] and import_root() == REPO
    done = subprocess.run(
        [sys.executable, "-c", "import daemon.protect.child as m; print(m.__file__)"],
        env=child_env({}), cwd="/", capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.stdout.strip() == str(REPO / "daemon" / "protect" / "child.py"), done.stderr
