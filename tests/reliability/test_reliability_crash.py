"""Crash injection: `ppd watch` SIGKILLed at random instants while it protects images and a
video, then restarted (the short CI version of `python -m bench faults`), and a short load run
(the CI version of `python -m bench load`)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from daemon.paths import AppPaths
from daemon.states import FileState
from daemon.store import Store
from testkit.reliability import (
    CrashTrialOptions,
    app_paths,
    check_invariants,
    drop_files,
    kill_daemon,
    run_crash_trials,
    sha256,
    start_daemon,
    wait_all_protected,
)


def test_random_sigkills_lose_nothing_and_a_restart_finishes(tmp_path: Path) -> None:
    options = CrashTrialOptions(
        trials=10, images_per_trial=4, image_size=640, video_every=5, seed=8, kill_after_s=(0.1, 0.7),
        kill_when_working_every=2,
    )
    report = run_crash_trials(tmp_path, options)
    summary = f"{report}"
    assert report.trials == 10 and report.videos == 2, summary
    assert all(code == -9 for code in report.exit_codes.elements()), summary
    assert report.violations_after_kill == [] and report.violations_final == [], summary
    assert report.not_exactly_once == [], summary
    # The kills must land mid-work at least sometimes, else the test proves nothing.
    assert report.kill_phases["kills that interrupted this trial's work"] >= 1, summary


def test_invariant_checker_sees_loss_and_corruption(tmp_path: Path) -> None:
    """The checker itself: a truncated protected file, a half-written original and a deleted
    vault blob are each reported."""
    paths = app_paths(tmp_path)
    daemon = start_daemon(tmp_path, "--no-verify", "--debounce", "0.05")
    try:
        originals = drop_files(tmp_path / "stage", paths.outbox / "ds", [(f"{i}.png", i) for i in range(3)])
        wait_all_protected(paths, list(originals), 60)
    finally:
        kill_daemon(daemon)
    assert check_invariants(paths, originals) == []
    first, second, third = sorted(originals)
    first.write_bytes(first.read_bytes()[:100])  # a torn protected file
    row = Store(paths.db_path).file(third)
    (paths.vault_dir / row["original_sha256"][:2] / row["original_sha256"]).unlink()
    untracked = paths.outbox / "ds" / "untracked.png"
    untracked.write_bytes(b"\x89PNG half")
    problems = check_invariants(paths, {**originals, untracked: originals[second]})
    assert any(p.startswith("store:") and first.name in p for p in problems), problems
    assert any(p.startswith("vault:") and third.name in p for p in problems), problems
    assert any(p.startswith("corrupted:") and untracked.name in p for p in problems), problems
    os.unlink(untracked)


@pytest.mark.parametrize("files", [300])
def test_short_load_every_file_protected_exactly_once(tmp_path: Path, files: int) -> None:
    from testkit.load import FloodOptions, run_flood

    result = run_flood(tmp_path, FloodOptions(files=files, size=128))
    assert result.protected == files and result.failed == 0
    assert result.not_exactly_once == [] and result.violations == []
    assert result.daemon_exit_code == 0


class Killed(BaseException):
    """Stands for SIGKILL at one instant: not an Exception, so protect_file records nothing."""


def test_duplicate_killed_between_rename_and_record_is_recovered(
    ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Found by the crash trials: two identical originals (the same photo in two datasets) give
    identical protected files. When ppd died between renaming the second one into place and
    recording it, the restart found that content as the first file's output ('already ppd
    output') and left the second row 'pending' for ever."""
    import shutil

    from daemon.protect.one_file import AppContext, protect_file
    from testkit.reliability import write_image

    ctx = AppContext.open()
    first = write_image(ppd_env["outbox"] / "one" / "p.png", seed=1)
    (ppd_env["outbox"] / "two").mkdir()
    second = Path(shutil.copyfile(first, ppd_env["outbox"] / "two" / "p.png"))
    assert protect_file(first, ctx).state == "patched"
    real_record = ctx.store.record_file

    def die_before_recording_protected(path: Path | str, dataset: str, state: str, **kw: object) -> None:
        if state == FileState.PATCHED and Path(path) == second:
            raise Killed
        real_record(path, dataset, state, **kw)

    # A context of its own: monkeypatch.undo() would also undo ppd_env's PPD_* variables, and
    # the invariant check below would then read the real user's data folder.
    with monkeypatch.context() as patch, pytest.raises(Killed):
        patch.setattr(ctx.store, "record_file", die_before_recording_protected)
        protect_file(second, ctx)
    assert ctx.store.file(second)["state"] == "pending"  # the crash left this
    assert sha256(second) == sha256(first)  # ... with the protected file already in place
    outcome = protect_file(second, ctx)  # the restart
    row = ctx.store.file(second)
    ctx.close()
    assert outcome.state == "unchanged" and "recovered" in outcome.reason, outcome
    assert row["state"] == FileState.PATCHED and row["poisoned_sha256"] == sha256(second)
    assert check_invariants(AppPaths.from_env(), {}) == []


def test_a_pending_file_sealed_for_its_row_is_recovered_without_patching_it_again(
    ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """CI found a pending video whose bytes were not what patching its original again gave. Its
    seal is what tells ppd's complete output: a run killed between the rename and the row, then a
    restart under which re-poisoning gives other bytes (here: keep_location switched on, the photo
    has GPS), completes the row from the seal; a file whose seal names another original does not."""
    from PIL import Image

    from daemon.protect import recovery
    from daemon.protect.one_file import AppContext, protect_file
    from poisoner.provenance import read_seal
    from testkit.photos import gps_exif
    from testkit.reliability import texture

    photo = ppd_env["outbox"] / "trip" / "p.jpg"
    photo.parent.mkdir()
    Image.fromarray(texture(3, 320)).save(photo, quality=92, exif=gps_exif())
    ctx = AppContext.open()
    real_record = ctx.store.record_file

    def die_before_recording_protected(path: Path | str, dataset: str, state: str, **kw: object) -> None:
        if state == FileState.PATCHED:
            raise Killed
        real_record(path, dataset, state, **kw)

    with monkeypatch.context() as patch, pytest.raises(Killed):
        patch.setattr(ctx.store, "record_file", die_before_recording_protected)
        protect_file(photo, ctx)
    killed_output, seal = sha256(photo), read_seal(photo, ctx.seal_key())
    assert seal is not None and ctx.store.file(photo)["state"] == "pending"
    ctx.close()
    (ppd_env["config"] / "config.toml").write_text("[privacy]\nkeep_location = true\n")
    ctx = AppContext.open()
    assert ctx.config.keep_location
    pending = ctx.store.file(photo)
    # re-poisoning now keeps the GPS: other bytes, so only the seal can tell this file is ppd's
    assert not recovery._redone_is(ctx, pending, photo, killed_output, "image")
    outcome = protect_file(photo, ctx)  # the restart
    row = ctx.store.file(photo)
    assert outcome.state == "unchanged" and "recovered" in outcome.reason, outcome
    assert row["state"] == FileState.PATCHED and row["poisoned_sha256"] == killed_output == sha256(photo)
    assert check_invariants(AppPaths.from_env(), {}) == []

    # A sealed file for another original at a pending path is not taken as this row's output.
    other = ppd_env["outbox"] / "trip" / "q.jpg"
    Image.fromarray(texture(4, 320)).save(other, quality=92)
    with monkeypatch.context() as patch, pytest.raises(Killed):
        patch.setattr(ctx.store, "record_file", die_before_recording_protected)
        protect_file(other, ctx)
    pending = ctx.store.file(other)
    other.write_bytes(photo.read_bytes())  # ppd's sealed output, but of p.jpg's original
    problems = check_invariants(AppPaths.from_env(), {})
    assert pending["state"] == "pending", pending
    assert any("q.jpg" in p and "a seal naming" in p for p in problems), problems
    # ... nor by the daemon: not recovered as q.jpg's output (it is p.jpg's, and said so)
    assert not recovery.recover_pending(ctx, pending, other, sha256(other), "image")
    again = protect_file(other, ctx)
    ctx.close()
    assert "recovered" not in again.reason and again.state == "unchanged", again
