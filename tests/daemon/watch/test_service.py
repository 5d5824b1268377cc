"""The systemd user unit: rendered with this installation's real paths, checked by the real
`systemd-analyze verify`, installed/removed by the real `ppd service` commands."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from daemon.config import Config
from daemon.paths import AppPaths
from daemon.watch.service import (
    UNIT_NAME,
    generic_layout,
    installed_layout,
    quote_word,
    render_unit,
    unit_dir,
    watch_command,
)

REPO = Path(__file__).resolve().parents[3]
SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(SYSTEMD_ANALYZE is None, reason="systemd-analyze is not installed")


def unit_settings(text: str) -> dict[str, list[str]]:
    settings: dict[str, list[str]] = {}
    for line in text.splitlines():
        if line and not line.startswith(("#", "[")) and "=" in line:
            key, value = line.split("=", 1)
            settings.setdefault(key, []).append(value)
    return settings


def analyze_verify(unit: Path, home: Path) -> str:
    """`systemd-analyze --user verify`; returns what it printed (empty when the unit is clean)."""
    # the machine's other user units put sockets under the runtime dir: a short private one keeps their
    # paths under the 107-byte AF_UNIX limit whatever temp path the suite runs under
    runtime = tempfile.mkdtemp(prefix="ppd-rt-", dir="/tmp" if os.path.isdir("/tmp") else None)
    env = {**os.environ, "HOME": str(home), "XDG_RUNTIME_DIR": runtime}
    try:
        proc = subprocess.run([SYSTEMD_ANALYZE, "--user", "verify", str(unit)],
                              capture_output=True, text=True, env=env, timeout=60)  # fmt: skip
    finally:
        shutil.rmtree(runtime, ignore_errors=True)
    output = (proc.stdout + proc.stderr).strip()
    assert proc.returncode == 0 or output, "systemd-analyze failed silently"
    return output if proc.returncode == 0 else f"rc={proc.returncode}: {output}"


def render_installed(ppd_env: dict[str, Path], tmp_path: Path) -> Path:
    paths = AppPaths.from_env()
    config = Config.from_toml('publish_dir = "/srv/ppd published"\n')
    unit = tmp_path / "render" / UNIT_NAME
    unit.parent.mkdir()
    unit.write_text(render_unit(installed_layout(paths, config)))
    return unit


@needs_analyze
def test_installed_unit_passes_systemd_analyze_verify(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    unit = render_installed(ppd_env, tmp_path)
    assert analyze_verify(unit, tmp_path) == ""
    settings = unit_settings(unit.read_text())
    argv, _ = watch_command()
    assert Path(argv[0]).is_absolute() and Path(argv[0]).exists()
    assert settings["ExecStart"] == [" ".join(quote_word(w) for w in argv)]
    assert settings["Type"] == ["notify"] and settings["Restart"] == ["on-failure"]
    assert settings["RestartPreventExitStatus"] == ["2 3"]  # a missing key is not retried every 5 s
    assert "WatchdogSec" in settings and settings["RestrictAddressFamilies"] == ["AF_UNIX"]
    read_write = settings["ReadWritePaths"][0]
    for folder in (ppd_env["outbox"], ppd_env["data"]):
        assert str(folder) in read_write
    assert '"-/srv/ppd published"' in read_write  # optional folder, quoted for its space
    outbox = ppd_env["outbox"]
    assert f"Environment={quote_word(f'PPD_OUTBOX={outbox}')}" in unit.read_text()
    assert "MemoryDenyWriteExecute" not in settings  # torch's JIT dies under it (docs/DAEMON.md)


@needs_analyze
def test_systemd_analyze_catches_a_broken_unit(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The check above can fail: an unknown key or a missing binary is reported."""
    unit = render_installed(ppd_env, tmp_path)
    text = unit.read_text().replace("LockPersonality=yes", "LockPersonality=yes\nNoSuchSetting=1")
    unit.write_text(text)
    assert "NoSuchSetting" in analyze_verify(unit, tmp_path)


@needs_analyze
def test_repository_unit_is_the_generic_render_and_verifies(tmp_path: Path) -> None:
    shipped = (REPO / "systemd" / UNIT_NAME).read_text()
    assert shipped == render_unit(generic_layout())
    # %h/.local/bin/ppd must exist for verify: a home with the real ppd linked there.
    bin_dir = tmp_path / ".local" / "bin"
    bin_dir.mkdir(parents=True)
    argv, _ = watch_command()
    (bin_dir / "ppd").symlink_to(argv[0] if argv[1] == "watch" else sys.executable)
    unit = tmp_path / "unit" / UNIT_NAME
    unit.parent.mkdir()
    unit.write_text(shipped)
    assert analyze_verify(unit, tmp_path) == ""


@pytest.mark.parametrize(
    "word, expected",
    [
        ("/usr/bin/ppd", "/usr/bin/ppd"),
        ("/home/a/PPD Outbox", '"/home/a/PPD Outbox"'),
        ('/x/say "hi"', '"/x/say \\"hi\\""'),
        ("/x/100%", "/x/100%%"),
        ("%h/.local/bin/ppd", "%h/.local/bin/ppd"),
    ],
)
def test_quote_word(word: str, expected: str) -> None:
    assert quote_word(word) == expected


def test_unit_dir_respects_xdg_config_home(tmp_path: Path) -> None:
    assert unit_dir({"XDG_CONFIG_HOME": str(tmp_path)}) == tmp_path / "systemd" / "user"
    assert unit_dir({}) == Path.home() / ".config" / "systemd" / "user"


def _ppd(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    exe = Path(sys.executable).parent / "ppd"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "daemon.cli"]
    return subprocess.run([*cmd, *args], capture_output=True, text=True, env=env, cwd=REPO, timeout=60)


def test_service_install_status_uninstall(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The real commands, with whatever systemctl this machine has (no user bus is tolerated)."""
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "xdg")}
    installed = _ppd("service", "install", "--no-start", env=env)
    assert installed.returncode == 0, installed.stderr
    unit = tmp_path / "xdg" / "systemd" / "user" / UNIT_NAME
    assert unit.is_file()
    assert f"PPD_OUTBOX={ppd_env['outbox']}" in unit.read_text()
    # the daemon's quarantine is writable under ProtectSystem=strict, and exists (the sandbox cannot
    # make it): before, a broken file stayed in the outbox ("Read-only file system", a black-box review)
    quarantine = ppd_env["outbox"].parent / "ppd-quarantine"
    assert quarantine.is_dir() and (quarantine.stat().st_mode & 0o777) == 0o700
    assert quote_word(f"-{quarantine}") in unit_settings(unit.read_text())["ReadWritePaths"][0]
    status = _ppd("service", "status", env=env)
    assert "installed" in status.stderr and "not installed" not in status.stderr
    removed = _ppd("service", "uninstall", env=env)
    assert removed.returncode == 0 and not unit.exists()
    again = _ppd("service", "uninstall", env=env)
    assert "was not installed" in again.stderr


def test_a_program_under_tmp_is_warned_of_like_the_folders() -> None:
    """A fifth black-box review: `ppd service install` from a venv under /tmp warned of the outbox,
    data and cache there (PrivateTmp hides them from the service) but not of ExecStart's ppd itself."""
    from daemon.watch.service import UnitLayout, temporary_folders

    home = Path.home() / "x"
    layout = UnitLayout(exec_start=["/tmp/rev/venv/bin/ppd", "watch"], read_write=[str(home), f"-{home}/p"])
    assert temporary_folders(layout) == ["/tmp/rev/venv/bin/ppd"]
    python = UnitLayout(exec_start=["/var/tmp/v/bin/python", "-m", "daemon.cli", "watch"],
                        read_write=["/tmp/o"])  # fmt: skip
    assert temporary_folders(python) == ["/var/tmp/v/bin/python", "/tmp/o"]
    assert temporary_folders(UnitLayout(exec_start=["/usr/bin/ppd", "watch"], read_write=[str(home)])) == []
    # the config folder, in Environment= only: the service ran on its defaults (a seventh review)
    config = UnitLayout(exec_start=["/usr/bin/ppd", "watch"], read_write=[str(home)],
                        environment={"PPD_CONFIG_DIR": "/tmp/h/config", "PYTHONUNBUFFERED": "1"})  # fmt: skip
    assert temporary_folders(config) == ["/tmp/h/config"]


def test_service_install_print_writes_nothing(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    xdg = tmp_path / "xdg"
    env = {**os.environ, "XDG_CONFIG_HOME": str(xdg)}
    printed = _ppd("service", "install", "--print", env=env)
    assert printed.returncode == 0, printed.stderr
    assert "[Service]" in printed.stdout and f"PPD_OUTBOX={ppd_env['outbox']}" in printed.stdout
    assert not xdg.exists()  # nothing written
    assert not (ppd_env["outbox"].parent / "ppd-quarantine").exists()
    in_tmp = any(ppd_env["outbox"].is_relative_to(t) for t in ("/tmp", "/var/tmp"))
    assert (
        "under a temporary folder, which the service cannot see" in " ".join(printed.stderr.split())
    ) == in_tmp
    shown = _ppd("service", "install", "--help", env=env)
    assert "$XDG_CONFIG_HOME" in shown.stdout and "".join(str(xdg).split()) in "".join(shown.stdout.split())
    plain = _ppd("service", "install", "--help", env={k: v for k, v in env.items() if k != "XDG_CONFIG_HOME"})
    assert "~/.config/systemd/user" in plain.stdout


@needs_analyze
def test_the_unit_lists_every_datasets_own_publish_folder(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A black-box review (s5 F3): a dataset's own publish folder (`ppd dataset set NAME --publish-dir`,
    kept in the store) was not in ReadWritePaths=, so under ProtectSystem=strict the daemon could not
    move a patched file there. Now `ppd service install` lists it (read from the store, `--print` too),
    and `dataset set --publish-dir` says to install again while the unit installed lacks a folder."""
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "xdg"), "PYTHONPATH": str(REPO)}  # this checkout
    pub2, pub3 = tmp_path / "sites" / "beach 2", tmp_path / "sites" / "lake"
    (ppd_env["config"] / "config.toml").write_text(f'publish_dir = "{tmp_path / "pub"}"\n')
    for name in ("beach", "lake"):  # a new dataset needs its folder (a seventh black-box review, F4)
        (ppd_env["outbox"] / name).mkdir()
    first = _ppd("dataset", "set", "beach", "--publish-dir", str(pub2), env=env)
    assert first.returncode == 0 and "service install" not in first.stdout, first.stdout  # none installed
    printed = _ppd("service", "install", "--print", env=env)
    assert quote_word(f"-{pub2}") in unit_settings(printed.stdout)["ReadWritePaths"][0]
    assert _ppd("service", "install", "--no-start", env=env).returncode == 0
    unit = tmp_path / "xdg" / "systemd" / "user" / UNIT_NAME
    read_write = unit_settings(unit.read_text())["ReadWritePaths"][0]
    assert quote_word(f"-{pub2}") in read_write and f"-{tmp_path / 'pub'} " in f"{read_write} "
    assert analyze_verify(unit, tmp_path) == ""
    inside = _ppd("dataset", "set", "lake", env=env)  # publish_dir/lake: under a listed folder
    assert inside.returncode == 0 and "-/" + str(tmp_path / "pub" / "lake") not in _ppd(
        "service", "install", "--print", env=env).stdout  # fmt: skip
    same = _ppd("dataset", "set", "beach", "--publish-dir", str(pub2), env=env)
    assert same.returncode == 0 and "service install" not in same.stdout
    moved = _ppd("dataset", "set", "beach", "--publish-dir", str(pub3), env=env)
    assert moved.returncode == 0 and moved.stdout.splitlines()[1] == (
        "ppd.service cannot write there yet: run `ppd service install` again"
    )
