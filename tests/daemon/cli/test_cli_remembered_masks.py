"""The subject-mask folder a dataset remembers (`ppd poison --subject-masks DIR`, issue 25) going missing
(a seventh black-box review, F1): `ppd status` said nothing of it and told the user to run the `ppd poison`
that then stopped (exit 3); no command showed which folder the dataset remembers, and none could change or
clear it. Now status warns (the line config.toml's folder gets) and says what the files wait for, `ppd
dataset show` names the folder, and `ppd dataset set NAME --subject-masks DIR` / `--no-subject-masks`
change or drop it. Real CLI, real files, a real SQLite store."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.context import AppContext
from daemon.datasets.subject_masks import latest_choice
from testkit.photos import MASKED_SIZE, assert_in_corner_off_subject, changed_pixels, make_image, masked_shoot

runner = CliRunner()


def run(*args: str) -> tuple[int, str, str]:
    """Exit status, stdout and stderr, each as one line of words (the console wraps at any width)."""
    result = runner.invoke(app, list(args))
    return result.exit_code, " ".join(result.stdout.split()), " ".join(result.stderr.split())


def remembered(name: str) -> Path | None:
    return held(name)[0]


def held(name: str) -> tuple[Path | None, str | None]:
    """The dataset's remembered mask folder and its spec's id, as the store holds them."""
    ctx = AppContext.open()
    try:
        return ctx.store.dataset_masks(name), (ctx.store.dataset(name) or {}).get("spec_id")
    finally:
        ctx.close()


def test_a_remembered_mask_folder_gone_is_said_shown_and_changed(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot, masks = tmp_path / "shoot" / "kit", tmp_path / "masks" / "kit"
    masked_shoot(shoot, masks, n=3)
    assert run("poison", str(shoot), "--subject-masks", str(masks), "-j", "1")[0] == 0
    moved = masks.rename(tmp_path / "masks" / "kit-old")  # tidied up, or a drive unplugged
    new = make_image(shoot / "000009.png", 29, MASKED_SIZE)  # a new photo of the shoot
    shutil.copy(moved / "000.png", moved / "009.png")
    original = new.read_bytes()

    code, out, err = run("status", "kit")
    assert code == 0 and f"kit's remembered subject masks: {masks} is not a readable folder" in err, err
    assert "`ppd dataset set kit --subject-masks DIR` points it at another folder" in err, err
    waiting = f"1 not patched yet, NOT protected: they wait for its subject masks, and {masks} is not there"
    assert waiting in out, out
    assert "run `ppd poison" not in out, out  # that run stops (exit 3)
    code, out, err = run("poison", str(shoot))
    assert code == 3 and err.count("ppd: error:") == 1 and "--no-subject-masks" in err, err
    assert new.read_bytes() == original  # never without its masks
    code, out, _ = run("dataset", "show", "kit")
    assert code == 0 and f"subject masks: {masks} (remembered) (NOT there now: its files wait for it)" in out

    code, out, err = run("dataset", "set", "kit", "--subject-masks", str(moved))
    assert code == 0 and f"kit: subject masks from {moved}, remembered for later runs" in out, out
    assert "its 3 patched file(s) keep the mark where it was placed" in out, out
    assert run("status", "kit")[2] == ""  # no warning now
    code, out, err = run("poison", str(shoot), "-j", "1")
    assert code == 0 and "patched 1," in out, out + err
    changed = changed_pixels(original, new)
    subject = np.asarray(Image.open(moved / "009.png").convert("L")) > 0
    assert changed.any() and not (changed & subject).any()  # placed off the mask of the folder set

    code, out, _ = run("dataset", "set", "kit", "--no-subject-masks")
    assert code == 0 and f"kit: subject masks dropped (they were {moved})" in out, out
    assert remembered("kit") is None and "subject masks:" not in run("dataset", "show", "kit")[1]
    again = run("dataset", "set", "kit", "--no-subject-masks")[1]
    assert again.startswith("kit: no subject masks remembered"), again


def test_a_masks_change_that_cannot_be_is_refused_with_nothing_changed(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot, masks = tmp_path / "shoot" / "kit", tmp_path / "masks" / "kit"
    masked_shoot(shoot, masks, n=1)
    assert run("poison", str(shoot), "--subject-masks", str(masks))[0] == 0
    inside = ppd_env["outbox"] / "masks"
    inside.mkdir()
    kept = held("kit")
    assert kept[0] == masks.absolute() and kept[1]
    for args, why in [
        (["--subject-masks", str(masks), "--no-subject-masks"], "give one of them"),
        (["--subject-masks", str(tmp_path / "nowhere")], "is not a readable folder"),
        (["--subject-masks", str(inside)], "is inside the outbox"),
        (["--subject-masks", str(tmp_path / "gone"), "--patch-size", "7%"], "is not a readable folder"),
    ]:
        code, out, err = run("dataset", "set", "kit", *args)
        assert code == 2 and err.count("ppd: error:") == 1 and why in err, (args, err)
        assert held("kit") == kept
    (ppd_env["config"] / "config.toml").write_text(f'[datasets.kit]\nsubject_masks = "{masks}"\n')
    code, _, err = run("dataset", "set", "kit", "--no-subject-masks")  # the config's comes first
    assert code == 2 and "[datasets.kit] subject_masks in config.toml" in err, err
    assert "change it there" in err, err
    assert remembered("kit") == masks.absolute()
    assert f"subject masks: {masks} (from [datasets.kit] subject_masks in config.toml)" in run(
        "dataset", "show", "kit")[1]  # fmt: skip


def test_masks_set_before_the_first_file_place_its_corner(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The safety rule: a dataset's spec is never set without its masks. `dataset set NAME --subject-masks`
    before its first file leaves the spec to that file, whose corner is then chosen off the masks (a spec
    set now would have fixed the design's own corner)."""
    (ppd_env["config"] / "config.toml").write_text('[patch]\ndesign = "watermark"\n')  # corner-bound
    porch, masks = ppd_env["outbox"] / "porch", tmp_path / "masks"
    files = masked_shoot(porch, masks, n=3)
    before = {f: f.read_bytes() for f in files}
    code, out, _ = run("dataset", "set", "porch", "--subject-masks", str(masks))
    assert code == 0 and "porch: no spec yet: its first patched file gets the config's" in out, out
    assert "no spec yet" in run("dataset", "show", "porch")[1]
    code, out, err = run("poison", str(porch), "-j", "1")  # no flag: the remembered masks
    assert code == 0 and "porch: mark in the bottom-right corner (from the subject masks" in out, out + err
    ctx = AppContext.open()
    try:
        assert ctx.store.dataset_spec("porch").position == "bottom-right"
        assert (latest_choice(ctx, "porch") or {}).get("source") == "masks"
    finally:
        ctx.close()
    for f in files:
        mask = masks / f"{f.stem[-3:]}.png"
        assert_in_corner_off_subject(changed_pixels(before[f], f), mask, "bottom-right")
