"""Start-up (issue 19): `ppd poison --help`, `ppd status` and the daemon's command registration
import only what they use. Real `python -X importtime` runs in a subprocess; the check is on the
modules loaded, not on a time (speed is measured in bench/bench_startup.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from testkit.privilege import modes_bind

REPO = Path(__file__).resolve().parents[3]
HEAVY = ("numpy", "PIL", "av", "torch", "pycolmap", "sqlite_utils", "flip_evaluator", "pydantic")


def imported_modules(env: dict[str, str], *args: str) -> set[str]:
    """Every module `python -X importtime -m daemon.cli ARGS` imported (top-level names too)."""
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "daemon.cli", *args],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    names = set()
    for line in proc.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            name = line.rsplit("|", 1)[1].strip()
            names.update({name, name.split(".")[0]})
    assert "daemon.cli.errors" in names, "importtime output not understood"
    return names


@pytest.fixture
def env(ppd_env: dict[str, Path]) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="80")


@pytest.mark.parametrize("command", [["poison", "--help"], ["--help"], ["status", "--help"]])
def test_help_loads_nothing_heavy(env: dict[str, str], command: list[str]) -> None:
    loaded = imported_modules(env, *command)
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))
    assert "daemon.protect.one_file" not in loaded and "poisoner.blend" not in loaded
    assert "rich" not in loaded  # nothing is drawn: the consoles are made on first use


def test_status_loads_no_pixels_and_no_verifier(env: dict[str, str]) -> None:
    loaded = imported_modules(env, "status")
    pixel_and_sfm = {"numpy", "PIL", "av", "torch", "pycolmap", "flip_evaluator", "pydantic"}
    if "sqlite_utils" in loaded:  # the store's connection wrapper imports numpy when present
        pixel_and_sfm.discard("numpy")
    assert not loaded & pixel_and_sfm, sorted(loaded & pixel_and_sfm)
    assert "daemon.protect.one_file" not in loaded and "verifier.verification" not in loaded
    assert "daemon.cli.poison_cmd" not in loaded  # `ppd COMMAND` registers that command only


def test_top_level_help_lists_every_command(env: dict[str, str]) -> None:
    proc = subprocess.run([sys.executable, "-m", "daemon.cli", "--help"], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    from daemon.cli import COMMAND_MODULES

    listed = {line.split()[0] for line in proc.stdout.splitlines() if line.startswith("  ") and line.split()}
    assert set(COMMAND_MODULES) <= listed, set(COMMAND_MODULES) - listed


def test_plain_values_convert_as_typer_does() -> None:
    """The light converter gives typer's answer for what it takes and declines the rest."""
    from daemon.cli.coerce import _NOT_PLAIN, plain_value

    assert plain_value(int, "12") == 12 and plain_value(int, "-3") == -3
    assert plain_value(float, "0.5") == 0.5 and plain_value(float, "2") == 2.0
    assert plain_value(float, 3) == 3.0 and type(plain_value(float, 3)) is float
    assert plain_value(str, "castle") == "castle" and plain_value(bool, True) is True
    assert plain_value(list[str], ("a", "b")) == ["a", "b"]
    for annotation, value in ((int, "1e3"), (int, "x"), (int, 2.5), (int, True), (float, "1e3"),
                              (Path, "a.jpg"), (bool, "yes"), (list[int], ["1"])):  # fmt: skip
        assert plain_value(annotation, value) is _NOT_PLAIN, (annotation, value)
    assert plain_value(int, "0", 1, None) is _NOT_PLAIN  # out of range: typer's error message
    assert plain_value(int, "3", 1, 5) == 3


def test_paths_convert_as_typer_does(tmp_path: Path) -> None:
    """Paths and lists of paths (`ppd poison DATASET`, `--out`, `--subject-masks`) come out as typer's
    own converter gives them; a path option asking typer to check it, or text typer must judge, is
    declined (issue 30: a `ppd poison` run no longer imports pydantic)."""
    from typer._adapters import try_build_adapter
    from typer.models import OptionInfo

    from daemon.cli.coerce import _NOT_PLAIN, plain_path

    shoot = tmp_path / "shoot dir"
    shoot.mkdir()
    (shoot / "a.jpg").write_bytes(b"x")
    info = OptionInfo()
    for annotation, value in ((Path, str(shoot)), (Path, str(shoot / "a.jpg")), (Path, "missing/b.jpg"),
                              (Path, "-"), (list[Path], (str(shoot), "c d.jpg", "~/e"))):  # fmt: skip
        mine = plain_path(annotation, value, info)
        assert mine is not _NOT_PLAIN and mine == try_build_adapter(annotation, info).validate_python(value)
        assert type(mine) is type(try_build_adapter(annotation, info).validate_python(value))
    assert plain_path(Path, str(shoot), OptionInfo(exists=True)) is _NOT_PLAIN
    assert plain_path(Path, str(shoot), OptionInfo(file_okay=False)) is _NOT_PLAIN
    assert plain_path(Path, str(shoot), OptionInfo(resolve_path=True)) is _NOT_PLAIN
    for annotation, value in ((Path, ""), (Path, "a\0b"), (list[Path], ("a", "")), (list[int], ("1",)),
                              (Path, 3), (str, "a")):  # fmt: skip
        assert plain_path(annotation, value, info) is _NOT_PLAIN, (annotation, value)
    for flags in (OptionInfo(exists=True), OptionInfo(readable=False)):  # typer's checks, lists too
        assert plain_path(list[Path], (str(shoot),), flags) is _NOT_PLAIN


def test_an_unreadable_path_keeps_typers_message(env: dict[str, str], tmp_path: Path) -> None:
    """A path that exists but cannot be read goes to typer's converter and its one-line error, given
    alone, in a list of paths or with a trailing slash (typer stats the Path, which drops it)."""
    locked = tmp_path / "locked.jpg"
    locked.write_bytes(b"x")
    locked.chmod(0)
    readable = tmp_path / "fine.jpg"
    readable.write_bytes(b"x")
    prefix = modes_bind()
    for paths in ([str(locked)], [str(readable), str(locked)], [f"{locked}/"]):
        proc = subprocess.run([*prefix, sys.executable, "-m", "daemon.cli", "poison", "--dry-run", *paths],
                              cwd=REPO, env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
        assert proc.returncode == 2, (paths, proc.stderr)
        assert proc.stderr.startswith("ppd: error: ") and "is not readable" in proc.stderr, proc.stderr


def test_bad_values_keep_typers_messages(env: dict[str, str]) -> None:
    """A value the light converter declines reaches typer's own converter and its error."""
    for args, word in ((["poison", "x", "--workers", "0"], "--workers"),
                       (["poison", "x", "--workers", "two"], "--workers"),
                       (["auto", "x", "--sample", "2"], "--sample")):  # fmt: skip
        proc = subprocess.run([sys.executable, "-m", "daemon.cli", *args], cwd=REPO, env=env,
                              capture_output=True, text=True, timeout=120)  # fmt: skip
        assert proc.returncode == 2, (args, proc.stderr)
        assert proc.stderr.startswith("ppd: error: ") and word in proc.stderr, proc.stderr


def test_poison_run_loads_no_scipy_no_sfm_and_no_network_stack(env: dict[str, str], tmp_path: Path) -> None:
    """A real `ppd poison` of two photos (issue 30: its whole-process CPU against the codec floor): the
    scene hint's filters are numpy (no scipy, 0.45 s CPU a process), the provenance marker's XML
    quoting does not pull in urllib/http/ssl, and nothing of the verifier's SfM or GPU stack loads."""
    from PIL import Image

    from testkit.photos import textured

    folder = tmp_path / "shoot"
    folder.mkdir()
    for i in range(2):
        Image.fromarray(textured(240, 320, seed=i)).save(folder / f"IMG_{i}.jpg", quality=90)
    loaded = imported_modules(env, "poison", str(folder))
    assert "poisoner.scene" in loaded and "poisoner.provenance" in loaded  # the hint and marker ran
    unwanted = {"scipy", "ssl", "urllib.request", "http", "pycolmap", "torch", "skimage", "flip_evaluator",
                "pydantic"}  # fmt: skip
    unwanted.add("av")
    assert not loaded & unwanted, sorted(loaded & unwanted)


BLAS_THREADS = """
import contextlib, os, sys
from daemon.cli import app
with contextlib.suppress(SystemExit):
    app(["poison", sys.argv[1], "--workers", "1"], standalone_mode=False)
print("numpy" in sys.modules, len(os.listdir("/proc/self/task")), os.environ.get("OPENBLAS_NUM_THREADS"))
"""


@pytest.mark.skipif((os.cpu_count() or 1) < 2 or not Path("/proc/self/task").is_dir(),
                    reason="OpenBLAS starts no threads of its own on one core; /proc is Linux's")  # fmt: skip
@pytest.mark.parametrize("users", [None, "2"])
def test_poison_runs_numpy_on_one_blas_thread(env: dict[str, str], tmp_path: Path, users: str | None) -> None:
    """`ppd poison` does no BLAS work worth a thread, and OpenBLAS's idle threads spin for CPU at
    numpy's import (bench/results/batch.md round 18): after a real run the process has no thread but
    its own, unless the user set OPENBLAS_NUM_THREADS, which stands."""
    from PIL import Image

    shoot = tmp_path / "shoot"
    shoot.mkdir()
    for i in range(2):
        Image.new("RGB", (320, 240), (40 * i, 90, 160)).save(shoot / f"v{i}.jpg", quality=90)
    env = {k: v for k, v in env.items() if k != "OPENBLAS_NUM_THREADS"}
    if users is not None:
        env["OPENBLAS_NUM_THREADS"] = users
    proc = subprocess.run([sys.executable, "-c", BLAS_THREADS, str(shoot)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    numpy_loaded, threads, setting = proc.stdout.split()[-3:]
    assert numpy_loaded == "True"  # the patch pass ran (numpy is what starts OpenBLAS)
    if users is None:
        assert int(threads) == 1
    else:
        assert int(threads) >= 2  # the user's two threads: the main one and one of OpenBLAS's
    assert setting == (users or "1")
