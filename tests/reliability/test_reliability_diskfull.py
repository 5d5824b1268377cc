"""A full disk and I/O errors: nothing lost, one clear error per file, and recovery once space
returns. Two variants:

* a real small filesystem (a 3 MiB tmpfs mounted for the test; skipped with the reason where
  mounting is not allowed) that holds the outbox and the data folder and is filled to the
  last block, with protect_file in-process and with a real `ppd watch`;
* an ENOSPC injected at chosen points of the pipeline (the poisoned temporary's write, its
  fsync, the atomic rename, the vault's copy), which runs everywhere.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import daemon.protect.stages
import daemon.store.vault
import poisoner.atomic
import poisoner.formats
from daemon.cli.output import _field  # the log line's own quoting (a path with a space)
from daemon.protect.job import NO_SPACE_WORDS
from daemon.protect.one_file import AppContext, protect_file
from daemon.states import FileState
from daemon.store import Store
from daemon.watch.outcomes import is_no_space
from testkit.disk_full import MountUnavailable, fill, run_disk_full, small_filesystem
from testkit.reliability import (
    DAEMON_ARGS,
    app_paths,
    check_invariants,
    kill_daemon,
    sha256,
    start_daemon,
    wait_all_protected,
    wait_for,
    write_image,
)

ENOSPC_TEXT = os.strerror(errno.ENOSPC)  # "No space left on device"


@contextlib.contextmanager
def mounted_or_skip(where: Path) -> Iterator[Path]:
    """The harness's small tmpfs, or a skip that says why it cannot be mounted here."""
    try:
        with small_filesystem(where) as fs:
            yield fs
    except MountUnavailable as exc:
        pytest.skip(f"cannot mount a tmpfs here: {exc}")


@pytest.mark.parametrize("leave", [0, 96 << 10], ids=["no-byte-left", "96KiB-left"])
def test_full_tmpfs_in_process_loses_nothing_and_recovers(tmp_path: Path, leave: int) -> None:
    """0 bytes left: the store cannot write either; 96 KiB: the store can, ppd's output cannot."""
    with mounted_or_skip(tmp_path / "small") as fs:
        report = run_disk_full(fs, leave, files=4)
    assert report.failed_while_full == 3 and report.protected_while_full == 0
    assert report.unclear_reasons == [] and report.leftover_temporaries == 0
    assert report.violations_while_full == [] and report.violations_after == []
    assert report.protected_after_space_returned == 4


def test_full_tmpfs_under_the_daemon_retries_when_space_returns(tmp_path: Path) -> None:
    """Files arrive whole (renamed in from the same filesystem) when ~96 KiB are left: ppd's
    output does not fit and the store fills up a few rows later. Each file fails with a
    one-line no-space reason in the log (and in its row while the store had room), nothing is
    touched, the daemon keeps going, and once space returns it protects them, no restart."""
    with mounted_or_skip(tmp_path / "small") as fs:
        paths = app_paths(fs)
        sources = [write_image(fs / "stage" / f"{i}.png", seed=i, size=256) for i in range(6)]
        originals = {paths.outbox / "shoot" / s.name: sha256(s) for s in sources}
        targets = list(originals)
        targets[0].parent.mkdir(parents=True)
        # its log outside the filesystem it fills: on it, the full disk ate log lines (more of them the
        # longer the temp path in each line), and the lines are what this test reads
        daemon = start_daemon(fs, *DAEMON_ARGS, log_dir=tmp_path)
        try:
            os.rename(sources[0], targets[0])
            wait_all_protected(paths, targets[:1], 30)  # the store and vault are set up
            filler = fill(fs, leave=96 << 10)
            for src, dst in zip(sources[1:], targets[1:], strict=True):
                os.rename(src, dst)

            def all_tried() -> bool:  # one clear line per file (the store may be full as well)
                log = daemon.log.read_text(errors="replace").splitlines()
                said = [line for line in log if is_no_space(line)]
                lines = [f"file={_field(p)} outcome=failed" for p in targets[1:]]
                return all(any(want in line for line in said) for want in lines)

            wait_for(all_tried, 30, "each file to fail for lack of space")
            store = Store(paths.db_path)
            for p in targets[1:]:
                row = store.file(p)  # a row when the store still had room: failed, or pending
                assert row is None or row["state"] in ("failed", "pending"), row
                assert row is None or row["state"] != "failed" or is_no_space(row["error"]), row
                assert sha256(p) == originals[p]
            assert daemon.proc.poll() is None, "the daemon died on a full disk"
            assert check_invariants(paths, originals) == []
            filler.unlink()  # space returns; no new event, no restart
            try:
                wait_all_protected(paths, targets, 60)
            except AssertionError:
                print(daemon.log.read_text(errors="replace")[-6000:])
                raise
            store.close()
        finally:
            code = kill_daemon(daemon, signal.SIGTERM)
        assert code == 0
        assert check_invariants(paths, originals) == []
        log = daemon.log.read_text(errors="replace")
        assert "Traceback" not in log and "disk space returned: retrying 5 file(s)" in log, log[-3000:]


def _protected(store: Store, path: Path) -> bool:
    row = store.file(path)
    return row is not None and row["state"] == FileState.PATCHED


# ---- ENOSPC injected at chosen points ----------------------------------------------------------------
def _raise_enospc(*_: object, **__: object) -> None:
    raise OSError(errno.ENOSPC, ENOSPC_TEXT)


def _fail_patched_write(monkeypatch: pytest.MonkeyPatch) -> None:
    """An image's patched bytes, made in memory, fail half-way through their one write: into the
    temporary beside the file (replace_atomically)."""

    def write_all(fd: int, data: bytes) -> None:
        os.write(fd, data[: len(data) // 2])
        _raise_enospc()

    monkeypatch.setattr(daemon.protect.stages, "write_all", write_all)


def _fail_work_file_write(monkeypatch: pytest.MonkeyPatch) -> None:
    """The poison stage's work file (an image over IN_MEMORY_MAX, a video: made small here, so both
    test images take that path) fails half-way through its write in the vault's work folder."""
    real = Path.write_bytes

    def write_bytes(self: Path, data: bytes) -> int:
        if self.name.startswith(daemon.protect.stages.PATCHED_PREFIX):
            with open(self, "wb") as fh:  # half of it lands, then the disk is full
                fh.write(data[: len(data) // 2])
            _raise_enospc()
        return real(self, data)

    monkeypatch.setattr(daemon.protect.stages, "IN_MEMORY_MAX", 0)
    monkeypatch.setattr(Path, "write_bytes", write_bytes)


def _fail_fsync(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(poisoner.atomic.os, "fsync", _raise_enospc)


def _fail_replace(monkeypatch: pytest.MonkeyPatch) -> None:
    real = os.rename

    def rename(src: object, dst: object, **kw: object) -> None:
        # the patched file's replace: not the vault's own (its spec file: "vault-spec")
        if Path(os.fsdecode(src)).name.startswith(poisoner.atomic.TEMP_PREFIX) and not _in_vault(dst, kw):
            _raise_enospc()
        real(src, dst, **kw)

    monkeypatch.setattr(poisoner.atomic.os, "rename", rename)


def _in_vault(dst: object, kw: dict[str, object]) -> bool:
    """Whether a rename's destination (a name in the folder dst_dir_fd, or a path) is in the vault."""
    folder = kw.get("dst_dir_fd")
    where = Path(os.readlink(f"/proc/self/fd/{folder}")) if isinstance(folder, int) else Path()
    return "vault" in (where / os.fsdecode(str(dst))).parts


def _fail_spec_write(monkeypatch: pytest.MonkeyPatch) -> None:
    """The vault's copy of the patch spec (kept once per spec, so that a rebuild knows it) finds no room."""
    monkeypatch.setattr(daemon.store.vault, "atomic_write_text", _raise_enospc)


def _fail_vault_copy(monkeypatch: pytest.MonkeyPatch) -> None:
    """The vault's copy (no reflink here) runs out of space while writing the original's bytes."""
    monkeypatch.setattr(daemon.store.vault, "_write_blob", _raise_enospc)


INJECTIONS: dict[str, Callable[[pytest.MonkeyPatch], None]] = {
    "poisoned-write": _fail_patched_write,
    "poisoned-work-file-write": _fail_work_file_write,
    "fsync": _fail_fsync,
    "atomic-rename": _fail_replace,
    "vault-copy": _fail_vault_copy,
    "vault-spec": _fail_spec_write,
}


@pytest.fixture
def ctx(ppd_env: dict[str, Path]) -> Iterator[AppContext]:
    context = AppContext.open()
    yield context
    context.close()


@pytest.mark.parametrize("point", sorted(INJECTIONS))
def test_enospc_at_each_point_loses_nothing_and_a_retry_protects(
    ctx: AppContext, monkeypatch: pytest.MonkeyPatch, point: str
) -> None:
    target = write_image(ctx.paths.outbox / "shoot" / "a.png", seed=1, size=128)
    jpeg = write_image(ctx.paths.outbox / "shoot" / "b.jpg", seed=2, size=128)
    originals = {target: sha256(target), jpeg: sha256(jpeg)}
    with monkeypatch.context() as patch:
        INJECTIONS[point](patch)
        outcomes = [protect_file(p, ctx) for p in originals]
    # the disk named, not a raw "[Errno 28]" (a black-box review): the photo's, the vault's for a work copy
    disk = {"poisoned-write": target.parent, "poisoned-work-file-write": ctx.vault.vault_dir,
            "atomic-rename": target.parent}.get(point)  # fmt: skip
    for outcome in outcomes:
        assert outcome.state == "failed", (point, outcome)
        assert is_no_space(outcome.reason) and "[Errno" not in outcome.reason and "\n" not in outcome.reason
        assert disk is None or outcome.reason == f"{NO_SPACE_WORDS} {disk}", (point, outcome.reason)
        assert ctx.store.file(outcome.path)["error"] == outcome.reason
    assert all(sha256(p) == digest for p, digest in originals.items())
    assert not list(ctx.paths.outbox.rglob(".ppd-tmp-*"))
    tmp_prefix = daemon.store.vault.VAULT_TMP_PREFIX
    assert not [p for p in ctx.paths.vault_dir.iterdir() if p.name.startswith(tmp_prefix)]
    assert check_invariants(ctx.paths, originals) == []
    again = [protect_file(p, ctx) for p in originals]  # space is back
    assert [o.state for o in again] == ["patched", "patched"], [o.reason for o in again]
    assert check_invariants(ctx.paths, originals) == []


def test_enospc_module_points_exist() -> None:
    """The injection points name real code paths (a rename would silently disarm a test)."""
    assert callable(poisoner.formats.poison_file) and hasattr(daemon.store.vault, "VAULT_TMP_PREFIX")
    assert "dst.write_bytes(out)" in Path(poisoner.formats.__file__).read_text()
    assert (
        callable(daemon.store.vault._write_blob)
        and "_write_blob(tmp_fd" in Path(daemon.store.vault.__file__).read_text()
    )
    stages = Path(daemon.protect.stages.__file__).read_text()
    assert "PATCHED_PREFIX" in stages and "write_all(fd, content)" in stages
    assert "os.rename(tmp_name, name" in Path(poisoner.atomic.__file__).read_text()


def test_ppd_poison_on_a_full_disk_exits_3_as_its_help_says(tmp_path: Path, ppd_env: dict[str, Path]) -> None:
    """`ppd --help`: 3 = cannot work here (disk full). A black-box review: a full disk gave exit 1, like a
    bad file, with no line saying what to do."""
    from typer.testing import CliRunner

    from daemon.cli import app

    with mounted_or_skip(tmp_path / "small") as fs:
        shoot = fs / "shoot"
        photo = write_image(shoot / "a.png", seed=3)
        before = photo.read_bytes()
        fill(fs)
        result = CliRunner().invoke(app, ["poison", str(shoot)])
        assert result.exit_code == 3, result.output
        assert "a disk is full" in " ".join(result.output.split())
        assert photo.read_bytes() == before  # nothing lost


def test_a_full_photo_disk_is_named_in_each_line_in_natural_order(
    tmp_path: Path, ppd_env: dict[str, Path]
) -> None:
    """A black-box review (S9): on a full photo disk every file read "ppd: failed: .../x10.jpg: [Errno 28]
    No space left on device", sorted as text (x10 before x2). `ppd restore` on it: the same reason, and
    exit 3 as poison's."""
    from typer.testing import CliRunner

    from daemon.cli import app

    with mounted_or_skip(tmp_path / "small") as fs:
        shoot = fs / "shoot"
        photos = [write_image(shoot / f"x{i}.jpg", seed=i, size=96) for i in range(12)]
        before = {p: p.read_bytes() for p in photos}
        filler = fill(fs)
        result = CliRunner().invoke(app, ["poison", str(shoot)])
        failed = [line for line in result.output.splitlines() if line.startswith("ppd: failed: ")]
        assert result.exit_code == 3, result.output
        assert failed == [f"ppd: failed: {p}: {NO_SPACE_WORDS} {shoot}" for p in photos], result.output
        listed = CliRunner().invoke(app, ["status", "shoot", "--failed"]).output.splitlines()[1:]
        assert [line.split(": ")[0].strip() for line in listed] == [str(p) for p in photos], listed
        assert all(p.read_bytes() == data for p, data in before.items())  # nothing lost
        filler.unlink()
        assert CliRunner().invoke(app, ["poison", str(shoot)]).exit_code == 0
        fill(fs)
        restore = CliRunner().invoke(app, ["restore", "shoot"])
        failed = [line for line in restore.output.splitlines() if line.startswith("ppd: not restored: ")]
        assert restore.exit_code == 3 and "a disk is full" in restore.output, restore.output
        assert failed == [f"ppd: not restored: {p}: {NO_SPACE_WORDS} {shoot}" for p in photos], restore.output


def test_a_full_disk_under_the_store_says_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With the data folder's disk full, `ppd status` said "cannot open the store ...: disk I/O error",
    which reads as failing hardware (a third black-box review): it says the disk is full."""
    from typer.testing import CliRunner

    from daemon.cli import app

    with mounted_or_skip(tmp_path / "small") as fs:
        monkeypatch.setenv("PPD_DATA_DIR", str(fs / "data"))
        for var, name in (("PPD_CONFIG_DIR", "config"), ("PPD_OUTBOX", "outbox"), ("PPD_CACHE_DIR", "cache")):
            monkeypatch.setenv(var, str(tmp_path / name))
        write_image(tmp_path / "shoot" / "a.png", seed=3)
        runner = CliRunner()
        assert runner.invoke(app, ["poison", str(tmp_path / "shoot")]).exit_code == 0
        fill(fs)
        result = runner.invoke(app, ["status"])
        said = " ".join(result.output.split())
        assert result.exit_code == 3 and "the disk holding it is full" in said, said
