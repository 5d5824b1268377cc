"""The vault's size limit reached (a review, rev8 F6): every later file failed with "raise [vault]
max_bytes", which a running `ppd watch` never rereads (nothing said to restart it), and `ppd status`
printed one "0 of 3 patched, 3 failed" line per dataset, never the cause. Now the reason gives the whole
way out (the config file, the restart, `ppd dataset forget`), and status says it in ONE line, as it is
now: full, the limit changed in the config since (restart), or room made since (restart)."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from testkit.cli import said
from testkit.photos import make_image, make_shoot

runner = CliRunner()
RESTART = "restart ppd watch (`systemctl --user restart ppd` for the service)"


def _limit(config: Path, max_bytes: int) -> None:
    (config / "config.toml").write_text(f"[vault]\nmax_bytes = {max_bytes}\n")


def test_a_full_vault_is_one_line_with_the_whole_way_out(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    config = ppd_env["config"] / "config.toml"
    first = make_shoot(tmp_path / "first", 1)
    limit = (first / "v0.png").stat().st_size + 100  # room for one original
    _limit(ppd_env["config"], limit)
    assert runner.invoke(app, ["poison", str(first)]).exit_code == 0
    for k, name in enumerate("ab"):  # other photos than first's (the vault keeps one copy of each)
        shoot = [make_image(tmp_path / name / f"v{i}.png", 10 + 2 * k + i) for i in range(2)][0].parent
        assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 1
    code, text = said("status", "a", "--failed")
    assert (f"would pass its limit of {limit} bytes: raise [vault] max_bytes in {config} and {RESTART}, or "
            "`ppd dataset forget` a finished shoot") in text, text  # fmt: skip
    used = sum(p.stat().st_size for p in (ppd_env["data"] / "vault").glob("??/*"))
    code, text = said("status")
    assert code == 0 and text.count("failed on it") == 1, text  # one line for the 4 files of 2 datasets
    assert (
        f"vault full: {used} of {limit} bytes used; 4 photo(s) or video(s) failed on it, NOT protected: "
        f"raise [vault] max_bytes in {config} and {RESTART}, or `ppd dataset forget` a finished shoot"
    ) in text
    full = json.loads(runner.invoke(app, ["status", "--json"]).output)["vault_full"]
    assert (full["used_bytes"], full["limit_bytes"], len(full["failed"])) == (used, limit, 4), full
    # raised as told: a running daemon still has the limit of its start, so status says to restart it
    _limit(ppd_env["config"], 0)
    code, text = said("status")
    assert (f"vault limit reached ({used} of {limit} bytes used): 4 photo(s) or video(s) failed on it, NOT "
            f"protected; {config} now says no limit: {RESTART}, which reads it at its start and patches "
            "them") in text, text  # fmt: skip
    # the limit as it was, a finished shoot forgotten: room again, which a running daemon does not retry
    _limit(ppd_env["config"], limit)
    assert said("dataset", "forget", "first", "--force")[0] == 0
    code, text = said("status")
    assert (f"vault limit reached earlier (0 of {limit} bytes used now): 4 photo(s) or video(s) failed on "
            f"it, NOT protected: {RESTART}, which retries them at its start") in text, text  # fmt: skip
    # patched at last (no limit): the line goes
    _limit(ppd_env["config"], 0)
    assert all(said("poison", str(tmp_path / name))[0] == 0 for name in ("a", "b"))
    assert "vault" not in said("status")[1]
