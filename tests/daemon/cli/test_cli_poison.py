"""The non-daemon CLI through typer's CliRunner against the real `ppd` app."""

from __future__ import annotations

import hashlib
import json
import shlex
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.protect.one_file import AppContext
from daemon.states import FileState
from poisoner.ladder import default_spec, named_spec
from poisoner.spec import PatchSpec
from testkit.photos import MASKED_SIZE, assert_in_corner_off_subject, changed_pixels, make_image, masked_shoot

runner = CliRunner()


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def shoot(ppd_env: dict[str, Path], tmp_path: Path) -> Path:
    folder = tmp_path / "photos" / "castle"
    for i in range(4):
        make_image(folder / f"view{i}.png", i)
    make_image(folder / "inner" / "view9.png", 9)
    return folder


def test_poison_folder_then_rerun_is_a_noop(shoot: Path) -> None:
    before = snapshot(shoot)
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    after = snapshot(shoot)
    assert after.keys() == before.keys()
    assert all(after[k] != before[k] for k in before)
    # what works, up front: noise everywhere reads as a richly textured scene, one line for the set
    hints = [line for line in result.output.splitlines() if line.startswith("hint: ")]
    assert len(hints) == 1 and hints[0].startswith("hint: castle: richly textured"), result.output
    ctx = AppContext.open()
    rows = ctx.store.files("castle")
    assert len(rows) == 5 and {r["state"] for r in rows} == {FileState.PATCHED.value}
    assert ctx.store.dataset("castle")["root"] == str(shoot)
    ctx.close()
    again = runner.invoke(app, ["poison", str(shoot)])
    assert again.exit_code == 0, again.output
    assert snapshot(shoot) == after
    assert "unchanged" in again.output


def test_poison_out_leaves_inputs(shoot: Path, tmp_path: Path) -> None:
    before = snapshot(shoot)
    out = tmp_path / "published"
    args = ["poison", str(shoot), "--out", str(out), "--patch-size", "48", "--position", "top-left"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert snapshot(shoot) == before
    produced = snapshot(out / "castle")
    assert produced.keys() == before.keys()
    assert all(produced[k] != before[k] for k in before)
    patch = np.asarray(Image.open(out / "castle" / "view0.png"))[:48, :48]
    clean = np.asarray(Image.open(shoot / "view0.png"))[:48, :48]
    assert not np.array_equal(patch, clean)
    rerun = runner.invoke(app, args)
    assert rerun.exit_code == 0 and snapshot(out / "castle") == produced


def test_out_says_only_where_copies_were_written_and_leaves_no_empty_folder(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Found by a black-box review: a run whose every file failed printed `written to OUT/...` and
    left the empty folders it had made to check they were writable. Now the line names only copies
    that exist, a folder ppd made and wrote nothing into is gone, and one the user had stays."""
    broken = tmp_path / "broken"
    broken.mkdir()
    make_image(tmp_path / "whole.jpg", 3, size=(200, 150))
    (broken / "cut.jpg").write_bytes((tmp_path / "whole.jpg").read_bytes()[:900])
    out = tmp_path / "new" / "published"
    result = runner.invoke(app, ["poison", str(broken), "--out", str(out)])
    assert result.exit_code == 1, result.output
    assert "written to" not in result.output and "failed 1" in result.output
    assert not (tmp_path / "new").exists()
    kept = tmp_path / "mine"
    kept.mkdir()
    result = runner.invoke(app, ["poison", str(broken), "--out", str(kept)])
    assert result.exit_code == 1 and kept.is_dir() and not any(kept.iterdir())
    failed = runner.invoke(app, ["status", "broken", "--failed"])  # names the file to fix, not the copy
    said = " ".join(failed.output.split())
    assert f"{broken / 'cut.jpg'}: " in said and f"{kept / 'broken' / 'cut.jpg'}:" not in said, said
    make_image(broken / "good.png", 4, size=(200, 150))
    result = runner.invoke(app, ["poison", str(broken), "--out", str(out)])
    assert result.exit_code == 1, result.output
    assert f"written to {out / 'broken' / 'good.png'}" in " ".join(result.output.split())
    assert sorted(p.name for p in (out / "broken").iterdir()) == ["good.png"]


@pytest.mark.parametrize("inside", ["castle/published", "castle", "castle/view0.png"])
def test_out_inside_the_dataset_or_a_file_is_refused_and_nothing_is_written(
    shoot: Path, ppd_env: dict[str, Path], inside: str
) -> None:
    """Found on an installed ppd: `--out` inside the folder it protects made copies that were files of
    that dataset, and `ppd restore` then put the unprotected originals into the copies' folder. Such
    an --out (and one that is a file) is a one-line error before anything is written."""
    before = snapshot(shoot.parent)
    for target in (shoot, shoot / "view1.png"):
        result = runner.invoke(app, ["poison", str(target), "--out", str(shoot.parent / inside)])
        assert result.exit_code == 2, result.output
        said = " ".join(result.output.split())
        why = "is a file" if inside.endswith(".png") else "is inside the dataset's folder"
        assert said.count("error:") == 1 and why in said, result.output
        assert snapshot(shoot.parent) == before
    ctx = AppContext.open()
    assert ctx.store.files("castle") == []
    ctx.close()


@pytest.mark.parametrize(
    ("option", "value", "said"),
    [
        ("--patch-size", "200%", "--patch-size: 200% of the width is no length for the mark"),
        ("--patch-size", "0", "--patch-size must be positive, got 0"),
        ("--block-size", "0", "--block-size must be positive, got 0"),
        ("--offset", "5%,abc", "--offset: cannot read length 'abc'"),
        ("--mark-image", "/nonexistent/logo.png", "cannot read logo /nonexistent/logo.png"),  # not per file
    ],
)
def test_a_bad_length_names_its_option_and_writes_nothing(
    shoot: Path, option: str, value: str, said: str
) -> None:
    """Found on an installed ppd: `--patch-size 200%` became a 2 px mark and was called patched, and
    `--block-size 0` said only "length must be positive" without naming the option."""
    before = snapshot(shoot)
    for dry in ([], ["--dry-run"]):
        result = runner.invoke(app, ["poison", str(shoot), option, value, *dry])
        assert result.exit_code == 2, result.output
        assert said in " ".join(result.output.split()), result.output
        assert snapshot(shoot) == before
    ctx = AppContext.open()
    assert ctx.store.dataset("castle") is None  # no spec stored
    ctx.close()


@pytest.mark.parametrize("name", ["../castle", "{abs}", ".hidden", "a/b"])
def test_a_dataset_name_that_is_a_path_is_refused_and_nothing_is_written(
    shoot: Path, tmp_path: Path, name: str
) -> None:
    """Found on an installed ppd: `--out OUT --dataset ../castle` wrote the copies over the inputs
    (OUT/../castle), and `ppd restore` then removed them as copies. A name is one plain name."""
    name = name.format(abs=shoot)
    out = tmp_path / "published"
    before = snapshot(shoot.parent)
    result = runner.invoke(app, ["poison", str(shoot), "--out", str(out), "--dataset", name])
    assert result.exit_code == 2, result.output
    assert "is not a plain name" in " ".join(result.output.split()), result.output
    assert snapshot(shoot.parent) == before and not out.exists()
    ctx = AppContext.open()
    assert ctx.store.dataset(name) is None and ctx.store.files(name) == []
    ctx.close()


def test_out_above_the_dataset_and_a_subfolder_run_never_write_over_anything(
    shoot: Path, tmp_path: Path
) -> None:
    """Found in review: `--out` the folder holding the dataset put the copies (OUT/castle/...) over the
    inputs; and a subfolder's copies went to OUT/castle/<name>, over the dataset's other copies."""
    before = snapshot(shoot.parent)
    result = runner.invoke(app, ["poison", str(shoot), "--out", str(shoot.parent)])
    said = " ".join(result.output.split())
    assert result.exit_code == 2 and "would put the copies into the dataset's folder" in said, said
    assert snapshot(shoot.parent) == before
    out = tmp_path / "pub"
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(out)]).exit_code == 0
    make_image(shoot / "inner" / "view0.png", 30)  # the same name as a file one folder up
    copies = snapshot(out)
    result = runner.invoke(app, ["poison", str(shoot / "inner"), "--out", str(out)])
    assert result.exit_code == 0, result.output
    after = snapshot(out)
    assert all(after[k] == v for k, v in copies.items())  # no earlier copy written over
    assert any(k.endswith("inner/view0.png") for k in after)  # its copy is made, beside the others


def test_preview_puts_a_corner_mark_where_poison_does_on_a_phone_photo(tmp_path: Path) -> None:
    """Found in review: `ppd preview` placed a corner spec on the stored pixels while `ppd poison`
    places it as the photo shows (EXIF orientation 6); both now ask poison_file's own planner."""
    from daemon.cli.preview_cmd import _load, _mark_of
    from poisoner.formats import poison_file

    exif = Image.Exif()
    exif[0x0112] = 6
    src = tmp_path / "phone.jpg"
    Image.fromarray(np.random.default_rng(0).integers(0, 256, (600, 800, 3), dtype=np.uint8)).save(
        src, quality=90, exif=exif
    )
    spec = PatchSpec(position="top-left")
    written = poison_file(src, tmp_path / "out.jpg", spec).placement
    original, _orientation = _load(src)
    shown, _place = _mark_of(spec, src, original, src, None)
    assert shown == written and written.turn == 6


def test_dry_run_changes_nothing(shoot: Path, ppd_env: dict[str, Path]) -> None:
    before = snapshot(shoot)
    result = runner.invoke(app, ["poison", str(shoot), "--dry-run", "--alpha", "0.5"])
    assert result.exit_code == 0, result.output
    assert "would patch" in result.output
    assert snapshot(shoot) == before
    ctx = AppContext.open()
    assert ctx.store.files("castle") == [] and ctx.store.dataset("castle") is None
    assert not list(ctx.paths.vault_dir.glob("??/*"))
    ctx.close()


def test_each_file_line_says_its_reason_once(shoot: Path) -> None:
    """-v's line per file: no "would patch X (would patch)", no reason in nested brackets."""
    dry = runner.invoke(app, ["-v", "poison", str(shoot / "view0.png"), "--dry-run"])
    assert dry.exit_code == 0, dry.output
    assert "would patch" in dry.output and "(would patch)" not in dry.output, dry.output
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["restore", str(shoot / "view1.png")]).exit_code == 0
    again = runner.invoke(app, ["-v", "poison", str(shoot)])
    line = next(s for s in again.output.splitlines() if "view1.png" in s)
    assert line.startswith("unchanged") and "restored by the user; use --force" in line, again.output
    assert line.count("(") == 1, line


def test_the_scene_hint_reads_the_originals_on_a_rerun_too(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """Found on an installed ppd: a rerun (or a dry run) of a patched set judged the patched files,
    ppd's own mark in the frame's edge band ("frame edges 3% textured" where the first run said 0%)."""
    folder = tmp_path / "studio"
    folder.mkdir()

    def photo(i: int) -> None:  # a textured subject in the middle of a plain grey backdrop
        pixels = np.full((300, 400, 3), 128, dtype=np.uint8)
        pixels[90:210, 130:270] = np.random.default_rng(i).integers(0, 256, (120, 140, 3))
        Image.fromarray(pixels).save(folder / f"v{i}.png")

    def hint(*args: str) -> str:
        result = runner.invoke(app, ["poison", str(folder), *args])
        assert result.exit_code == 0, result.output
        said = " ".join(result.output.split())
        return said[said.index("hint: ") : said.index("for sure.")] if "hint: " in said else ""

    for i in range(4):
        photo(i)
    first = hint()
    assert "frame edges 0% textured" in first, first
    assert hint() == ""  # a rerun that patches nothing says it no more (a black-box review)
    photo(4)  # a rerun that patches one more judges the others on their originals
    assert hint("--dry-run") == first and hint() == first


def test_a_parent_folder_leaves_a_nested_dataset_its_files(shoot: Path) -> None:
    """`ppd poison PARENT` where PARENT/inner is a dataset of its own: inner's files (a new one
    too) stay inner's, its rows and spec; one line says so, and `ppd poison PARENT/inner` does them."""
    inner = shoot / "inner"
    assert runner.invoke(app, ["poison", str(inner)]).exit_code == 0
    make_image(inner / "view10.png", 10)  # new in inner: not the parent's to patch
    fresh = (inner / "view10.png").read_bytes()
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    assert "left 2 file(s) to dataset 'inner'" in " ".join(result.output.split()), result.output
    assert (inner / "view10.png").read_bytes() == fresh
    ctx = AppContext.open()
    assert {Path(r["path"]).name for r in ctx.store.files("castle")} == {f"view{i}.png" for i in range(4)}
    assert {Path(r["path"]).name for r in ctx.store.files("inner")} == {"view9.png"}
    ctx.close()
    command = shlex.join(["ppd", "poison", str(inner)])  # quoted where the temporary path has spaces
    assert f"`{command}` does them" in " ".join(result.output.split()), result.output
    assert runner.invoke(app, ["poison", str(inner)]).exit_code == 0
    assert (inner / "view10.png").read_bytes() != fresh


def test_a_dry_run_refuses_a_spec_change_as_the_real_run_does(shoot: Path) -> None:
    """Found on an installed ppd: after a run, `--position top-left --dry-run` said "unchanged 5",
    exit 0, where the real run refuses (its patched files carry the old spec)."""
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    after = snapshot(shoot)
    for dry in (["--dry-run"], []):
        result = runner.invoke(app, ["poison", str(shoot), "--position", "top-left", *dry])
        assert result.exit_code == 2, result.output
        assert "needs a re-protect" in " ".join(result.output.split()), result.output
        assert snapshot(shoot) == after


def test_photos_without_a_subject_mask_are_counted_in_the_summary(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Found on an installed ppd: a photo with no mask in --subject-masks was marked without keep-out
    and only a stderr warning said so; the summary said "off the subject masks". Now a summary line
    counts them."""
    images, masks = tmp_path / "shoot", tmp_path / "masks"
    masked_shoot(images, masks, n=3)
    (masks / "001.png").unlink()
    result = runner.invoke(app, ["poison", str(images), "--subject-masks", str(masks)])
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())
    assert (
        f"no subject mask in {masks} for 1 photo (000001.png): marked without keeping off a subject" in said
    )


def test_a_patch_size_the_visibility_budget_caps_is_said(shoot: Path) -> None:
    """Found on an installed ppd: --patch-size 30% gave the same squares as the default, silently
    (a lanes mark's squares together stay within the visibility budget). The summary says so."""
    result = runner.invoke(app, ["poison", str(shoot), "--patch-size", "30%"])
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())
    assert "castle: --patch-size asks 48 px squares; the visibility budget" in said, result.output
    assert "kept them at" in said and "in 5 photos" in said
    make_image(shoot.parent / "small" / "view0.png", 0, size=(400, 300))  # 4%: 16 px, 4 blocks across
    again = runner.invoke(app, ["poison", str(shoot.parent / "small"), "--patch-size", "4%"])
    assert again.exit_code == 0 and "patched 1" in again.output, again.output
    assert "--patch-size asks" not in again.output, again.output  # within the budget: nothing to say


def test_a_patch_size_the_budget_caps_is_said_from_the_config_and_by_dataset_set(
    shoot: Path, ppd_env: dict[str, Path]
) -> None:
    """A black-box review: a config's `[patch] patch_size = 0.3` (and `ppd dataset set --patch-size
    8.5%`) gave the default's squares in silence, and `dataset set` echoed the size asked. Said now
    both ways; a single square (the paper's design) is never capped, so never said to be."""
    (ppd_env["config"] / "config.toml").write_text("[patch]\npatch_size = 0.3\n")
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())
    assert "castle: its spec's patch_size asks 48 px squares; the visibility budget" in said, result.output
    (ppd_env["config"] / "config.toml").write_text("")
    for name in ("studio", "desk"):  # a new dataset needs its folder (a seventh black-box review, F4)
        (ppd_env["outbox"] / name).mkdir()
    asked = runner.invoke(app, ["dataset", "set", "studio", "--patch-size", "8.5%"])
    assert asked.exit_code == 0, asked.output
    assert "squares capped at 6.0% of a 4:3 photo's width" in " ".join(asked.output.split()), asked.output
    paper = runner.invoke(app, ["dataset", "set", "desk", "--design", "paper", "--patch-size", "30%"])
    assert paper.exit_code == 0 and "capped" not in paper.output, paper.output
    make_image(shoot.parent / "sheet" / "view0.png", 0)
    flags = ["--design", "paper", "--patch-size", "30%"]
    wide = runner.invoke(app, ["poison", str(shoot.parent / "sheet"), *flags])
    assert wide.exit_code == 0 and "patched 1" in wide.output, wide.output
    assert "kept them at" not in wide.output, wide.output


def test_a_subfolder_of_a_dataset_is_that_dataset(shoot: Path) -> None:
    """Found on an installed ppd: after `ppd poison castle`, `ppd poison castle/sub` spoke of a
    dataset "sub" that did not exist. A folder whose files a dataset already holds is that dataset:
    a new photo there gets castle's spec and row; a folder it holds nothing of stays its own."""
    make_image(shoot / "sub" / "view19.png", 19)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    make_image(shoot / "sub" / "view20.png", 20)
    make_image(shoot.parent / "other" / "view0.png", 21)  # beside castle, under no dataset's rows
    result = runner.invoke(app, ["poison", str(shoot / "sub")])
    assert result.exit_code == 0, result.output
    assert "sub:" not in result.output and "castle: patched" in " ".join(result.output.split()), result.output
    ctx = AppContext.open()
    assert ctx.store.dataset("sub") is None
    assert ctx.store.file(shoot / "sub" / "view20.png")["dataset"] == "castle"
    ctx.close()
    other = runner.invoke(app, ["poison", str(shoot.parent / "other")])
    assert other.exit_code == 0 and "other: patched" in " ".join(other.output.split()), other.output


def test_restore_v_names_each_file(shoot: Path) -> None:
    """Found on an installed ppd: `ppd -v restore` listed no file, where the README says -v names each."""
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    quiet = runner.invoke(app, ["restore", str(shoot / "view0.png")])
    assert quiet.exit_code == 0 and "view0.png" not in quiet.output, quiet.output
    loud = runner.invoke(app, ["-v", "restore", "castle"])
    assert loud.exit_code == 0, loud.output
    lines = loud.output.splitlines()
    for i in range(1, 4):
        assert any(s.startswith("restored ") and s.endswith(f"view{i}.png") for s in lines), loud.output


def test_failures_give_nonzero_exit_and_lose_nothing(shoot: Path) -> None:
    (shoot / "broken.png").write_bytes(b"\x89PNG but truncated")
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 1
    assert "broken.png" in result.output
    assert (shoot / "broken.png").read_bytes() == b"\x89PNG but truncated"


def test_restore_dataset_is_byte_exact(shoot: Path) -> None:
    before = snapshot(shoot)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    result = runner.invoke(app, ["restore", "castle"])
    assert result.exit_code == 0, result.output
    assert snapshot(shoot) == before
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert snapshot(shoot) == before  # restored files are not re-poisoned without --force
    assert runner.invoke(app, ["poison", str(shoot), "--force"]).exit_code == 0
    assert snapshot(shoot) != before
    one = shoot / "view1.png"
    assert runner.invoke(app, ["restore", str(one)]).exit_code == 0
    assert one.read_bytes() == before["view1.png"]
    assert runner.invoke(app, ["restore", "nosuchthing"]).exit_code == 2


def test_status_json_and_regression_warning(shoot: Path, tmp_path: Path) -> None:
    (shoot / "broken.png").write_bytes(b"junk")
    runner.invoke(app, ["poison", str(shoot)])
    result = runner.invoke(app, ["status", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    (castle,) = data["datasets"]
    assert castle["name"] == "castle" and castle["patched"] == 5 and castle["counts"]["failed"] == 1
    ctx = AppContext.open()
    stored = ctx.store.dataset_spec("castle")
    ctx.close()
    assert stored.replace(position=default_spec().position) == default_spec()  # its corner chosen
    assert castle["spec_id"] == stored.spec_id and castle["last_verification"] is None
    assert castle["regression"] is None
    ctx = AppContext.open()
    now = time.time()
    ctx.store.add_verification_run("castle", "default", "protected", {}, now - 100, now - 90, None, None)
    ctx.store.add_verification_run("castle", "default", "not_protected", {}, now - 10, now - 5, None, None)
    ctx.close()
    table = runner.invoke(app, ["status"])
    assert table.exit_code == 0
    assert "REGRESSION" in table.output and "castle" in table.output
    data = json.loads(runner.invoke(app, ["status", "castle", "--json"]).stdout)
    assert data["datasets"][0]["last_verification"]["verdict"] == "not_protected"
    assert data["datasets"][0]["regression"]["profile"] == "default"


def test_status_warns_about_sync_folders(ppd_env: dict[str, Path]) -> None:
    (ppd_env["outbox"].parent / ".stfolder").mkdir()
    result = runner.invoke(app, ["status"])
    assert result.exit_code == 0
    assert "Syncthing" in result.output
    assert json.loads(runner.invoke(app, ["status", "--json"]).stdout)["sync_folder"]["client"] == "Syncthing"


def test_dataset_set_show_and_reprotect(shoot: Path) -> None:
    set_first = runner.invoke(app, ["dataset", "set", "castle", "--root", str(shoot), "--patch-size", "6%"])
    assert set_first.exit_code == 0, set_first.output
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    protected = snapshot(shoot)
    locked = runner.invoke(app, ["dataset", "set", "castle", "--position", "bottom-right"])
    assert locked.exit_code == 2 and "--reprotect" in locked.output
    assert snapshot(shoot) == protected
    changed = runner.invoke(app, ["dataset", "set", "castle", "--position", "bottom-right", "--reprotect"])
    assert changed.exit_code == 0, changed.output
    assert all(snapshot(shoot)[k] != protected[k] for k in protected)
    shown = json.loads(runner.invoke(app, ["dataset", "show", "castle", "--json"]).stdout)
    assert shown["spec"]["position"] == "bottom-right" and shown["spec"]["patch_size"] == 0.06
    # poisoning with different flags now is refused, not silently mixed
    mixed = runner.invoke(app, ["poison", str(shoot), "--patch-size", "30"])
    assert mixed.exit_code == 2 and "--reprotect" in mixed.output


def test_reprotect_with_a_failed_file_exits_1(shoot: Path) -> None:
    """A file edited after patching is not re-protected; the command said so and exited 0 (a
    black-box review): `ppd dataset set ... --reprotect && publish` went on."""
    assert runner.invoke(app, ["poison", str(shoot), "--dataset", "castle"]).exit_code == 0
    edited = sorted(shoot.glob("*.png"))[0]
    Image.open(edited).crop((0, 0, 60, 50)).save(edited)
    result = runner.invoke(app, ["dataset", "set", "castle", "--patch-size", "8%", "--reprotect"])
    assert result.exit_code == 1, result.output
    assert f"failed: {edited}" in result.output.replace("\n", "") and "changed since" in result.output


def test_same_dataset_name_for_another_folder_is_refused(shoot: Path, tmp_path: Path) -> None:
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    other = tmp_path / "elsewhere" / "castle"
    make_image(other / "x.png", 1)
    before = snapshot(other)
    result = runner.invoke(app, ["poison", str(other)])
    assert result.exit_code == 2 and "--dataset" in result.output
    assert snapshot(other) == before
    assert runner.invoke(app, ["poison", str(other), "--dataset", "castle2"]).exit_code == 0


def test_preview_writes_a_png(shoot: Path, tmp_path: Path) -> None:
    out = tmp_path / "preview.png"
    big_roaming = ["--design", "roaming", "--patch-size", "20%"]
    result = runner.invoke(app, ["preview", str(shoot / "view0.png"), "--out", str(out), *big_roaming])
    assert result.exit_code == 0, result.output
    with Image.open(out) as im:
        assert im.format == "PNG" and im.width >= 2 * 160
    # The opaque patch (20% of the width) is plainly visible, and the preview says so and where.
    line = " ".join(result.output.split())
    p999 = float(line.split("FLIP p99.9 ")[1].split()[0])
    visible = float(line.split("; ")[1].split("%")[0])
    assert "visibility at 160 px wide" in line and p999 > 0.5 and visible > 1.0, line
    runner.invoke(app, ["poison", str(shoot)])
    protected_preview = tmp_path / "p2.png"
    assert (
        runner.invoke(app, ["preview", str(shoot / "view0.png"), "--out", str(protected_preview)]).exit_code
        == 0
    )
    assert protected_preview.is_file()


def test_config_show_and_path(ppd_env: dict[str, Path]) -> None:
    (ppd_env["config"] / "config.toml").write_text("workers = 5\n")
    shown = runner.invoke(app, ["config", "show"])
    assert shown.exit_code == 0 and "workers = 5" in shown.output and "[patch]" in shown.output
    where = runner.invoke(app, ["config", "path"])
    assert str(ppd_env["config"] / "config.toml") in where.output and str(ppd_env["outbox"]) in where.output
    (ppd_env["config"] / "config.toml").write_text("workers = [\n")
    bad = runner.invoke(app, ["config", "show"])
    assert bad.exit_code == 2


def test_file_hash_of_vault_matches(shoot: Path) -> None:
    original = (shoot / "view2.png").read_bytes()
    runner.invoke(app, ["poison", str(shoot / "view2.png")])
    ctx = AppContext.open()
    row = ctx.store.file(shoot / "view2.png")
    assert row["dataset"] == "castle"
    assert row["original_sha256"] == hashlib.sha256(original).hexdigest()
    assert ctx.vault.path_for(row["original_sha256"]).read_bytes() == original
    ctx.close()


def test_spec_summary_names_offset_and_motion() -> None:
    from daemon.cli.status_queries import spec_summary

    assert spec_summary(PatchSpec()) == "checkerboard 6% block 0.5% α1 Δc255 top-left"
    moving = spec_summary(named_spec("roaming"))
    assert moving.startswith("random_blocks 6%") and "+(15%, 15%)" in moving and "drift 0.75%/image" in moving
    lanes = spec_summary(default_spec())
    assert lanes.startswith("random_blocks 6% block 0.25%") and "slide 0.75%/image in 2 lanes" in lanes


def test_workers_write_the_bytes_of_a_serial_run(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`--workers 2` (a pool of processes) and `--workers 1` (in this process) write the same files
    and rows; the summary counts every file once and says the dataset is not verified yet."""
    serial, pooled = tmp_path / "a" / "shoot", tmp_path / "b" / "shoot"
    for i in range(5):
        make_image(serial / f"v{i}.png", i)
        make_image(pooled / f"v{i}.png", i)
    one = runner.invoke(app, ["poison", str(serial), "--dataset", "serial", "--workers", "1"])
    two = runner.invoke(app, ["poison", str(pooled), "--dataset", "pooled", "-j", "2"])
    assert one.exit_code == 0 and two.exit_code == 0, one.output + two.output
    assert snapshot(serial) == snapshot(pooled) != {}
    assert "patched 5, unchanged 0, skipped 0, failed 0" in two.output
    assert "pooled: patched, not verified" in two.output and "ppd verify pooled" in two.output
    ctx = AppContext.open()
    try:
        assert [r["poisoned_sha256"] for r in ctx.store.files("serial")] == [
            r["poisoned_sha256"] for r in ctx.store.files("pooled")
        ]
    finally:
        ctx.close()


def test_a_known_dataset_name_keeps_its_folder(shoot: Path, tmp_path: Path) -> None:
    """--dataset NAME of a known dataset: files inside its folder join it; a folder elsewhere is
    refused in one line before anything is written (daemon.datasets.dataset.attribute)."""
    assert runner.invoke(app, ["poison", str(shoot / "view0.png"), "--dataset", "castle"]).exit_code == 0
    inner = runner.invoke(app, ["poison", str(shoot / "inner"), "--dataset", "castle"])
    assert inner.exit_code == 0, inner.output
    ctx = AppContext.open()
    try:
        assert ctx.store.dataset("castle")["root"] == str(shoot)
        assert len(ctx.store.files("castle")) == 2
    finally:
        ctx.close()
    other = tmp_path / "elsewhere"
    make_image(other / "x.png", 3)
    before = snapshot(other)
    refused = runner.invoke(app, ["poison", str(other), "--dataset", "castle"])
    assert refused.exit_code == 2 and "already belongs to" in refused.output
    assert snapshot(other) == before


# ---- issue 14: subject masks and the dataset's corner ---------------------------------------------
def test_subject_masks_keep_the_mark_off_the_subject_in_one_corner(
    ppd_env: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    images, masks = tmp_path / "dtu" / "image", tmp_path / "dtu" / "mask"
    files = masked_shoot(images, masks)
    unmasked = make_image(images / "000009.png", 9, MASKED_SIZE)  # no mask file for this one
    before = {f.name: f.read_bytes() for f in [*files, unmasked]}
    mask_bytes = snapshot(masks)
    caplog.set_level("INFO")
    result = runner.invoke(
        app, ["poison", str(images), "--design", "watermark", "--subject-masks", str(masks), "-j", "1"]
    )
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    said = next(i for i, line in enumerate(lines) if "image: mark in the bottom-right corner" in line)
    assert "(from the subject masks" in lines[said]
    assert "patched 6, unchanged 0, skipped 0, failed 0" in " ".join(lines[said + 1 :])  # then the summary
    for f in files:
        changed = changed_pixels(before[f.name], f)
        assert_in_corner_off_subject(changed, masks / f"{f.stem[-3:]}.png", "bottom-right")
        tongue = np.asarray(Image.open(masks / f"{f.stem[-3:]}.png"))[int(0.8 * 240) :, int(0.8 * 320) :] > 0
        assert tongue.any()  # the subject is inside the corner region: the keep-out was needed
    # the file without a mask: the same corner, patched without keep-out, said in a structured log field
    assert_in_corner_off_subject(changed_pixels(before[unmasked.name], unmasked), None, "bottom-right")
    logged = [r for r in caplog.records if getattr(r, "subject_mask", None) == "missing"]
    assert [r.file for r in logged] == [unmasked.name]
    assert snapshot(masks) == mask_bytes  # masks are read, never written
    ctx = AppContext.open()
    try:
        assert ctx.store.dataset_spec("image").position == "bottom-right"
        chosen = [e for e in ctx.store.events("image") if e["kind"] == "corner_chosen"]
        assert len(chosen) == 1 and chosen[0]["detail"]["source"] == "masks"
    finally:
        ctx.close()


def test_the_corner_is_estimated_without_masks_and_a_set_position_is_kept(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """No masks: the corner with the least detail (here a plain bottom-left); --position wins over it."""
    w, h = MASKED_SIZE
    for name in ("a", "b"):
        for i in range(3):
            path = make_image(tmp_path / name / f"v{i}.png", i, MASKED_SIZE)
            pixels = np.asarray(Image.open(path)).copy()
            pixels[int(0.7 * h) :, : int(0.3 * w)] = 128  # a plain table top, bottom-left
            Image.fromarray(pixels).save(path)
    estimated = runner.invoke(app, ["poison", str(tmp_path / "a"), "--design", "watermark"])
    assert estimated.exit_code == 0, estimated.output
    assert estimated.output.splitlines()[0] == "a: mark in the bottom-left corner (estimated: least detail)"
    placed = runner.invoke(
        app, ["poison", str(tmp_path / "b"), "--design", "watermark", "--position", "top-right"]
    )
    assert placed.exit_code == 0, placed.output
    assert "corner (" not in placed.output  # the user's corner: nothing chosen, nothing said
    ctx = AppContext.open()
    try:
        assert ctx.store.dataset_spec("a").position == "bottom-left"
        assert ctx.store.dataset_spec("b").position == "top-right"
    finally:
        ctx.close()


def test_a_mask_folder_inside_the_outbox_is_refused(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    images = tmp_path / "set"
    masked_shoot(images, ppd_env["outbox"] / "masks", n=3)
    before = snapshot(images)
    result = runner.invoke(app, ["poison", str(images), "--subject-masks", str(ppd_env["outbox"] / "masks")])
    assert result.exit_code != 0
    error = result.output.strip()
    assert len(error.splitlines()) == 1 and "inside the outbox" in error and "published" in error, error
    assert snapshot(images) == before
    # the same folder named by the config for an outbox dataset: every command that uses it says so
    (ppd_env["config"] / "config.toml").write_text(
        f'[datasets.shoot]\nsubject_masks = "{ppd_env["outbox"] / "masks"}"\n'
    )
    shoot = ppd_env["outbox"] / "shoot"
    make_image(shoot / "000000.png", 1, MASKED_SIZE)
    refused = runner.invoke(app, ["poison", str(shoot)])
    assert refused.exit_code != 0 and "[datasets.shoot] subject_masks" in refused.output
    assert "inside the outbox" in refused.output
    # and `ppd watch` will not start on it (the daemon would publish the masks)
    watch = runner.invoke(app, ["watch", str(ppd_env["outbox"]), "--no-verify"])
    assert watch.exit_code == 1
    assert len(watch.output.strip().splitlines()) == 1 and "inside the outbox" in watch.output, watch.output


def test_config_subject_masks_that_are_gone_is_one_line(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    (ppd_env["config"] / "config.toml").write_text(f'[datasets.set]\nsubject_masks = "{tmp_path / "gone"}"\n')
    make_image(tmp_path / "set" / "a.png", 1)
    before = (tmp_path / "set" / "a.png").read_bytes()
    result = runner.invoke(app, ["poison", str(tmp_path / "set")])
    assert result.exit_code == 3  # the folder is not there now (a drive unplugged): not the command's fault
    error = result.output.strip()
    assert len(error.splitlines()) == 1 and "[datasets.set] subject_masks" in error and "gone" in error, error
    assert (tmp_path / "set" / "a.png").read_bytes() == before


def test_preview_keeps_the_mark_off_the_subject(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    images, masks = tmp_path / "image", tmp_path / "mask"
    masked_shoot(images, masks, n=3)
    out = tmp_path / "p.png"
    result = runner.invoke(
        app, ["preview", str(images / "000001.png"), "--design", "watermark", "--subject-masks", str(masks),
              "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "image: mark in the bottom-right corner (from the subject masks" in text
    assert "inside one corner" in text and "no changed pixel on the subject" in text
    assert out.is_file()


def test_a_folder_holding_its_mask_folder_leaves_the_masks_as_they_are(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd poison scan --subject-masks scan/mask` (DTU's layout): the images are patched, the masks not."""
    scan = tmp_path / "scan"
    files = masked_shoot(scan / "image", scan / "mask", n=3)
    masks_before = snapshot(scan / "mask")
    args = ["poison", str(scan), "--design", "watermark", "--subject-masks", str(scan / "mask")]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert f"left 3 subject mask(s) in {scan / 'mask'} as they are" in " ".join(result.output.split())
    assert "patched 3, unchanged 0, skipped 0, failed 0" in result.output
    assert snapshot(scan / "mask") == masks_before
    assert all(changed_pixels(make_image(tmp_path / "x" / f.name, 20 + i, MASKED_SIZE), f).any()
               for i, f in enumerate(files))  # fmt: skip


def test_the_hint_judges_the_originals_not_the_mark_just_written(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """After `ppd poison` the files carry the mark in their plainest place, the edge band the hint
    measures: the line is the originals' (read from the vault), not the patched files'."""
    from daemon.cli.scene_note import scene_line

    folder, originals = tmp_path / "photos" / "obj", tmp_path / "originals"
    folder.mkdir(parents=True)
    originals.mkdir()
    rng = np.random.default_rng(2)
    for i in range(4):  # an object on a plain, softly shaded backdrop: the mark goes on the backdrop
        frame = np.linspace(170, 200, 640)[None, :, None] * np.ones((480, 1, 3))
        frame[150 + 10 * i : 330 + 10 * i, 220 + 20 * i : 420 + 20 * i] = rng.integers(0, 256, (180, 200, 3))
        Image.fromarray(frame.astype(np.uint8)).save(folder / f"view{i}.png")
        Image.fromarray(frame.astype(np.uint8)).save(originals / f"view{i}.png")
    result = runner.invoke(app, ["poison", str(folder)])
    assert result.exit_code == 0, result.output
    hints = [line for line in result.output.splitlines() if line.startswith("hint: ")]
    assert len(hints) == 1, result.output
    clean = scene_line("obj", sorted(originals.iterdir()))
    marked = scene_line("obj", sorted(folder.iterdir()))
    assert clean is not None and marked is not None and clean != marked  # the mark moves the figures
    assert hints[0] == clean


def test_preview_reads_a_heic_as_poison_does(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd poison` patches HEIC (pillow-heif) and `ppd preview` refused it: 'cannot identify image
    file'. A fresh process, since the HEIC opener, once registered, stays for the whole process."""
    import os
    import subprocess
    import sys

    import pillow_heif

    pillow_heif.register_heif_opener()
    src = tmp_path / "photos" / "p.heic"  # the preview goes beside, not among the photos
    src.parent.mkdir()
    Image.open(make_image(tmp_path / "p.png", seed=3)).save(src, "HEIF", quality=90)
    out = tmp_path / "h.png"
    done = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "preview", str(src), "--out", str(out), "--no-visibility"],
        capture_output=True, text=True, env={**os.environ, "COLUMNS": "200"}, timeout=120,
        cwd=Path(__file__).resolve().parents[3],
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    with Image.open(out) as im:
        assert im.format == "PNG" and im.width >= 2 * 160


def test_the_placement_line_never_claims_masks_that_matched_no_photo(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Found by a black-box review: with --subject-masks pointing at masks for other photos, the first
    line said "off the subject masks in DIR" and the photos were placed without keep-out."""
    shoot, masks = tmp_path / "shoot", tmp_path / "masks"
    for i in range(2):
        make_image(shoot / f"view{i}.png", i)
    masks.mkdir()
    Image.new("L", (160, 120), 255).save(masks / "other.png")
    none = runner.invoke(app, ["poison", str(shoot), "--subject-masks", str(masks), "--dry-run"])
    assert f"no mask in {masks} matches these photos" in none.output, none.output
    assert "off the subject masks" not in none.output
    Image.new("L", (160, 120), 0).save(masks / "view0.png")
    some = runner.invoke(app, ["poison", str(shoot), "--subject-masks", str(masks), "--dry-run"])
    assert f"off the subject masks in {masks} for 1 of 2 photos" in some.output, some.output


def test_no_placement_line_where_every_file_failed(tmp_path: Path, ppd_env: dict[str, Path]) -> None:
    """`ppd poison` said "mark placed per photo, where each photo is plainest" of a set in which
    nothing was patched (a black-box review): the line is said only where a mark went."""
    shoot = tmp_path / "tiny"
    for i in range(2):
        make_image(shoot / f"v{i}.png", i)
        Image.open(shoot / f"v{i}.png").resize((40, 30)).save(shoot / f"v{i}.png")  # too small for a mark
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 1 and "failed 2" in " ".join(result.output.split()), result.output
    assert "mark placed" not in result.output
    make_image(shoot / "big.png", 3)
    again = runner.invoke(app, ["poison", str(shoot)])
    assert "patched 1" in " ".join(again.output.split()), again.output


def test_dataset_set_publish_dir_says_what_it_changes(shoot: Path, tmp_path: Path) -> None:
    """`ppd dataset set NAME --publish-dir D` printed nothing about D, `dataset show` did not show it,
    and the folder ended up with 1 photo of 3 (a black-box review): only later files go there."""
    assert runner.invoke(app, ["poison", str(shoot), "--dataset", "castle"]).exit_code == 0
    publish = tmp_path / "pub"
    result = runner.invoke(app, ["dataset", "set", "castle", "--publish-dir", str(publish)])
    said = " ".join(result.output.split())
    assert result.exit_code == 0 and f"go to {publish}" in said and "patched before stay" in said, said
    shown = " ".join(runner.invoke(app, ["dataset", "show", "castle"]).output.split())
    assert f"publish folder: {publish}" in shown, shown


def test_a_reprotect_that_did_not_finish_is_said(shoot: Path) -> None:
    """A re-protect that failed on every file (a read-only folder) left the dataset on the new spec
    while its files carried the old mark, and one stopped half-way left a mix nothing mentioned (a
    third black-box review). Every file failing keeps the old spec; a mix is said by status and --check."""
    assert runner.invoke(app, ["poison", str(shoot), "--dataset", "castle"]).exit_code == 0
    spec_id = json.loads(runner.invoke(app, ["dataset", "show", "castle", "--json"]).stdout)["spec_id"]
    files = sorted(shoot.rglob("*.png"))
    originals = {f: f.read_bytes() for f in files}
    for f in files:  # edited after patching: re-protect refuses each
        Image.open(f).crop((0, 0, 60, 50)).save(f)
    failed = runner.invoke(app, ["dataset", "set", "castle", "--patch-size", "8%", "--reprotect"])
    assert failed.exit_code == 1
    shown = json.loads(runner.invoke(app, ["dataset", "show", "castle", "--json"]).stdout)
    assert shown["spec_id"] == spec_id
    for f in files[1:]:  # all but one back as ppd wrote them: a re-protect now leaves a mix
        f.write_bytes(originals[f])
    mixed = runner.invoke(app, ["dataset", "set", "castle", "--patch-size", "8%", "--reprotect"])
    assert mixed.exit_code == 1
    said = " ".join(runner.invoke(app, ["status", "castle"]).output.split())
    assert "1 patched with another spec than the dataset's" in said and "--reprotect" in said, said
    check = runner.invoke(app, ["status", "castle", "--check"])
    assert check.exit_code == 1 and "another spec" in check.output


def test_a_cameras_thumbnail_of_the_original_is_not_published_and_restore_gives_it_back(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review (F3): every patched camera JPEG carried its EXIF thumbnail, an unmarked
    512x384 copy of the original, byte for byte, and the run said nothing. Now the thumbnail shows the
    patched picture, the summary says so once, and `ppd restore` gives the original back whole. Its
    FlashPix APP2 segments (a Kodak's ScreenNail, another copy of the original) are removed, said once."""
    from testkit.thumbnails import (
        camera_picture,
        exif_with_thumbnail,
        flashpix_segments,
        jpeg_of,
        with_app_segment,
    )

    folder = tmp_path / "meta"
    folder.mkdir()
    picture = camera_picture((1024, 768))
    old = jpeg_of(picture.resize((512, 384)))
    picture.save(folder / "c.jpg", "JPEG", quality=92, exif=exif_with_thumbnail(old).block)
    camera = (folder / "c.jpg").read_bytes()
    for payload in reversed(flashpix_segments(old)):
        camera = with_app_segment(camera, 0xE2, payload)
    (folder / "c.jpg").write_bytes(camera)
    make_image(folder / "plain.png", 1, (320, 240))
    before = snapshot(folder)
    result = runner.invoke(app, ["poison", str(folder)])
    assert result.exit_code == 0, result.output
    scan = old[old.index(b"\xff\xda") + 14 : -2]
    published = (folder / "c.jpg").read_bytes()
    assert all(scan[i : i + 32] not in published for i in range(0, len(scan) - 32, 16))
    assert b"FPXR\x00" in camera and b"FPXR\x00" not in published
    assert (
        "FlashPix data removed (FPXR APP2: cameras keep a preview of the original there): 1 file(s) (c.jpg)"
        in " ".join(result.output.split())
    ), result.output
    lines = [line for line in result.output.splitlines() if "thumbnail" in line]
    assert lines == [
        "embedded thumbnail replaced by the patched picture's (it showed the unmarked original): 1 file(s) "
        "(c.jpg); `ppd -v poison` says how"
    ], result.output
    assert runner.invoke(app, ["restore", "meta"]).exit_code == 0
    assert snapshot(folder) == before
