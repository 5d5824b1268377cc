"""`ppd status` says what is true of a dataset's files (black-box reviews, F8, S3, N8, N9, N11, N12):
a re-protect's failures stay listed, a moved folder or a renamed file is not called deleted or
unpatched, a headline leads with its failures, and identical advice is one line."""

from __future__ import annotations

import json
import os
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import make_shoot

runner = CliRunner()


def said(*args: str) -> str:
    """The command's output, its lines joined as one (the terminal's wrapping undone)."""
    return " ".join(runner.invoke(app, list(args)).output.split())


def status_json(name: str) -> dict:
    result = runner.invoke(app, ["status", name, "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)["datasets"][0]


def test_a_reprotect_failure_stays_listed_until_fixed(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """F8/S3: `dataset set --reprotect` printed each failure and exited 1, then `status --failed` said
    "0 failed": nothing kept it. A file that still carries the earlier spec's mark is not called failed."""
    from daemon.context import AppContext

    shoot = make_shoot(tmp_path / "A", 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    old_spec = status_json("A")["spec_id"]
    edited = shoot / "v0.png"
    Image.open(edited).crop((0, 0, 150, 110)).save(edited)  # edited since patched: refused
    ctx = AppContext.open()
    try:  # v1's vault copy damaged: refused, v1 untouched, still ppd's output under the old spec
        blob = ctx.vault.path_for(ctx.store.file(shoot / "v1.png")["original_sha256"])
    finally:
        ctx.close()
    os.chmod(blob, 0o644)
    blob.write_bytes(b"not the original")
    result = runner.invoke(app, ["dataset", "set", "A", "--patch-size", "8%", "--reprotect"])
    assert result.exit_code == 1, result.output
    failed = said("status", "A", "--failed")
    assert "A: 0 failed, 0 quarantined, 2 not re-protected" in failed, failed
    assert (f"{edited}: changed since ppd patched it, maybe NOT protected; not re-protected to spec "
            in failed and "changed since ppd protected it" in failed), failed  # fmt: skip
    kept = f"{shoot / 'v1.png'}: still carries the earlier spec's mark (spec {old_spec}); not re-protected to"
    assert kept in failed and "vault copy of v1.png is missing or corrupt" in failed, failed
    assert "v2.png" not in failed
    assert "A: 2 not re-protected: ppd status A --failed" in said("status", "A")
    assert status_json("A")["not_reprotected"] == 2
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0  # patches the edited file again
    again = said("status", "A", "--failed")
    assert "1 not re-protected" in again and "v0.png" not in again and "v1.png" in again, again
