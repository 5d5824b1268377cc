"""`ppd report` of a HEIC dataset (black-box review 7, F3): it had no patch preview ("ppd: warning: no
patch preview": the report's process had no HEIC opener) and still said "the preview below says where
this file's mark is"; and a HEIC, re-encoded whole, differs in every pixel, so "where the pixels
changed" was the whole picture. The preview now decodes as `ppd poison` does, zooms where ppd recorded
the mark, and the sentence points at a preview only where there is one. The report runs in a fresh
process: the HEIC opener, once registered, stays for the whole process."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import write_image

runner = CliRunner()
REPO = Path(__file__).resolve().parents[3]


def report_in_a_fresh_process(name: str, page: Path) -> tuple[str, str]:
    """(the page, stderr) of `ppd report NAME` run as the user runs it."""
    done = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "report", name, "--out", str(page)],
        capture_output=True, text=True, env={**os.environ, "COLUMNS": "40"}, timeout=120, cwd=REPO,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return page.read_text(), done.stderr


def test_the_report_of_a_heic_set_shows_where_its_mark_is(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    import pillow_heif

    from daemon.context import AppContext

    pillow_heif.register_heif_opener()  # to write the photos (the report's process has its own)
    kitchen = tmp_path / "kitchen"
    kitchen.mkdir()
    for i in range(3):
        Image.open(write_image(tmp_path / "src" / f"v{i}.png", seed=i)).save(
            kitchen / f"IMG_{i}.HEIC", quality=90
        )
    assert runner.invoke(app, ["poison", str(kitchen)]).exit_code == 0
    ctx = AppContext.open()
    try:
        patched = ctx.store.last_event(kitchen / "IMG_0.HEIC", "patched")
        assert patched is not None
        place = patched["detail"]["place"]  # where ppd wrote its mark
        now = time.time() + 1  # a verification: the page shows the photo at display size too
        ctx.store.add_verification_run("kitchen", "default", "protected", {}, now, now + 1, None, None)
    finally:
        ctx.close()

    html, stderr = report_in_a_fresh_process("kitchen", tmp_path / "kitchen.html")
    assert "no patch preview" not in stderr and "no display picture" not in stderr, stderr
    captions = " ".join(re.findall(r"<figcaption>([^<]*)</figcaption>", html))
    x0, y0, x1, y1 = place["box"]
    assert (f"Patch preview: original | patched (IMG_0.HEIC), zoom on the patch below; mark at the "
            f"{place['words']}, within pixels ({x0},{y0})-({x1},{y1}) as shown (as recorded when ppd "
            "patched it)") in captions, captions  # fmt: skip
    assert f"the mark as recorded in x {x0}–{x1}, y {y0}–{y1}" in captions, captions
    assert "where its file&#x27;s mark is" in html  # the placement note points at it: it is there


def test_no_sentence_points_at_a_preview_the_page_lacks(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """The vault's copy of the original unreadable (cut short): no preview can be made, and the page
    no longer says there is one below."""
    from daemon.context import AppContext

    shoot = tmp_path / "shoot"
    for i in range(3):
        write_image(shoot / f"v{i}.png", seed=i)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    ctx = AppContext.open()
    try:
        for row in ctx.store.files("shoot"):
            vault_copy = ctx.vault.path_for(row["original_sha256"])
            os.chmod(vault_copy, 0o600)
            vault_copy.write_bytes(vault_copy.read_bytes()[:100])
    finally:
        ctx.close()
    html, stderr = report_in_a_fresh_process("shoot", tmp_path / "shoot.html")
    assert "no patch preview" in stderr and "Patch preview" not in html
    assert "Placement: per photo, where each photo is plainest as shown" in html
    assert "preview below" not in html, json.dumps(re.findall(r'class="note">([^<]*)', html), indent=1)
