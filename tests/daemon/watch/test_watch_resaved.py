"""The daemon and a patched photo saved again in the outbox with its seal gone (a black-box review,
2026-12-07, F1: `shoot30/IMG_0010.jpg` re-saved by Pillow at quality 90 was logged `patched ...
event=changed`, a second mark, and `ppd restore` then gave back the once-marked picture, exit 0): it is
recognised as ppd's output, left as it is, and restore refuses to write over it without --force."""

from __future__ import annotations

import hashlib
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.protect.one_file import AppContext
from testkit.daemon_proc import start_daemon, stop_daemon, wait_for
from testkit.photos import textured
from testkit.reliability import DAEMON_ARGS


def _row(path: Path) -> dict[str, object] | None:
    ctx = AppContext.open()
    try:
        return ctx.store.file(path)
    finally:
        ctx.close()


def test_the_daemon_does_not_mark_a_resaved_photo_twice(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    photo = ppd_env["outbox"] / "shoot30" / "IMG_0010.jpg"
    photo.parent.mkdir()
    Image.fromarray(textured(240, 320, seed=10)).save(tmp_path / "IMG_0010.jpg", quality=95)
    original = (tmp_path / "IMG_0010.jpg").read_bytes()
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)  # the folders ppd_env made, under tmp_path
    try:
        (tmp_path / "IMG_0010.jpg").rename(photo)
        wait_for(lambda: (_row(photo) or {}).get("state") == "patched", 30, "IMG_0010.jpg patched")
        with Image.open(photo) as im:
            im.load()
            im.save(photo, quality=90)  # in place, the seal gone
        resaved = photo.read_bytes()
        sha = hashlib.sha256(resaved).hexdigest()
        wait_for(lambda: (_row(photo) or {}).get("poisoned_sha256") == sha, 30, "the re-save recognised")
    finally:
        stop_daemon(daemon)
    assert "saved again by another program" in daemon.log.read_text()
    row = _row(photo)
    assert row is not None and row["resaved"] == 1
    assert row["original_sha256"] == hashlib.sha256(original).hexdigest()  # the clean one
    assert photo.read_bytes() == resaved  # no second mark
    refused = CliRunner().invoke(app, ["restore", "shoot30"])
    assert refused.exit_code == 1 and "saved again since" in " ".join(refused.output.split()), refused.output
    assert photo.read_bytes() == resaved
