"""daemon.datasets.subject_masks: where a dataset's subject masks come from, and its corner chosen once
(real files, a real store; the pixels are poisoner.subject's, tested in tests/poisoner/test_subject.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from PIL import Image

from daemon.datasets.subject_masks import (
    SubjectMaskError,
    check_mask_folder,
    choice_text,
    corner_line,
    latest_choice,
    place_corner,
)
from daemon.protect.one_file import AppContext, protect_file
from poisoner.ladder import named_spec
from poisoner.subject import CornerChoice
from testkit.photos import MASKED_SIZE, masked_shoot

CORNER_CONFIG = '[patch]\ndesign = "watermark"\n'


def test_a_mask_folder_must_be_a_readable_folder_outside_the_outbox(tmp_path: Path) -> None:
    outbox, masks = tmp_path / "outbox", tmp_path / "masks"
    (outbox / "shoot").mkdir(parents=True)
    masks.mkdir()
    assert check_mask_folder(masks, outbox) == masks
    with pytest.raises(SubjectMaskError, match="is not a readable folder"):
        check_mask_folder(tmp_path / "gone", outbox)
    with pytest.raises(SubjectMaskError, match="inside the outbox"):
        check_mask_folder(outbox / "shoot", outbox)
    (tmp_path / "link").symlink_to(outbox / "shoot")  # a link from outside still lands inside
    with pytest.raises(SubjectMaskError, match=r"^\[datasets.x\] subject_masks: .* inside the outbox"):
        check_mask_folder(tmp_path / "link", outbox, "[datasets.x] subject_masks")


def test_the_corner_is_judged_on_the_readable_files(tmp_path: Path) -> None:
    files = masked_shoot(tmp_path / "image", tmp_path / "mask", n=3)
    broken = tmp_path / "image" / "000007.png"
    broken.write_bytes(files[0].read_bytes()[:200])
    placed = place_corner(named_spec("watermark"), [broken, *files], tmp_path / "mask")
    assert placed.spec.position == "bottom-right" and placed.choice.source == "masks"
    nothing = place_corner(named_spec("watermark"), [broken], None)
    assert nothing.spec == named_spec("watermark") and nothing.choice.source == "default"


def test_the_corner_in_words() -> None:
    choice = CornerChoice("bottom-right", "estimated", {"bottom-right": 0.1})
    assert corner_line("lego", choice) == "lego: mark in the bottom-right corner (estimated: least detail)"
    assert choice_text("lego", {"corner": "top-left", "source": "default"}) == (
        "lego: mark in the top-left corner (default: no masks, no estimate)"
    )
    assert choice_text("lego", None) is None


def test_a_first_file_that_fails_still_leaves_the_corner_to_its_neighbours(ppd_env: dict[str, Path]) -> None:
    """The daemon's first file of a new dataset cannot be read: the dataset (created to record the
    failure) still gets its corner from the files next to it, not a default that would then be locked."""
    (ppd_env["config"] / "config.toml").write_text(CORNER_CONFIG)
    shoot = ppd_env["outbox"] / "shoot"
    files = masked_shoot(shoot, ppd_env["config"] / "unused-masks", n=3)
    w, h = MASKED_SIZE
    for f in files:  # a plain, detail-free top-right corner: the estimate's pick
        pixels = Image.open(f).convert("RGB")
        pixels.paste((120, 120, 120), (int(0.7 * w), 0, w, int(0.3 * h)))
        pixels.save(f)
    broken = shoot / "000000-broken.png"
    broken.write_bytes(files[0].read_bytes()[:200])
    ctx = AppContext.open()
    try:
        assert protect_file(broken, ctx).state == "failed"
        assert ctx.store.dataset_spec("shoot").position == "top-right"
        chosen = latest_choice(ctx, "shoot")
        assert chosen is not None and chosen["source"] == "estimated"
        assert protect_file(files[1], ctx).state == "patched"
        assert ctx.store.dataset_spec("shoot").position == "top-right"  # chosen once
    finally:
        ctx.close()
