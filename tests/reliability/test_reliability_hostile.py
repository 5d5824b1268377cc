"""Hostile input: a corpus generated here (truncated/corrupt files of every format, zero bytes,
decompression bombs, 16-bit, CMYK, palette, animated, huge metadata, non-images with image
names, odd names, link tricks, FIFOs) goes through protect_file and through a real `ppd watch`.
Each file ends protected or refused with a one-line error and untouched; nothing outside the
outbox changes; the daemon survives."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import signal
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from daemon.paths import AppPaths
from daemon.protect.one_file import AppContext, ProtectOutcome, protect_file
from daemon.states import FileState
from daemon.store import Store
from testkit.hostile_inputs import HostileInput, build_hostile_corpus
from testkit.reliability import (
    DAEMON_ARGS,
    act_after_poisoning,
    app_paths,
    check_invariants,
    kill_daemon,
    sha256,
    start_daemon,
    wait_for,
)


@pytest.fixture
def ctx(ppd_env: dict[str, Path]) -> Iterator[AppContext]:
    context = AppContext.open()
    yield context
    context.close()


def _fingerprint(path: Path) -> str | None:
    """sha256 of a regular file, else a description of what is there (links are not followed)."""
    if path.is_symlink():
        return f"symlink -> {os.readlink(path)}"
    if path.is_file():
        return sha256(path)
    return "folder" if path.is_dir() else ("other" if os.path.lexists(path) else None)


def _outside_fingerprints(outside: Path) -> dict[Path, str | None]:
    return {p: _fingerprint(p) for p in sorted(outside.rglob("*"))}


def _judge(item: HostileInput, before: str | None, state: str | None, reason: str | None) -> str | None:
    """What is wrong with how this input was handled (None: as expected)."""
    after = _fingerprint(item.path)
    if state == "failed" and (not reason or "\n" in reason):
        return f"{item.what}: failure without a one-line reason: {reason!r}"
    if item.expect == "protected" and state != FileState.PATCHED:
        return f"{item.what}: expected protected, got {state} ({reason})"
    if item.expect == "refused" and state != "failed":
        return f"{item.what}: expected a refusal, got {state}"
    if item.expect == "either" and state not in (FileState.PATCHED, FileState.FAILED):
        return f"{item.what}: expected protected or refused, got {state}"
    if state != FileState.PATCHED and after != before:
        return f"{item.what}: not protected, yet changed on disk"
    if state == FileState.PATCHED and after == before:
        return f"{item.what}: protected, yet unchanged on disk"
    return None


def test_hostile_corpus_through_protect_file(ctx: AppContext, tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    items = build_hostile_corpus(ctx.paths.outbox / "hostile", outside)
    before = {item.path: _fingerprint(item.path) for item in items}
    outside_before = _outside_fingerprints(outside)
    problems = []
    for item in items:
        outcome: ProtectOutcome = protect_file(item.path, ctx)  # never raises, whatever the input
        state = outcome.state if item.expect != "left" or outcome.state != "skipped" else None
        state = FileState.PATCHED if state == "patched" else state  # judged like a store row
        if item.expect == "left":
            if outcome.state == "patched" or _fingerprint(item.path) != before[item.path]:
                problems.append(f"{item.what}: was touched ({outcome.state})")
            continue
        if (problem := _judge(item, before[item.path], state, outcome.reason)) is not None:
            problems.append(problem)
    assert problems == []
    assert _outside_fingerprints(outside) == outside_before  # links never lead ppd out
    assert len(items) >= 50


def _move_corpus_into_outbox(
    tmp_path: Path, paths: AppPaths, outside: Path
) -> tuple[list[HostileInput], dict[Path, str | None], dict[Path, str | None]]:
    """Build the corpus in a staging folder and move it into the outbox as one folder; returns the
    items at their outbox paths, their fingerprints and those of the files outside."""
    staged = build_hostile_corpus(tmp_path / "stage" / "hostile", outside)
    before_staged = {item.path: _fingerprint(item.path) for item in staged}
    outside_before = _outside_fingerprints(outside)
    os.rename(tmp_path / "stage" / "hostile", paths.outbox / "hostile")  # moved in as one folder
    moved = [paths.outbox / i.path.relative_to(tmp_path / "stage") for i in staged]
    items = [dataclasses.replace(i, path=p) for i, p in zip(staged, moved, strict=True)]
    before = {item.path: before_staged[old.path] for item, old in zip(items, staged, strict=True)}
    return items, before, outside_before


def _wait_until_all_decided(store: Store, items: list[HostileInput]) -> None:
    expected_rows = [i for i in items if i.expect != "left"]

    def all_decided() -> bool:
        rows = {r["path"]: r["state"] for r in store.files("hostile")}
        decided = (FileState.PATCHED, FileState.FAILED, FileState.QUARANTINED)
        return all(rows.get(str(i.path)) in decided for i in expected_rows)

    wait_for(all_decided, 120, "every hostile input protected or refused")


def _daemon_problems(
    paths: AppPaths,
    quarantine: Path,
    items: list[HostileInput],
    rows: dict[str, dict],
    before: dict[Path, str | None],
) -> list[str]:
    """What the daemon did wrong with each hostile input (empty when every outcome is acceptable)."""
    problems = []

    def quarantined(path: Path) -> Path:
        return quarantine / path.relative_to(paths.outbox)

    def moved_from(item: HostileInput) -> Path:
        if item.path.is_relative_to(quarantine):
            return paths.outbox / item.path.relative_to(quarantine)
        return item.path

    for item in items:
        row = rows.get(str(item.path))
        if item.expect == "left":
            touched = row is not None and row["state"] == FileState.PATCHED
            # untouched in place, or moved out whole (a name the store cannot hold is quarantined)
            kept = before[item.path] in (_fingerprint(item.path), _fingerprint(quarantined(item.path)))
            if touched or not kept:
                problems.append(f"{item.what}: was touched")
            continue
        state = row["state"]
        if state == FileState.QUARANTINED:  # refused, and moved out of the outbox untouched
            if item.path.exists() or item.path.is_symlink():
                problems.append(f"{item.what}: quarantined but still in the outbox")
            item, state = dataclasses.replace(item, path=quarantined(item.path)), FileState.FAILED
        if (problem := _judge(item, before[moved_from(item)], state, row["error"])) is not None:
            problems.append(problem)
    return problems


def test_hostile_corpus_under_the_daemon(tmp_path: Path) -> None:
    paths = app_paths(tmp_path)
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)
    outside = tmp_path / "outside"
    try:
        items, before, outside_before = _move_corpus_into_outbox(tmp_path, paths, outside)
        store = Store(paths.db_path)
        _wait_until_all_decided(store, items)
        store.close()
        assert daemon.proc.poll() is None, "the daemon died"
    finally:
        code = kill_daemon(daemon, signal.SIGTERM)
    assert code == 0
    # Read once the daemon has stopped: a refused file's row says `failed` (its worker) a moment
    # before the daemon moves the file out and says `quarantined`.
    store = Store(paths.db_path)
    rows = {r["path"]: r for r in store.files("hostile")}
    store.close()
    quarantine = tmp_path / "ppd-quarantine"  # the default: next to the outbox
    problems = _daemon_problems(paths, quarantine, items, rows, before)
    assert problems == []
    assert _outside_fingerprints(outside) == outside_before
    log = daemon.log.read_text(errors="replace")
    assert "Traceback" not in log and "worker job failed" not in log, log[-3000:]
    originals = {
        i.path: before[i.path]
        for i in items
        if i.expect != "left" and i.path.is_file() and rows[str(i.path)]["state"] != FileState.QUARANTINED
    }
    assert check_invariants(paths, originals) == []


def _replace_after_poisoning(monkeypatch: pytest.MonkeyPatch, replace: Callable[[], None]) -> None:
    """Make a concurrent writer act at the worst instant, once (testkit.reliability)."""
    act_after_poisoning(monkeypatch, replace)


@pytest.mark.parametrize("how", ["rename-over", "rewrite-in-place", "symlink-swap"])
def test_file_replaced_mid_processing_is_left_as_the_user_made_it(
    ctx: AppContext, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    """Before: the new version was left in place but the run ended 'failed', so nothing patched it
    until another event. Now: never overwritten, and patched next in the same call (its bytes are
    the vault's original); a symlink put in its place is refused and never written through."""
    from testkit.reliability import write_image

    target = write_image(ctx.paths.outbox / "race" / "a.png", seed=1)
    newer = write_image(tmp_path / "newer.png", seed=2)
    newer_bytes = newer.read_bytes()
    secret = write_image(tmp_path / "secret.png", seed=3)
    secret_sha = sha256(secret)

    def replace() -> None:
        if how == "rename-over":
            os.replace(newer, target)
        elif how == "rewrite-in-place":
            target.write_bytes(newer_bytes)
        else:
            target.unlink()
            target.symlink_to(secret)

    _replace_after_poisoning(monkeypatch, replace)
    outcome = protect_file(target, ctx)
    assert sha256(secret) == secret_sha
    assert not list(target.parent.glob(".ppd-tmp-*"))
    if how == "symlink-swap":
        assert outcome.state == "failed" and "symlink" in outcome.reason
        assert target.is_symlink() and os.readlink(target) == str(secret)
    else:
        new_sha = hashlib.sha256(newer_bytes).hexdigest()
        assert outcome.state == "patched" and outcome.original_sha256 == new_sha, outcome
        assert ctx.vault.path_for(new_sha).read_bytes() == newer_bytes
        assert ctx.store.file(target)["original_sha256"] == new_sha
        assert sha256(target) == outcome.poisoned_sha256


def test_name_that_is_not_utf8_is_refused_with_a_clear_reason(
    ctx: AppContext, caplog: pytest.LogCaptureFixture
) -> None:
    """Before the fix: a raw UnicodeEncodeError from SQLite as the reason, no row, and a
    traceback logged for the failure to record it."""
    from testkit.reliability import write_image

    folder = ctx.paths.outbox / "names"
    good = write_image(folder / "plain.png", seed=1)
    odd = Path(os.fsdecode(os.fsencode(folder) + b"/caf\xe9.png"))
    odd.write_bytes(good.read_bytes())
    before = sha256(odd)
    with caplog.at_level("WARNING"):
        outcome = protect_file(odd, ctx)
    assert outcome.state == "failed"
    assert outcome.reason.startswith("caf\\xe9.png: the file name is not valid UTF-8")
    assert sha256(odd) == before
    assert "Traceback" not in caplog.text and "could not record" not in caplog.text
    assert protect_file(good, ctx).state == "patched"  # the store still works


def test_newline_in_a_name_does_not_cut_the_reason(ctx: AppContext) -> None:
    """Before the fix the reason was the part of the name before the newline."""
    bad = ctx.paths.outbox / "names" / "two\nlines.jpg"
    bad.parent.mkdir(parents=True)
    bad.write_bytes(b"not a photo")
    outcome = protect_file(bad, ctx)
    assert outcome.state == "failed" and "\n" not in outcome.reason
    assert outcome.reason.startswith("two\\nlines.jpg")
    assert "not a recognised image" in outcome.reason or "is incomplete" in outcome.reason
    assert ctx.store.file(bad)["error"] == outcome.reason


def test_decode_budget_refusal_names_the_file_not_its_descriptor(ctx: AppContext) -> None:
    """The budget check reads through /proc/self/fd/N; before the fix the stored reason began
    with the descriptor number ("11: 100000x100000 ...") instead of the file's name."""
    from testkit.hostile_images import tiff_huge

    bomb = ctx.paths.outbox / "bombs" / "huge.tif"
    bomb.parent.mkdir(parents=True)
    tiff_huge(bomb)
    outcome = protect_file(bomb, ctx)
    assert outcome.state == "failed"
    assert outcome.reason.startswith("huge.tif: 100000x100000 (10000 MP) is over the"), outcome.reason
    assert ctx.store.file(bomb)["error"] == outcome.reason
