"""`ppd` as the CLI tests run it: typer's CliRunner in this process, on the ppd_env folders."""

from __future__ import annotations

import time
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from testkit.photos import write_image

runner = CliRunner()
HEADLINE = ("default", "hardened", "published", "global", "masked")  # the profiles `ppd verify` runs


def said(*args: str) -> tuple[int, str]:
    """The exit status and output of `ppd ARGS`, its lines joined by single spaces: a sentence reads the
    same at any terminal width."""
    result = runner.invoke(app, list(args))
    return result.exit_code, " ".join(result.output.split())


def verified_shoot(shoot: Path, views: int, left_out_of_default: tuple[str, ...] = ()) -> None:
    """A patched outbox shoot of `views` photos, every attacker "protected" as record_report writes it
    (a Store row per profile), the default's run leaving out the photos named: a verdict without the
    verification's own work (that has tests of its own)."""
    from daemon.context import AppContext

    for i in range(views):
        write_image(shoot / f"v{i}.png", seed=i)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    ctx = AppContext.open()
    try:
        now = time.time() + 1
        for profile in HEADLINE:
            left = list(left_out_of_default) if profile == "default" else []
            ctx.store.add_verification_run(shoot.name, profile, "protected", {"left_out": left}, now, now + 1,
                                           None, None)  # fmt: skip
    finally:
        ctx.close()
