"""What a person sees on the terminal: one-line errors at any width, exit codes, the vocabulary of
states, status at 80 and 40 columns, the shared spec options. Real `ppd` processes in a subprocess
(COLUMNS=40, a 150-character TMPDIR) where the terminal matters; CliRunner elsewhere."""

from __future__ import annotations

import dataclasses
import json
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.cli.errors import os_error_text, reason_text
from daemon.cli.options import SpecOptions, designs, spec_fields
from daemon.cli.output import KeyValueFormatter
from daemon.protect.one_file import AppContext
from daemon.states import FileState, Protection, dataset_protection, protection_text
from poisoner.ladder import default_spec, named_specs
from poisoner.spec import PatchSpec
from testkit.photos import make_image

REPO = Path(__file__).resolve().parents[3]
runner = CliRunner()


@pytest.fixture
def narrow_env(tmp_path: Path, ppd_env: dict[str, Path]) -> dict[str, str]:
    """The environment of a 40-column terminal with a 150-character TMPDIR (and ppd's folders)."""
    long_tmp = tmp_path / ("t" * 60) / ("m" * 60)
    long_tmp = Path(str(long_tmp) + "/" + "x" * max(1, 150 - len(str(long_tmp)) - 1))
    long_tmp.mkdir(parents=True)
    assert len(str(long_tmp)) >= 150
    env = dict(os.environ, COLUMNS="40", LINES="20", TMPDIR=str(long_tmp), PYTHONPATH=str(REPO))
    env.pop("PPD_LOG_LEVEL", None)
    return env


def ppd(env: dict[str, str], *args: str, columns: int | None = None) -> subprocess.CompletedProcess[str]:
    if columns is not None:
        env = dict(env, COLUMNS=str(columns))
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", *args], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip


def one_error_line(proc: subprocess.CompletedProcess[str]) -> str:
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("ppd: error: "), lines[0]
    assert "Traceback" not in proc.stderr and "╭" not in proc.stderr
    return lines[0]


# ---- errors: one unwrapped line, one style, exit code ---------------------------------------
def test_errors_are_one_line_at_40_columns_with_a_long_tmpdir(narrow_env: dict[str, str]) -> None:
    missing = Path(narrow_env["TMPDIR"]) / "no such folder of images"
    proc = ppd(narrow_env, "experiment", str(missing), "--sweep", "P=10,20")
    line = one_error_line(proc)
    assert proc.returncode == 2 and "not a folder of images" in line and str(missing) in line

    usage = ppd(narrow_env, "poison", "--no-such-flag")
    assert usage.returncode == 2 and "--no-such-flag" in one_error_line(usage)

    preview = ppd(narrow_env, "preview", str(missing / "a.jpg"))
    assert preview.returncode == 2 and "does not exist" in one_error_line(preview)

    unknown = ppd(narrow_env, "restore", "no-such-dataset")
    assert unknown.returncode == 2 and "no-such-dataset" in one_error_line(unknown)


def test_a_device_or_pipe_given_to_poison_is_bad_input_and_makes_no_dataset(
    narrow_env: dict[str, str], tmp_path: Path
) -> None:
    """`ppd poison /dev/null` made a dataset "dev" holding one failed file (a black-box review)."""
    fifo = tmp_path / "shot.jpg"
    os.mkfifo(fifo)
    for target in ("/dev/null", str(fifo)):
        for command in ("poison", "preview"):
            proc = ppd(narrow_env, command, target)
            assert proc.returncode == 2 and "not a photo, video or folder" in one_error_line(proc)
    status = ppd(narrow_env, "status", "--json")
    assert status.returncode == 0 and json.loads(status.stdout)["datasets"] == []


def test_version_and_help_read_well(narrow_env: dict[str, str]) -> None:
    version = ppd(narrow_env, "--version")
    assert version.returncode == 0 and version.stdout.startswith("ppd ")
    assert version.stdout.split()[1][0].isdigit()
    top = ppd(narrow_env, "--help", columns=80)
    assert "Exit status:" in top.stdout and "130  interrupted" in top.stdout
    for command in (["poison"], ["preview"], ["dataset", "set"], ["status"], ["restore"], ["watch"]):
        shown = ppd(narrow_env, *command, "--help", columns=80)
        assert shown.returncode == 0, shown.stderr
        text = shown.stdout
        assert "<bool>" not in text and "poisoner." not in text and "{paths}" not in text, text
        assert max(len(line) for line in text.splitlines()) <= 80
        if command[0] in ("poison", "preview", "dataset", "status", "restore"):
            assert "Examples:" in text and f"ppd {' '.join(command)}" in text


def test_os_errors_say_what_to_do() -> None:
    import errno

    denied = OSError(errno.EACCES, "Permission denied", "/photos/castle/.ppd-tmp-x1.jpg")
    assert os_error_text(denied) == "folder not writable: /photos/castle; use --out DIR"
    assert os_error_text(OSError(errno.ENOSPC, "No space left", "/out/a.jpg")).startswith("disk full")
    raw = "[Errno 13] Permission denied: '/photos/castle/.ppd-tmp-_isopwap.jpg'"
    assert reason_text(raw) == "folder not writable: /photos/castle; use --out DIR"
    assert reason_text("truncated JPEG") == "truncated JPEG"
    # a temporary written beside the file by a descriptor names no folder: the file's is said (a
    # black-box review: "folder not writable: ."), and restore, which has no --out, does not offer it
    beside = "[Errno 13] Permission denied: '.ppd-tmp-L0a1b2c3d4e5f.jpg'"
    said = reason_text(beside, Path("/photos/castle"), hint_out=False)
    assert said == "folder not writable: /photos/castle", said


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_is_one_line(tmp_path: Path, narrow_env: dict[str, str]) -> None:
    folder = tmp_path / "ro"
    make_image(folder / "a.png", 1)
    folder.chmod(0o555)
    try:
        proc = ppd(narrow_env, "poison", str(folder))
    finally:
        folder.chmod(0o755)
    assert proc.returncode == 3 and "folder not writable" in one_error_line(proc)


# ---- the vocabulary ---------------------------------------------------------------------------
def _run(verdict: str) -> dict[str, object]:
    return {"verdict": verdict, "finished_at": time.time()}


def test_dataset_protection_is_never_more_than_the_verdicts() -> None:
    patched = {FileState.PATCHED.value: 3, "files": 3}
    assert dataset_protection({"files": 2, "failed": 2}, {}) == (Protection.NOTHING_PATCHED, [])
    assert dataset_protection(patched, {}) == (Protection.PATCHED_NOT_VERIFIED, [])
    assert dataset_protection({"patched": 3}, {}) == (Protection.PATCHED_NOT_VERIFIED, [])  # after migration
    both = {"default": _run("protected"), "hardened": _run("protected")}
    assert dataset_protection(patched, both) == (Protection.PROTECTED, ["default", "hardened"])
    one_fails = {"default": _run("protected"), "hardened": _run("not_protected")}
    assert dataset_protection(patched, one_fails) == (Protection.NOT_PROTECTED, ["hardened"])
    # the masked attacker counts like the others (issue 25, round 2: the per-photo mark holds it)
    masked_fails = {**both, "masked": _run("not_protected")}
    assert dataset_protection(patched, masked_fails) == (Protection.NOT_PROTECTED, ["masked"])
    masked_holds = {**both, "masked": _run("protected")}
    held = (Protection.PROTECTED, ["default", "hardened", "masked"])
    assert dataset_protection(patched, masked_holds) == held
    assert dataset_protection(patched, {"masked": _run("weak")}) == (Protection.WEAK, ["masked"])
    assert dataset_protection(patched, {"default": _run("weak")}) == (Protection.WEAK, ["default"])
    crashed = {"default": _run("sfm_crashed")}
    assert dataset_protection(patched, crashed) == (Protection.UNVERIFIABLE, ["default"])
    # a crash beside profiles that held is still no protection (as verifier.verdict.overall: the diff
    # review found status and --check saying "protected" where `ppd verify` said sfm_crashed)
    one_crashed = {**both, "global": _run("sfm_crashed")}
    assert dataset_protection(patched, one_crashed) == (Protection.UNVERIFIABLE, ["global"])
    fails_and_crashed = {**one_fails, "global": _run("sfm_crashed")}
    assert dataset_protection(patched, fails_and_crashed)[0] == Protection.NOT_PROTECTED
    assert protection_text(Protection.PROTECTED, ["default"]) == "protected under default"
    assert protection_text(Protection.NOT_PROTECTED, ["hardened"]) == "NOT protected (hardened)"


@pytest.fixture
def shoot(ppd_env: dict[str, Path], tmp_path: Path) -> Path:
    folder = tmp_path / "photos" / "castle"
    for i in range(3):
        make_image(folder / f"view{i}.png", i)
    return folder


def test_poison_summary_says_patched_and_what_to_run(shoot: Path) -> None:
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    assert "patched 3, unchanged 0, skipped 0, failed 0" in result.output
    assert "castle: patched, not verified: run `ppd verify castle`" in result.output
    assert "protected 3" not in result.output
    dry = runner.invoke(app, ["poison", str(shoot), "--dry-run", "--force"])
    assert "dry run, nothing changed" in dry.output and "protect protected" not in dry.output


def test_rerun_after_restore_says_left_unprotected(shoot: Path) -> None:
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["restore", "castle"]).exit_code == 0
    again = runner.invoke(app, ["poison", str(shoot)])
    assert "left unprotected (restored by you): 3; use --force to protect them again" in again.output


def test_out_prints_the_real_output_place(shoot: Path, tmp_path: Path) -> None:
    out = tmp_path / "pub"
    result = runner.invoke(app, ["poison", str(shoot), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert f"written to {out / 'castle'}{os.sep}" in result.output
    single = runner.invoke(app, ["poison", str(shoot / "view1.png"), "--out", str(tmp_path / "one")])
    assert f"written to {tmp_path / 'one' / 'view1.png'}" in single.output


def test_status_failed_lists_each_file_with_its_reason(shoot: Path) -> None:
    (shoot / "broken.png").write_bytes(b"\x89PNG but truncated")
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 1
    listed = runner.invoke(app, ["status", "castle", "--failed"])
    assert listed.exit_code == 0, listed.output
    lines = [line for line in listed.output.splitlines() if "broken.png" in line]
    assert len(lines) == 1 and lines[0].strip().startswith(str(shoot / "broken.png") + ": ")
    assert len(lines[0].split(": ", 1)[1].strip()) > 3
    data = json.loads(runner.invoke(app, ["status", "castle", "--failed", "--json"]).stdout)
    assert [Path(f["path"]).name for f in data["datasets"][0]["failed_files"]] == ["broken.png"]


@pytest.mark.parametrize("columns", [80, 40])
def test_status_fits_and_keeps_the_verdict_whole(
    shoot: Path, ppd_env: dict[str, Path], narrow_env: dict[str, str], columns: int
) -> None:
    poisoned = runner.invoke(app, ["poison", str(shoot), "--dataset", "a-rather-long-dataset-name"])
    assert poisoned.exit_code == 0, poisoned.output
    ctx = AppContext.open()
    now = time.time()  # verified after the poison: a verdict on today's pixels (issue 25)
    ctx.store.add_verification_run(
        "a-rather-long-dataset-name", "default", "protected", {}, now, now + 1, None, None
    )
    ctx.store.add_verification_run(
        "a-rather-long-dataset-name", "hardened", "not_protected", {}, now + 2, now + 3, None, None
    )
    ctx.close()
    proc = ppd(narrow_env, "status", columns=columns)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert max(len(line) for line in lines) <= columns, proc.stdout
    assert any("NOT protected" in line for line in lines), proc.stdout  # the words, whole, on one line
    assert "…" not in proc.stdout
    flat = "".join(line.strip(" │|┃") for line in lines)
    assert "a-rather-long-dataset-name" in flat.replace(" ", "").replace("│", "")
    long = ppd(narrow_env, "status", "--long", columns=columns)
    assert "hardened: NOT protected" in long.stdout and "default: protected" in long.stdout


def _status_of_two(
    shoot: Path, tmp_path: Path, env: dict[str, str], names: list[str], columns: int
) -> tuple[subprocess.CompletedProcess[str], list[str]]:
    """`ppd status` at `columns` of two datasets named `names` (shoot and a copy): the process and the
    lines of its table (or list), not the next steps under it, which name the datasets too."""
    other = shutil.copytree(shoot, tmp_path / "other")
    for folder, name in zip((shoot, other), names, strict=True):
        assert runner.invoke(app, ["poison", str(folder), "--dataset", name]).exit_code == 0
    proc = ppd(env, "status", columns=columns)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    steps = min(i for i, line in enumerate(lines) if line.startswith(tuple(f"{n}:" for n in names)))
    return proc, lines[:steps]


@pytest.mark.parametrize("columns", [30, 40, 50, 80])
def test_status_shows_each_dataset_name_whole(
    shoot: Path, narrow_env: dict[str, str], tmp_path: Path, columns: int
) -> None:
    """At 30 to 80 columns `ppd status` folded a long name inside its column, between the borders and
    the protection words: two such names could not be told apart, nor one copied (a black-box review).
    The name has priority: whole on a line of the table, or on a line of its own when it cannot be."""
    names = ["client-shoot-2026-studio-north-wing", "client-shoot-2026-studio-south-wing"]
    proc, shown = _status_of_two(shoot, tmp_path, narrow_env, names, columns)
    for name in names:
        assert any(name in line for line in shown), proc.stdout
    assert all(len(line) <= columns or line in names for line in shown), proc.stdout
    assert "…" not in proc.stdout and "patched, not verified" in " ".join(" ".join(shown).split())


@pytest.mark.parametrize("columns", [40, 120])
def test_status_shows_a_name_with_an_emoji_code_as_it_is(
    shoot: Path, narrow_env: dict[str, str], tmp_path: Path, columns: int
) -> None:
    """rich turned a name's ":thumbs_up:" into its picture, in the table (120 columns) and in the list
    (40: the long name cannot be whole in the table), so the name shown was not the dataset's."""
    names = ["x:thumbs_up:y[red]", "client-shoot-2026:smile:-studio-north-wing"]
    proc, shown = _status_of_two(shoot, tmp_path, narrow_env, names, columns)
    for name in names:  # whole in the table or the list, and in the next steps under it
        assert any(name in line for line in shown), proc.stdout
        assert f"{name}: run" in " ".join(proc.stdout.split()), proc.stdout
    assert ("│" in proc.stdout) == (columns == 120), proc.stdout  # the table, or the list


def test_status_json_carries_the_protection(shoot: Path) -> None:
    runner.invoke(app, ["poison", str(shoot)])
    data = json.loads(runner.invoke(app, ["status", "--json"]).stdout)
    (castle,) = data["datasets"]
    assert castle["protection"]["state"] == Protection.PATCHED_NOT_VERIFIED.value
    assert castle["protection"]["next"] == "run `ppd verify castle`"


# ---- spec options -----------------------------------------------------------------------------
def test_every_patchspec_field_has_a_flag(narrow_env: dict[str, str]) -> None:
    shown = ppd(narrow_env, "poison", "--help", columns=200).stdout
    for f in spec_fields():
        flag = "--block-size" if f.name == "block_size" else "--" + f.name.replace("_", "-")
        assert flag in shown, flag
    assert "--version" not in {f.name for f in dataclasses.fields(PatchSpec)}
    flat = "".join(shown.split())  # click wraps long help lines, hyphens included
    for name in designs():
        assert name in flat, name


def test_designs_and_flags_express_the_paper_and_the_default() -> None:
    assert SpecOptions(design="paper").build(default_spec()) == PatchSpec()
    assert SpecOptions(design="default").build(PatchSpec()) == default_spec()
    values = (
        ("pattern", "random_blocks"), ("patch_size", "6%"), ("block_size", "0.25%"), ("motion", "slide"),
        ("motion_step", "0.75%"), ("motion_span", "14%"), ("lanes", 2), ("slide_run", 8),
        ("position", "auto"),
    )  # fmt: skip
    assert SpecOptions(values=values).build(PatchSpec()) == default_spec()
    moved = SpecOptions(design="paper", values=(("motion", "orbit"), ("motion_step", "8"))).build(
        default_spec()
    )
    assert moved.motion == "orbit" and moved.motion_step == 8 and moved.pattern == "checkerboard"
    # The named kinds of protection are designs too (the corner watermark, the roaming texture).
    assert SpecOptions(design="watermark").build(default_spec()) == named_specs()["watermark"]
    assert SpecOptions(design="roaming").build(PatchSpec()).motion == "drift"


def test_flags_on_the_command_line_reach_the_spec(shoot: Path) -> None:
    result = runner.invoke(
        app, ["poison", str(shoot), "--design", "paper", "--motion", "drift", "--motion-step", "6",
              "--offset", "10,12"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    ctx = AppContext.open()
    spec = ctx.store.dataset_spec("castle")
    ctx.close()
    assert spec == PatchSpec(motion="drift", motion_step=6, offset=(10, 12))
    bad = runner.invoke(app, ["preview", str(shoot / "view0.png"), "--design", "nope"])
    assert bad.exit_code == 2 and "unknown design" in bad.output


# ---- the daemon's log lines --------------------------------------------------------------------
def test_daemon_log_lines_are_key_value() -> None:
    import logging

    args = ("/home/me/PPD Outbox",)
    record = logging.LogRecord("daemon.watch.watcher", logging.INFO, __file__, 1, "watching %s", args, None)
    record.outbox = "/home/me/PPD Outbox"  # said in msg already: not repeated
    record.workers = 2
    record.dataset = "trip x"
    line = KeyValueFormatter().format(record)
    expected = 'level=info logger=daemon.watch.watcher msg="watching /home/me/PPD Outbox" workers=2 dataset="trip x"'  # noqa: E501
    assert line == expected
    assert "\x1b[" not in line


# ---- preview: what a viewer sees ---------------------------------------------------------------
def test_preview_of_a_phone_photo_is_upright_and_labelled(shoot: Path, tmp_path: Path) -> None:
    from poisoner.preview import GAP, LABEL_HEIGHT

    photo = tmp_path / "phone" / "IMG_0001.jpg"
    photo.parent.mkdir()
    rng = np.random.default_rng(1)
    im = Image.fromarray(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8))  # stored landscape
    exif = im.getexif()
    exif[0x0112] = 6  # shown rotated: portrait 120 x 160
    im.save(photo, exif=exif, quality=95)
    out = tmp_path / "p.png"
    result = runner.invoke(app, ["preview", str(photo), "--out", str(out), "--design", "paper"])
    assert result.exit_code == 0, result.output
    assert f"preview written to {out}" in result.output
    with Image.open(out) as shown:
        pixels = np.asarray(shown.convert("RGB"))
    assert pixels.shape[1] == 2 * 120 + GAP  # two portrait panels side by side
    assert (pixels[LABEL_HEIGHT + 160 - 1, :120] != 32).any()  # the panel is 160 tall (portrait)
    assert (pixels[:LABEL_HEIGHT] > 200).any()  # captions


def test_preview_of_a_video_shows_a_frame(shoot: Path, tmp_path: Path) -> None:
    import av

    clip = tmp_path / "videos" / "clip.mp4"  # the preview goes beside, not among the videos
    clip.parent.mkdir()
    rng = np.random.default_rng(2)
    with av.open(str(clip), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = 160, 96, "yuv420p"
        for i in range(5):
            rgb = rng.integers(0, 256, (96, 160, 3), dtype=np.uint8)
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24").reformat(format="yuv420p")
            frame.pts = i
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    out = tmp_path / "clip.png"
    result = runner.invoke(app, ["preview", str(clip), "--out", str(out)])
    assert result.exit_code == 0, result.output
    with Image.open(out) as shown:
        assert shown.width >= 2 * 160


def test_a_damaged_store_is_one_line(narrow_env: dict[str, str], ppd_env: dict[str, Path]) -> None:
    (ppd_env["data"] / "ppd.sqlite3").write_bytes(bytes(range(256)) * 20)
    proc = ppd(narrow_env, "status")
    line = one_error_line(proc)
    # 3, "ppd cannot work here", as `ppd --help` says (it exited 2, a usage error: a black-box review)
    assert proc.returncode == 3 and "store" in line.lower()


def test_a_pipe_with_no_width_keeps_each_line_whole(shoot: Path, narrow_env: dict[str, str]) -> None:
    """Into a pipe or a file with no COLUMNS there is no width: rich's guess (80) broke the command a
    status or summary line tells you to run across two lines. With COLUMNS set it is still kept."""
    name = "a-very-long-dataset-name-for-the-kitchen-shoot-in-spring"
    assert runner.invoke(app, ["poison", str(shoot), "--dataset", name]).exit_code == 0
    unset = {k: v for k, v in narrow_env.items() if k != "COLUMNS"}
    proc = ppd(unset, "status")
    assert proc.returncode == 0, proc.stderr
    assert f"{name}: run `ppd verify {name}`" in proc.stdout.splitlines(), proc.stdout
    narrow = ppd(narrow_env, "status").stdout.splitlines()  # COLUMNS=40: wrapped at spaces, not in a command
    assert f"{name}:" in narrow and f"`ppd verify {name}`" in narrow, narrow


def test_watch_of_a_file_is_bad_input(tmp_path: Path, narrow_env: dict[str, str]) -> None:
    """`ppd watch photo.jpg` said "cannot set up ppd's folders: File exists" (1, an environment
    failure) after making ppd's folders; it is bad input (2), said as such, and nothing is made."""
    photo = make_image(tmp_path / "d" / "r_0.png", 0)
    data = Path(narrow_env["PPD_DATA_DIR"])
    shutil.rmtree(data)
    proc = ppd(narrow_env, "watch", str(photo))
    assert proc.returncode == 2, proc.stderr
    assert "is a file, not a folder" in one_error_line(proc)
    assert not data.exists()


def test_watch_of_a_missing_folder_is_bad_input(tmp_path: Path, narrow_env: dict[str, str]) -> None:
    """`ppd watch ~/Picturs` (a typo) made the folder and said "ppd watch ready" while the photos sat
    in the real one (a black-box review). A folder named on the command line must exist."""
    data = Path(narrow_env["PPD_DATA_DIR"])
    shutil.rmtree(data)
    proc = ppd(narrow_env, "watch", str(tmp_path / "nonexistent_dir"))
    assert proc.returncode == 2, proc.stderr
    assert "does not exist: make it first, or check its name" in one_error_line(proc)
    assert not (tmp_path / "nonexistent_dir").exists() and not data.exists()


def test_status_says_restored_photos_are_not_protected(shoot: Path) -> None:
    """Found by a black-box review: after `ppd restore` of one photo, `ppd status` said only "run
    ppd verify" for the dataset; the restored photo is published unprotected, and the overview says
    so with the command that patches it again (only `ppd poison` said it before)."""
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["restore", str(shoot / "view0.png")]).exit_code == 0
    status = " ".join(runner.invoke(app, ["status"]).output.split())  # at any terminal width
    assert "castle: 1 restored by you, NOT protected" in status, status
    assert f"`ppd poison {shlex.quote(str(shoot))} --force` patches them again" in status


def test_restored_out_copies_are_not_called_unprotected(shoot: Path, tmp_path: Path) -> None:
    """Found in review: restoring an `--out` dataset removes its copies (the inputs were never
    changed); the hint then told the user to run an in-place `ppd poison --force`, which would have
    patched the originals themselves. Nothing unprotected is published there: no hint."""
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(tmp_path / "pub")]).exit_code == 0
    assert runner.invoke(app, ["restore", "castle"]).exit_code == 0
    status = runner.invoke(app, ["status"])
    assert status.exit_code == 0 and "restored by you" not in " ".join(status.output.split()), status.output


def test_a_name_that_is_not_utf8_fails_its_file_and_the_run_still_ends_in_its_summary(
    narrow_env: dict[str, str], tmp_path: Path
) -> None:
    """A black-box review: after the file's one-line refusal a traceback (UnicodeEncodeError from the
    store) replaced the summary, and the name showed as caf\\udce9.png."""
    shoot = tmp_path / "shoot"
    good = make_image(shoot / "ok.png", 1, size=(200, 150))
    odd = Path(os.fsdecode(os.fsencode(shoot) + b"/caf\xe9.png"))
    odd.write_bytes(good.read_bytes())
    proc = ppd(narrow_env, "poison", str(shoot))
    assert proc.returncode == 1 and "Traceback" not in proc.stderr and "╭" not in proc.stderr, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "patched 1," in out and "failed 1" in out and "shoot: patched, not verified" in out, out
    assert "--failed" not in out  # no row names it: only its own line says why
    err = " ".join(proc.stderr.split())
    assert err.count("caf\\xe9.png: the file name is not valid UTF-8") == 1 and "udce9" not in err, err


@pytest.mark.parametrize("verbose", [0, 2])
def test_a_librarys_python_warning_is_not_printed_beside_the_one_line_messages(verbose: int) -> None:
    """A black-box review: Pillow's `UserWarning: Corrupt EXIF data` and numpy's `RuntimeWarning: Mean of
    empty slice` reached stderr as two raw lines each. They are logged, and shown with -vv only."""
    code = (
        "import warnings\nfrom daemon.cli.output import setup_logging\n"
        f"setup_logging({verbose})\nwarnings.warn('Corrupt EXIF data', UserWarning)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, PYTHONPATH=str(REPO)))  # fmt: skip
    assert proc.returncode == 0
    assert ("Corrupt EXIF data" in proc.stderr) == (verbose >= 2), proc.stderr


def test_a_narrow_status_table_still_shows_a_failure(narrow_env: dict[str, str], tmp_path: Path) -> None:
    """At 40 columns the files/patched/failed columns drop; a dataset with a failed file read only
    "patched, not verified" (a black-box review)."""
    shoot = tmp_path / "tty"
    make_image(shoot / "a.png", 1, size=(200, 150))
    (shoot / "b.jpg").write_text("not a photo")
    assert ppd(narrow_env, "poison", str(shoot)).returncode == 1
    said = ppd(narrow_env, "status").stdout
    table = " ".join(said[: said.index("└")].replace("│", " ").split())  # the table alone
    assert "┃ failed" not in said and "1 failed" in table, said


def test_the_daemons_lines_carry_a_time_unless_they_go_to_the_journal(tmp_path: Path) -> None:
    """`nohup ppd watch > log`: its lines had no time stamp (only a terminal got one; a black-box
    review). journald, recognised by JOURNAL_STREAM, adds its own."""
    code = (
        "import logging\nfrom daemon.cli.output import setup_logging\n"
        "setup_logging(0, daemon=True)\nlogging.getLogger('daemon.x').info('hello')\n"
    )
    log = tmp_path / "watch.log"
    for journal in (False, True):
        with open(log, "w") as fh:
            st = os.fstat(fh.fileno())
            env = dict(os.environ, PYTHONPATH=str(REPO))
            env.pop("JOURNAL_STREAM", None)
            if journal:
                env["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
            subprocess.run([sys.executable, "-c", code], cwd=REPO, stderr=fh, env=env, check=True, timeout=60)
        line = log.read_text()
        assert 'msg=hello' in line and ("ts=20" in line) != journal, line


def test_a_librarys_python_warning_in_a_worker_is_not_printed_either() -> None:
    """The diff review: `ppd poison --workers 2` printed Pillow's `UserWarning: Tag data larger than file`
    raw from its workers, which set up their logging themselves (daemon.protect.pool.log_like_caller)."""
    code = (
        "import logging, warnings\nfrom daemon.protect.pool import log_like_caller\n"
        "log_like_caller(logging.Formatter('%(message)s'))\nwarnings.warn('Tag data larger than file')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, PYTHONPATH=str(REPO)))  # fmt: skip
    assert proc.returncode == 0 and "Tag data larger than file" not in proc.stderr, proc.stderr


def test_a_command_in_backticks_is_never_broken_across_lines() -> None:
    """At 40 columns `ppd poison /long/path --force` was split after the path (a black-box review): a
    command to copy stays on one line, the words around it still wrap."""
    import io

    from rich.console import Console

    from daemon.cli.output import print_line

    buffer = io.StringIO()
    out = Console(file=buffer, width=40, force_terminal=True, color_system=None, soft_wrap=True)
    command = "`ppd poison /tmp/shoots/kitchen/day2 --force`"
    print_line(out, f"kitchen: 3 restored by you, NOT protected: {command} patches them again")
    lines = buffer.getvalue().splitlines()
    assert any(command in line for line in lines), lines
    assert len(lines) >= 3 and all(len(line) <= 40 for line in lines if "`" not in line), lines


def test_verbose_after_the_command_is_the_groups(shoot: Path) -> None:
    """`ppd restore X -v` said "No such option: -v" (a black-box review): -v after a command means
    what it means before it, except for a command with a -v of its own (`ppd store rebuild -v`)."""
    from daemon.cli.group import _verbosity_first

    assert runner.invoke(app, ["poison", str(shoot), "--dataset", "castle"]).exit_code == 0
    restored = runner.invoke(app, ["restore", "castle", "-v"])
    assert restored.exit_code == 0, restored.output
    assert f"restored {sorted(shoot.glob('*.png'))[0]}" in restored.output
    assert _verbosity_first(app_group(), ["store", "rebuild", "-v"]) == ["store", "rebuild", "-v"]
    moved = _verbosity_first(app_group(), ["poison", "x", "-vv", "--", "-v"])
    assert moved == ["-vv", "poison", "x", "--", "-v"]


def app_group():  # the click group typer builds for `ppd`
    import typer.main

    return typer.main.get_command(app)
