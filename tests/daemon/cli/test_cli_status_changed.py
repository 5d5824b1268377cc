"""`ppd status` checks each file patched in place against the size and time ppd wrote (a black-box
review, 2026-12-07: with no daemon running, originals copied back over patched files were counted
patched, and nothing warned). A file touched but not changed stops counting once a run sees it."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import write_image

runner = CliRunner()


def counts(name: str) -> dict[str, int]:
    result = runner.invoke(app, ["status", name, "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.output)["datasets"][0]["counts"]


def test_an_original_copied_back_is_not_counted_patched(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    shoot = ppd_env["outbox"] / "dtu"
    originals = tmp_path / "orig"
    for i in range(3):
        write_image(originals / f"v{i}.png", seed=i)
    shutil.copytree(originals, shoot)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert counts("dtu")["patched"] == 3 and counts("dtu").get("changed", 0) == 0
    shutil.copy(originals / "v1.png", shoot / "v1.png")  # the unprotected original back, no daemon
    now = counts("dtu")
    assert now["patched"] == 2 and now["changed"] == 1 and now["files"] == 3
    text = " ".join(runner.invoke(app, ["status"]).output.split())
    assert "dtu: 1 changed since ppd patched them (size or time), maybe NOT protected now" in text, text
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0  # patches it again
    assert counts("dtu")["patched"] == 3 and counts("dtu").get("changed", 0) == 0


def test_a_patched_photo_deleted_is_no_longer_counted(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A black-box review: a patched photo deleted (or moved away) with no daemon running still
    counted as a patched file of its dataset."""
    shoot = tmp_path / "shoot"
    for i in range(3):
        write_image(shoot / f"v{i}.png", seed=i)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    (shoot / "v1.png").unlink()
    now = counts("shoot")
    assert now["files"] == 2 and now["patched"] == 2 and now["gone"] == 1, now
    text = " ".join(runner.invoke(app, ["status", "shoot"]).output.split())
    assert "files 2: patched 2; not counted: deleted or moved away since patched 1" in text, text


def test_a_touched_file_is_changed_until_a_run_sees_its_bytes_are_ppds(ppd_env: dict[str, Path]) -> None:
    shoot = ppd_env["outbox"] / "set"
    write_image(shoot / "a.png", seed=3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    st = (shoot / "a.png").stat()
    os.utime(shoot / "a.png", ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))
    assert counts("set")["changed"] == 1
    again = runner.invoke(app, ["poison", str(shoot)])
    assert again.exit_code == 0 and "unchanged 1" in " ".join(again.output.split())
    assert counts("set").get("changed", 0) == 0 and counts("set")["patched"] == 1


def test_status_check_gates_publishing(ppd_env: dict[str, Path]) -> None:
    """`ppd --help` says exit 1 when the verdict is not 'protected', and `ppd status` always exited 0,
    so `ppd status X && publish` published anyway (a black-box review). A report still exits 0;
    `--check` exits 1 and says why until every file is patched and a verification says protected."""
    import time

    from daemon.protect.one_file import AppContext

    shoot = ppd_env["outbox"] / "set"
    for i in range(2):
        write_image(shoot / f"v{i}.png", seed=i)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["status", "set"]).exit_code == 0  # a report
    unverified = runner.invoke(app, ["status", "set", "--check"])
    assert runner.invoke(app, ["status", "set", "--check", "--json"]).exit_code == 1  # a script's gate too
    assert unverified.exit_code == 1
    assert "not ready to publish: set: patched, not verified" in " ".join(unverified.output.split())
    ctx = AppContext.open()
    try:
        now = time.time() + 1
        ctx.store.add_verification_run("set", "default", "protected", {}, now, now + 1, None, None)
        one = runner.invoke(app, ["status", "set", "--check"])  # one attacker of the five measured
        said = " ".join(one.output.split())
        assert one.exit_code == 1 and "not verified under hardened, published, global, masked" in said, said
        for profile in ("hardened", "published", "global", "masked"):
            ctx.store.add_verification_run("set", profile, "protected", {}, now, now + 1, None, None)
    finally:
        ctx.close()
    assert runner.invoke(app, ["status", "set", "--check"]).exit_code == 0
    ready = json.loads(runner.invoke(app, ["status", "--json"]).stdout)  # --check's answer, for scripts
    assert ready["ready_to_publish"] is True and ready["datasets"][0]["not_ready"] == []
    (shoot / "v2.jpg").write_bytes(b"\xff\xd8 not really")  # a file not patched yet
    later = json.loads(runner.invoke(app, ["status", "--json"]).stdout)
    assert later["ready_to_publish"] is False and "1 not patched yet" in later["datasets"][0]["not_ready"]
    late = runner.invoke(app, ["status", "set", "--check"])
    assert late.exit_code == 1 and "1 not patched yet" in " ".join(late.output.split()), late.output


def test_verify_takes_every_profile_given(ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    """`ppd verify X -p masked -p default` ran only the last (a black-box review): every one given is
    now read, each checked (a bad one refused even when another follows it). What reaches the
    verification is captured (the COLMAP runs themselves are other tests')."""
    from daemon.cli import verify_cmd

    bad_first = runner.invoke(app, ["verify", "nosuch", "-p", "bogus", "-p", "default"])
    assert bad_first.exit_code == 2 and "--profile must be one of" in " ".join(bad_first.output.split())
    seen: list[tuple[str, ...]] = []

    def capture(*args: object) -> None:
        seen.append(args[3])  # type: ignore[arg-type]
        raise SystemExit(0)

    monkeypatch.setattr(verify_cmd, "_verify_stored", capture)
    runner.invoke(app, ["verify", "set", "-p", "masked", "-p", "default"])
    assert seen == [("default", "masked")]


def test_verify_says_the_files_it_did_not_measure(
    ppd_env: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """A black-box review: with 5 of 10 photos restored, `ppd verify` said "protected", exit 0, and
    nothing of the 5 originals it had left out. The line after a verification says them."""
    from daemon.cli.verify_cmd import _say_left_out
    from daemon.protect.one_file import AppContext, restore_file

    shoot = ppd_env["outbox"] / "half"
    for i in range(4):
        write_image(shoot / f"v{i}.png", seed=i)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    ctx = AppContext.open()
    try:
        _say_left_out(ctx, "half")
        assert capsys.readouterr().err == ""  # every file measured: nothing to say
        for i in (0, 2):
            assert restore_file(ctx, shoot / f"v{i}.png").state == "restored"
        _say_left_out(ctx, "half")
    finally:
        ctx.close()
    said = " ".join(capsys.readouterr().err.split())
    assert (
        "not verified, and NOT protected: 2 restored by you (only the 2 patched files were measured)" in said
    )


def test_an_out_copy_deleted_is_gone_and_its_photo_not_patched_yet(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: a `--out` copy deleted still counted patched, and nothing said its photo
    had no protected copy any more; `ppd poison --out` again makes it."""
    shoot, out = tmp_path / "shoot", tmp_path / "out"
    for i in range(3):
        write_image(shoot / f"v{i}.png", seed=i)
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(out)]).exit_code == 0
    assert counts("shoot")["patched"] == 3
    (out / "shoot" / "v1.png").unlink()
    now = counts("shoot")
    assert (now["files"], now["patched"], now["gone"], now["untracked"]) == (3, 2, 1, 1), now
    again = runner.invoke(app, ["poison", str(shoot), "--out", str(out)])
    assert again.exit_code == 0 and (out / "shoot" / "v1.png").is_file()
    now = counts("shoot")
    assert (now["files"], now["patched"], now.get("gone", 0), now["untracked"]) == (3, 3, 0, 0), now


def test_out_after_patching_in_place_copies_the_patched_files(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: `ppd poison d4` then `ppd poison d4 --out pub` wrote nothing, said
    "unchanged 1" and exited 0, and pub did not exist. The copies are ppd's output byte for byte."""
    shoot, out = tmp_path / "d4", tmp_path / "pub"
    for i in range(2):
        write_image(shoot / f"v{i}.png", seed=i)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    result = runner.invoke(app, ["poison", str(shoot), "--out", str(out)])
    assert result.exit_code == 0 and "written to" in result.output, result.output
    for i in range(2):
        assert (out / "d4" / f"v{i}.png").read_bytes() == (shoot / f"v{i}.png").read_bytes()
    assert counts("d4")["patched"] == 4  # two in place, two copies
    assert runner.invoke(app, ["restore", "d4"]).exit_code == 0
    assert not (out / "d4" / "v0.png").exists()  # a restore takes the copies back too


def test_a_photo_patched_in_place_and_copied_with_out_is_one_view_to_verify(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The diff review: after `ppd poison DIR` then `ppd poison DIR --out OUT`, verify staged every
    view twice (identical images), which distorts its verdict and doubles its time."""
    from daemon.protect.one_file import AppContext, dataset_pairs

    shoot, out = tmp_path / "scan", tmp_path / "pub"
    for i in range(3):
        write_image(shoot / f"v{i}.png", seed=i)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert runner.invoke(app, ["poison", str(shoot), "--out", str(out)]).exit_code == 0
    ctx = AppContext.open()
    try:
        pairs = dataset_pairs(ctx, "scan")
    finally:
        ctx.close()
    assert len(pairs) == 3 and len({original for original, _ in pairs}) == 3, pairs


def test_check_of_a_dataset_whose_folder_is_gone_says_why(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """`ppd status NAME --check` exited 1 and said nothing when NAME's folder was gone (a second
    black-box review); `--help` promises one line saying why."""
    import shutil

    shoot = tmp_path / "gone"
    write_image(shoot / "v0.png", seed=1)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    shutil.rmtree(shoot)
    for args in (["status", "gone", "--check"], ["status", "--check"]):
        result = runner.invoke(app, args)
        said = " ".join(result.output.split())
        gone = "nothing to publish: the folder of dataset 'gone', "
        assert result.exit_code == 1 and gone in said, (args, said)
