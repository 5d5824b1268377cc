"""protect as a list of named stages, and containment that a swapped folder or file cannot escape
(real files, a real store and vault; the swaps happen at the worst instants, through hooks)."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path

import pytest

from daemon.protect.job import Outcome
from daemon.protect.one_file import AppContext, protect_file
from daemon.protect.stages import STAGES
from daemon.states import FileState
from testkit.reliability import act_after_poisoning, write_image


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def ctx(ppd_env: dict[str, Path]) -> AppContext:
    context = AppContext.open()
    yield context
    context.close()


def _tree(folder: Path) -> dict[str, str]:
    """Every entry under folder: a file's sha256, or where a link points."""
    out = {}
    for p in sorted(folder.rglob("*")):
        out[str(p)] = f"-> {os.readlink(p)}" if p.is_symlink() else _sha(p) if p.is_file() else "dir"
    return out


def test_the_crash_safe_order_is_one_list_of_named_stages(ctx: AppContext) -> None:
    names = [stage.__name__ for stage in STAGES]
    vault, pending, poison = names.index("keep_in_vault"), names.index("mark_pending"), names.index("poison")
    replace, row, publish = (
        names.index("replace_atomically"),
        names.index("record_provenance"),
        names.index("publish"),
    )
    assert vault < pending < poison < replace < row < publish
    photo = write_image(ctx.paths.outbox / "ds" / "a.png", seed=1)
    before = _sha(photo)
    outcome = protect_file(photo, ctx)
    assert outcome.state == Outcome.PATCHED == "patched"
    assert ctx.store.file(photo)["state"] == FileState.PATCHED
    assert ctx.vault.path_for(before).read_bytes() != photo.read_bytes()
    # the vault holds its own copy: not the inode the user's folder had
    assert os.stat(ctx.vault.path_for(before)).st_nlink == 1


def _swap_after_poisoning(monkeypatch: pytest.MonkeyPatch, swap: Callable[[], object]) -> None:
    act_after_poisoning(monkeypatch, swap)


def test_folder_swapped_for_a_symlink_before_the_write(
    ctx: AppContext, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: the write followed the new symlink and overwrote the private file outside the outbox."""
    sub = ctx.paths.outbox / "ds" / "sub"
    photo = write_image(sub / "a.png", seed=1)
    private = tmp_path / "private"
    secret = write_image(private / "a.png", seed=2)
    away = tmp_path / "away"
    private_before, photo_before = _tree(private), _sha(photo)

    def swap() -> None:
        os.rename(sub, away)
        sub.symlink_to(private, target_is_directory=True)

    _swap_after_poisoning(monkeypatch, swap)
    outcome = protect_file(photo, ctx)
    assert outcome.state == "failed" and "symlink" in outcome.reason, outcome
    assert _tree(private) == private_before and _sha(secret) == private_before[str(secret)]
    assert _sha(away / "a.png") == photo_before  # nothing written into the folder once it left the outbox
    assert not list(away.glob(".ppd-tmp-*")) and not list(private.glob(".ppd-tmp-*"))
    assert not [p for p in ctx.paths.vault_dir.rglob("*") if p.is_symlink()]


def test_file_swapped_for_a_symlink_is_never_read_or_stored(
    ctx: AppContext, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: poison(outside file) was copied into the outbox and a symlink put into the vault."""
    photo = write_image(ctx.paths.outbox / "ds" / "a.png", seed=1)
    secret = write_image(tmp_path / "secret.png", seed=2)
    secret_sha = _sha(secret)
    photo.unlink()
    photo.symlink_to(secret)
    outcome = protect_file(photo, ctx)
    assert outcome.state == "failed" and "symlink" in outcome.reason
    assert _sha(secret) == secret_sha and photo.is_symlink()
    assert not ctx.vault.has(secret_sha)
    assert not [p for p in ctx.paths.vault_dir.rglob("*") if p.is_symlink()]


def test_a_few_random_instant_races_write_nothing_outside(tmp_path: Path, ppd_env: dict[str, Path]) -> None:
    """The bench scenario (bench/bench_races.py, >= 100 trials) in miniature."""
    from testkit.races import run_symlink_races

    result = run_symlink_races(tmp_path / "races", trials=6, seed=5)
    assert result.trials == 6 and result.violations == [], result.violations


def test_a_subject_mask_in_the_outbox_is_never_patched_nor_quarantined(ppd_env: dict[str, Path]) -> None:
    """A config that points a dataset's masks into the outbox: the daemon's path refuses each mask file
    (failed, one line, not the file's fault), and a file of the dataset fails on the folder itself."""
    masks = ppd_env["outbox"] / "masks"
    mask = write_image(masks / "000.png", seed=2)
    photo = write_image(ppd_env["outbox"] / "shoot" / "000000.png", seed=3)
    (ppd_env["config"] / "config.toml").write_text(f'[datasets.shoot]\nsubject_masks = "{masks}"\n')
    from daemon.datasets.subject_masks import SubjectMaskError, check_config_masks

    ctx = AppContext.open()
    try:
        with pytest.raises(SubjectMaskError, match="inside the outbox"):
            check_config_masks(ctx.config, ctx.paths.outbox)  # what `ppd watch` checks at start
        before = {p: _sha(p) for p in (mask, photo)}
        refused = protect_file(mask, ctx)
        assert refused.state == Outcome.FAILED and not refused.hopeless  # never quarantined for it
        assert "is a subject mask ([datasets.shoot] subject_masks)" in refused.reason
        failed = protect_file(photo, ctx)
        assert failed.state == Outcome.FAILED and not failed.hopeless
        assert "inside the outbox" in failed.reason and "\n" not in failed.reason
        assert {p: _sha(p) for p in (mask, photo)} == before
    finally:
        ctx.close()
