"""The installation's seal key (issue 29): created once, atomically, 0600 whatever the umask;
refused when others can read it; moved to a new machine with `ppd key export/import`, after which
that machine recognises the files sealed here."""

from __future__ import annotations

import multiprocessing
import os
import re
import stat
import time
from multiprocessing.synchronize import Barrier
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from daemon.cli.key_cmd import register
from daemon.store.sealkey import SealKeyError, SealKeyMissing, key_path, load_key, new_key
from poisoner.formats import poison_file
from poisoner.provenance import Marker, Seal, read_seal, seal_file
from poisoner.spec import PatchSpec
from testkit.reliability import write_image


def _load(data_dir: str, out: multiprocessing.Queue[bytes | None]) -> None:
    out.put(load_key(Path(data_dir)))


def test_created_once_private_whatever_the_umask(tmp_path: Path) -> None:
    old = os.umask(0)
    try:
        ctx = multiprocessing.get_context("fork")
        out = ctx.Queue()
        procs = [ctx.Process(target=_load, args=(str(tmp_path / "data"), out)) for _ in range(4)]
        for p in procs:
            p.start()
        keys = {out.get(timeout=30) for _ in procs}
        for p in procs:
            p.join()
    finally:
        os.umask(old)
    assert len(keys) == 1 and len(next(iter(keys))) == 32  # four processes at once: one key
    st = key_path(tmp_path / "data").stat()
    assert stat.S_IMODE(st.st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "data").stat().st_mode) == 0o700
    assert load_key(tmp_path / "data") in keys
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == ["seal.key"]  # no temporary left


def _new(data_dir: str, start: Barrier, out: multiprocessing.Queue[str]) -> None:
    start.wait(timeout=30)  # a parent killed before all started: these end, not wait for ever
    try:
        new_key(Path(data_dir))
        out.put("made")
    except FileExistsError:
        out.put("exists")


def test_new_key_says_made_only_for_the_key_on_disk(tmp_path: Path) -> None:
    """`ppd key new` said "new seal key made" when another process linked its key first (a diff
    review, S3): processes racing for an empty data folder, one made it, the others are told it exists."""
    ctx = multiprocessing.get_context("fork")
    for round_ in range(5):
        data_dir, n = tmp_path / f"data{round_}", 6
        start, out = ctx.Barrier(n), ctx.Queue()
        procs = [ctx.Process(target=_new, args=(str(data_dir), start, out)) for _ in range(n)]
        for p in procs:
            p.start()
        said = sorted(out.get(timeout=30) for _ in procs)
        for p in procs:
            p.join()
        assert said == ["exists"] * (n - 1) + ["made"], said  # before: several "made"
        assert [p.name for p in data_dir.iterdir()] == ["seal.key"]  # no temporary left


def test_missing_key_is_not_created_when_not_asked(tmp_path: Path) -> None:
    assert load_key(tmp_path, create=False) is None and not key_path(tmp_path).exists()


def test_no_key_is_made_beside_a_vault_that_holds_originals(tmp_path: Path) -> None:
    """A missing key there is a lost one: a new one would take ppd's own output for new photos."""
    blob = tmp_path / "data" / "vault" / "ab" / ("ab" * 32)
    blob.parent.mkdir(parents=True)
    blob.write_bytes(b"an original")
    with pytest.raises(SealKeyMissing, match="`ppd key import FILE`"):
        load_key(tmp_path / "data")
    assert not key_path(tmp_path / "data").exists()
    assert load_key(tmp_path / "data", create=False) is None


def test_readable_or_linked_key_is_refused(tmp_path: Path) -> None:
    key = load_key(tmp_path / "data")
    os.chmod(key_path(tmp_path / "data"), 0o644)
    with pytest.raises(SealKeyError, match="readable by others"):
        load_key(tmp_path / "data")
    (tmp_path / "other").mkdir()
    key_path(tmp_path / "other").symlink_to(key_path(tmp_path / "data"))
    with pytest.raises(OSError):
        load_key(tmp_path / "other")
    key_path(tmp_path / "data").write_text("not a key\n")
    os.chmod(key_path(tmp_path / "data"), 0o600)
    with pytest.raises(SealKeyError, match="not a ppd seal key"):
        load_key(tmp_path / "data")
    assert key is not None


@pytest.fixture
def app() -> typer.Typer:
    app = typer.Typer()
    register(app)

    @app.callback()
    def _root() -> None:
        pass

    return app


def test_export_import_moves_recognition_to_a_new_machine(
    app: typer.Typer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    old_machine, new_machine = tmp_path / "old", tmp_path / "new"
    src = write_image(tmp_path / "a.png", seed=1, size=96)
    sealed = tmp_path / "sealed.png"
    key = load_key(old_machine)
    assert key is not None  # created on first use
    poison_file(src, sealed, PatchSpec(), marker=Marker.placeholder(key, "s", "ab" * 32))
    seal_file(sealed, key)
    runner = CliRunner()
    monkeypatch.setenv("PPD_DATA_DIR", str(old_machine))
    exported = runner.invoke(app, ["key", "export", str(tmp_path / "k")])
    assert exported.exit_code == 0, exported.output
    assert stat.S_IMODE((tmp_path / "k").stat().st_mode) == 0o600
    again = runner.invoke(app, ["key", "export", str(tmp_path / "k")])
    assert again.exit_code == 2 and "exists" in again.output
    monkeypatch.setenv("PPD_DATA_DIR", str(new_machine))
    assert read_seal(sealed, load_key(new_machine)) is None  # a fresh installation: not ours
    refused = runner.invoke(app, ["key", "import", str(tmp_path / "k")])
    assert refused.exit_code == 2 and "different key" in refused.output
    imported = runner.invoke(app, ["key", "import", str(tmp_path / "k"), "--force"])
    assert imported.exit_code == 0, imported.output
    assert read_seal(sealed, load_key(new_machine)) == Seal("ab" * 32, "s")
    assert stat.S_IMODE(key_path(new_machine).stat().st_mode) == 0o600
    (tmp_path / "bad").write_text("x" * 64)
    bad = runner.invoke(app, ["key", "import", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "not a ppd seal key" in bad.output and len(bad.output.splitlines()) == 1


def test_export_refuses_a_folder_whose_files_are_published(
    app: typer.Typer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The help said "never inside the outbox" and nothing checked it: the key (the secret that
    seals ppd's files) was written into the outbox, a synced folder. The outbox and every dataset's
    folder are refused, by any path (relative, through a symlink); elsewhere it is written."""
    from daemon.cli import app as ppd

    monkeypatch.setenv("PPD_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("PPD_CONFIG_DIR", str(tmp_path / "config"))
    outbox = tmp_path / "outbox"
    monkeypatch.setenv("PPD_OUTBOX", str(outbox))
    shoot = tmp_path / "shoot"
    write_image(shoot / "a.png", seed=1, size=96)
    runner = CliRunner()
    assert runner.invoke(ppd, ["poison", str(shoot)]).exit_code == 0
    outbox.mkdir(exist_ok=True)
    (tmp_path / "to-outbox").symlink_to(outbox)
    monkeypatch.chdir(outbox)
    for target in (outbox / "k.key", Path("k.key"), tmp_path / "to-outbox" / "k.key", shoot / "k.key"):
        refused = runner.invoke(app, ["key", "export", str(target)])
        assert refused.exit_code == 2 and "published" in refused.output, (target, refused.output)
    assert sorted(p.name for p in outbox.iterdir()) == [] and not (shoot / "k.key").exists()
    written = runner.invoke(app, ["key", "export", str(tmp_path / "k.key")])
    assert written.exit_code == 0, written.output


def test_export_refuses_an_out_copies_folder_and_the_config_s_publish_folder(
    app: typer.Typer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A privacy review: the key was written into a dataset's `--out` folder (the patched copies meant
    for publishing) and into the config's publish_dir, the folder a sync client uploads."""
    from daemon.cli import app as ppd

    monkeypatch.setenv("PPD_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("PPD_CONFIG_DIR", str(tmp_path / "config"))
    monkeypatch.setenv("PPD_OUTBOX", str(tmp_path / "outbox"))
    shoot, web, sync = tmp_path / "src" / "castle", tmp_path / "web", tmp_path / "sync"
    write_image(shoot / "sub" / "a.png", seed=1, size=96)
    runner = CliRunner()
    assert runner.invoke(ppd, ["poison", str(shoot), "--out", str(web)]).exit_code == 0
    assert (web / "castle" / "sub" / "a.png").is_file()
    sync.mkdir()
    (tmp_path / "config").mkdir(exist_ok=True)
    (tmp_path / "config" / "config.toml").write_text(f'publish_dir = "{sync}"\n')
    for target in (web / "castle" / "k.key", web / "castle" / "sub" / "k.key", sync / "k.key"):
        refused = runner.invoke(app, ["key", "export", str(target)])
        text = " ".join(refused.output.split())
        assert refused.exit_code == 2 and "published" in text and not target.exists(), (target, text)
    written = runner.invoke(app, ["key", "export", str(web / "k.key")])  # beside OUT/castle: not published
    assert written.exit_code == 0, written.output


# A hook on os.link (as `python -c` source) at the link of the written key into place, seal.key: the
# temporary's own creation (create_temp_at links a born-locked file too) goes on as usual.
AT_THE_LINK = (
    "import os, signal, sys, time\n"
    "real_link = os.link\n"
    "def link(src, dst, **kw):\n"
    "    if os.path.basename(os.fspath(dst)) == 'seal.key':\n"
    "        {action}\n"
    "    return real_link(src, dst, **kw)\n"
    "os.link = link\n"
)
# `ppd key new` killed (SIGKILL) after writing its key under a temporary name, before linking it
KILLED_BEFORE_THE_LINK = AT_THE_LINK.format(action="os.kill(os.getpid(), signal.SIGKILL)") + "\n".join(
    ["from daemon.cli import app", "sys.argv = ['ppd', 'key', 'new']", "app()"]
)
# A ppd making the key on first use (AppContext.seal_key), paused mid-install: the key written, not linked
PAUSED_BEFORE_THE_LINK = AT_THE_LINK.format(action="print('ready', flush=True); time.sleep(120)") + "\n".join(
    ["from pathlib import Path", "from daemon.store.sealkey import load_key", "load_key(Path(sys.argv[1]))"]
)
KEY_TEMP = r"\.ppd-tmp-L?[0-9a-f]{12}\.seal\.key"  # poisoner.atomic.create_temp_at's, born locked or not


def _ppd_python(script: str, *args: str) -> list[str]:
    import sys

    return [sys.executable, "-c", script, *args]


def _env() -> dict[str, str]:
    from testkit.kill_loops import REPO

    return {**os.environ, "PYTHONPATH": str(REPO)}


def _key_temporaries(data: Path) -> list[str]:
    return sorted(p.name for p in data.iterdir() if p.name != "seal.key" and "seal.key" in p.name)


def test_a_key_temporary_left_by_a_killed_ppd_is_removed_by_the_next_one(ppd_env: dict[str, Path]) -> None:
    """A kill between writing the key's temporary and unlinking it left a copy of the secret key in the
    data folder for good (a diff review). No process holds its lock any more: the next ppd removes it."""
    import signal
    import subprocess

    from daemon.cli import app as ppd
    from testkit.kill_loops import REPO

    data = ppd_env["data"]
    killed = subprocess.run(_ppd_python(KILLED_BEFORE_THE_LINK), cwd=REPO, env=_env(),
                            capture_output=True, text=True, timeout=120)  # fmt: skip
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    (left,) = _key_temporaries(data)
    assert re.fullmatch(KEY_TEMP, left), left  # before: .seal.key.PID.RANDOM, its liveness told by the PID
    assert len((data / left).read_text().strip()) == 64
    assert stat.S_IMODE((data / left).stat().st_mode) == 0o600
    status = CliRunner().invoke(ppd, ["status"])  # the next ppd, whatever it does
    assert status.exit_code == 0, status.output
    assert _key_temporaries(data) == []  # the copy is gone
    made = CliRunner().invoke(ppd, ["key", "new"])
    assert made.exit_code == 0 and "new seal key made" in made.output, made.output
    assert _key_temporaries(data) == [] and key_path(data).is_file()


def test_a_stale_key_temporary_goes_whatever_process_has_its_pid_now(ppd_env: dict[str, Path]) -> None:
    """Liveness was guessed from the PID in the name (`.seal.key.PID.RANDOM`): a dead writer's copy of
    the secret key stayed for as long as another process had that PID (a diff review, finding 6). Now
    a temporary nobody holds locked goes: an earlier ppd's (unlocked by design) once a few seconds
    old, whatever its PID; ppd's own kind (born locked) at any age. Other names are not touched."""
    from daemon.cli import app as ppd

    data = ppd_env["data"]
    key = ("ab" * 32 + "\n").encode()
    old = time.time() - 60
    stale = [f".seal.key.{os.getppid()}.deadbeef", ".seal.key.1.cafe0000", ".ppd-tmp-L0123456789ab.seal.key"]
    young = f".seal.key.{os.getppid()}.0badc0de"  # an earlier ppd may be writing it this instant
    others = [".seal.key.bak", ".ppd-tmp-L0123456789ab.json", "seal.key.1.deadbeef"]
    for name in stale + [young] + others:
        (data / name).write_bytes(key)
        if name != young:
            os.utime(data / name, (old, old))
    status = CliRunner().invoke(ppd, ["status"])
    assert status.exit_code == 0, status.output
    assert sorted(p.name for p in data.iterdir() if p.name in stale + [young] + others) == sorted(
        [young] + others
    )  # before: the two with a live PID (this test's parent, init) stayed
    os.utime(data / young, (old, old))
    assert CliRunner().invoke(ppd, ["status"]).exit_code == 0
    assert not (data / young).exists()


def test_a_live_writers_key_temporary_is_kept(ppd_env: dict[str, Path]) -> None:
    """Another process paused between writing the key and linking it into place holds its temporary's
    lock: ppd leaves it, whatever its age, and removes it once that process is killed."""
    import subprocess

    from daemon.cli import app as ppd
    from testkit.kill_loops import REPO

    data = ppd_env["data"]
    writer = subprocess.Popen(_ppd_python(PAUSED_BEFORE_THE_LINK, str(data)), cwd=REPO, env=_env(),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert writer.stdout is not None and writer.stderr is not None
        assert writer.stdout.readline() == "ready\n", writer.stderr.read()
        (writing,) = _key_temporaries(data)
        assert re.fullmatch(KEY_TEMP, writing)
        os.utime(data / writing, (0, 0))  # age plays no part: the lock says a writer is alive
        status = CliRunner().invoke(ppd, ["status"])
        assert status.exit_code == 0, status.output
        assert _key_temporaries(data) == [writing] and len((data / writing).read_text().strip()) == 64
    finally:
        writer.kill()
        writer.wait()
    assert CliRunner().invoke(ppd, ["status"]).exit_code == 0
    assert _key_temporaries(data) == []  # its writer is gone: so is the copy of the key


def test_export_refuses_the_data_folder(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd key export DATA/vault/k.key` was accepted without a word (a third black-box review, S9): a
    backup inside ppd's data folder is lost with it. Refused by any path, exit 2, one line."""
    from daemon.cli import app as ppd

    data = ppd_env["data"]
    assert CliRunner().invoke(ppd, ["key", "new"]).exit_code == 0
    (data / "vault").mkdir(exist_ok=True)
    (tmp_path / "to-data").symlink_to(data)
    for target in (data / "vault" / "k.key", data / "k.key", tmp_path / "to-data" / "k.key"):
        refused = CliRunner().invoke(ppd, ["key", "export", str(target)])
        said = refused.output.strip()
        assert refused.exit_code == 2 and len(said.splitlines()) == 1, (target, said)
        assert said.startswith("ppd: error: ") and "outside ppd's data folder" in said, said
        assert "PPD_DATA_DIR" in said and not target.exists()
    written = CliRunner().invoke(ppd, ["key", "export", str(tmp_path / "k.key")])
    assert written.exit_code == 0 and (tmp_path / "k.key").is_file(), written.output


def test_report_and_key_export_refuse_a_missing_folder_alike(ppd_env: dict[str, Path],
                                                              tmp_path: Path) -> None:  # fmt: skip
    """`ppd report X --out /nonexistent/dir/r.html` made the folders, exit 0; `ppd key export` into a
    missing folder said "cannot write", exit 3 (a black-box review, F11): one rule, exit 2, nothing made."""
    from daemon.cli import app as ppd

    shoot = tmp_path / "shoot"
    write_image(shoot / "a.png", seed=1, size=96)
    runner = CliRunner()
    assert runner.invoke(ppd, ["poison", str(shoot)]).exit_code == 0
    missing = tmp_path / "nowhere" / "dir"
    for args in (["report", "shoot", "--out", str(missing / "r.html")],
                 ["key", "export", str(missing / "k")]):  # fmt: skip
        result = runner.invoke(ppd, args)
        assert result.exit_code == 2, (args, result.output)
        assert result.output == f"ppd: error: no such folder: {missing}; create it first\n", result.output
    assert not (tmp_path / "nowhere").exists()
