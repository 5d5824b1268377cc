"""`ppd demo` (what `make demo` runs): the real daemon protects a rendered shoot, with the product's
default spec, and the verification prints a verdict. Run as a subprocess, as a user runs it."""

from __future__ import annotations

import json
import os
import shlex
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from daemon.states import FileState
from poisoner.ladder import default_spec
from poisoner.spec import PatchSpec


def _run_demo(workdir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", "demo", "--workdir", str(workdir), *args],
        capture_output=True, text=True, timeout=900, check=False,
        env={**os.environ, "COLUMNS": "80"},  # status fits 80 columns without cutting a name
    )  # fmt: skip


def test_demo_protects_every_view_with_the_default_spec(tmp_path: Path) -> None:
    proc = _run_demo(tmp_path, "--views", "4", "--no-verify")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    outbox = tmp_path / "outbox" / "demo-scene"
    views = sorted(outbox.glob("*.png"))
    assert len(views) == 4
    with sqlite3.connect(tmp_path / "data" / "ppd.sqlite3") as db:
        rows = db.execute("SELECT state, spec_id FROM files WHERE dataset = 'demo-scene'").fetchall()
    assert rows and {r[0] for r in rows} == {FileState.PATCHED.value} and len(rows) == 4
    with sqlite3.connect(tmp_path / "data" / "ppd.sqlite3") as db:
        (stored,) = db.execute("SELECT json FROM specs WHERE id = ?", (rows[0][1],)).fetchone()
    spec = PatchSpec.from_dict(json.loads(stored))
    # the default kind, its corner chosen for the dataset (daemon.datasets.subject_masks)
    assert spec.replace(position=default_spec().position) == default_spec()
    assert {r[1] for r in rows} == {spec.spec_id}
    # the patch moves: the protected views differ from their vault originals in different places
    boxes = {spec.resolve(400, 400, image_key=v.name).box for v in views}
    assert len(boxes) == 4
    preview = tmp_path / "preview.png"
    with Image.open(preview) as im:
        assert im.size[0] > 400 and np.asarray(im).std() > 0
    assert "demo-scene" in proc.stdout and "patched, not verified" in proc.stdout
    # the commands it names work in the user's shell with the demo's folders (a black-box review:
    # `ppd verify demo-scene` there read the user's own store, "no dataset 'demo-scene'")
    said = " ".join(proc.stdout.split())
    prefix = said.split("the demo's own folders, for any ppd command: ", 1)[1].rsplit(" ppd status", 1)[0]
    env = {**os.environ, **dict(p.split("=", 1) for p in shlex.split(prefix))}
    listed = subprocess.run([sys.executable, "-m", "daemon.cli", "status", "demo-scene", "--json"], env=env,
                            capture_output=True, text=True, timeout=60)  # fmt: skip
    assert listed.returncode == 0 and json.loads(listed.stdout)["datasets"][0]["patched"] == 4, listed.stderr


@pytest.mark.integration
def test_demo_verifies_and_prints_the_verdict(tmp_path: Path) -> None:
    proc = _run_demo(tmp_path, "--views", "8", "--profiles", "default")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    out = proc.stdout.lower()
    assert "verifying with colmap" in out
    before = " ".join(out.split("verifying with colmap", 1)[0].split())
    # it verifies next: no line tells the user to run `ppd verify` first (a black-box review)
    assert "patched 8 of 8 views" in before and "ppd verify" not in before, before
    verdicts = ("protected", "weak", "not protected", "not_protected", "sfm crashed", "inconclusive")
    assert any(v in out.split("verifying with colmap", 1)[1] for v in verdicts), proc.stdout[-3000:]
    runs = list((tmp_path / "data").rglob("report.json"))
    assert runs, "the verification left no report"


def test_demo_refuses_a_folder_it_would_mix_with(tmp_path: Path) -> None:
    """`ppd demo --workdir D`, D/data the user's PPD_DATA_DIR, added the demo's scene to the user's
    real store (a second black-box review); a folder of other things is refused too, nothing made."""
    live = tmp_path / "mine"
    (live / "data").mkdir(parents=True)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    for workdir, env in ((live, {"PPD_DATA_DIR": str(live / "data")}), (tmp_path / "other", {})):
        proc = subprocess.run(
            [sys.executable, "-m", "daemon.cli", "demo", "--workdir", str(workdir), "--no-verify"],
            capture_output=True, text=True, timeout=120, check=False, env={**os.environ, **env},
        )  # fmt: skip
        assert proc.returncode == 2 and "--workdir" in proc.stderr, proc.stderr
        assert sorted(p.name for p in workdir.iterdir()) in (["data"], ["notes.txt"])


@pytest.mark.parametrize(("args", "said"), [(["--timeout", "-5"], "--timeout must be > 0"),
                                            (["--profiles", "nosuch"], "--profiles must be one of"),
                                            (["--profiles", "default,nosuch"], "got 'nosuch'")])  # fmt: skip
def test_demo_refuses_a_bad_timeout_or_profile_before_any_work(tmp_path: Path, args: list[str],
                                                               said: str) -> None:  # fmt: skip
    """`--timeout -5` ran the demo, then "only 0 of 12 views patched in -5 s" (exit 1); `--profiles nosuch
    --no-verify` was exit 0 without a word (a black-box review, F11): one line, exit 2, nothing made."""
    proc = _run_demo(tmp_path / "d", *args, "--no-verify")
    lines = proc.stderr.splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and said in lines[0], proc.stdout + proc.stderr
    assert lines[0].startswith("ppd: error: ") and not proc.stdout and not (tmp_path / "d").exists()
