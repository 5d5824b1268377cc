"""A dataset with a photo ppd could not patch (left unmarked in the folder that is published) is NOT
protected, whatever the verification measured on its patched photos (black-box review 7, F8: `ppd
verify` said "overall ... protected" and exited 0, `--json` "protected", the status table "protected
under ...", the report's banner PROTECTED, while its own first line said NOT protected). Every surface
now counts the files `ppd status --check` counts (status_queries.unprotected_files)."""

from __future__ import annotations

import json
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from testkit.cli import HEADLINE, verified_shoot
from verifier.synthetic import SyntheticOptions, render_scene
from verifier.verdict import verdict_words

runner = CliRunner()


def flat(text: str) -> str:
    return " ".join(text.split())


def table_text(output: str) -> str:
    """`ppd status`'s table alone, its borders out, whatever the terminal's width (too narrow for a
    table: each dataset as a list, then its lines)."""
    end = output.find("└")
    return flat((output[:end] if end >= 0 else output).replace("│", " "))


def test_verify_of_a_set_with_a_failed_photo_is_not_protected(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The review's case, small: 6 views patched, a seventh truncated (ppd refuses it: failed, left as
    it is). One real verification (default attacker), then its `--json` (the clean side cached)."""
    render_scene(tmp_path / "renders", SyntheticOptions(num_views=6))
    shop = tmp_path / "shop"
    shop.mkdir()
    for png in sorted((tmp_path / "renders").glob("*.png")):
        Image.open(png).convert("RGB").save(shop / png.name)
    whole = (shop / "view_00.png").read_bytes()
    (shop / "view_99.png").write_bytes(whole[: len(whole) // 2])  # truncated: ppd cannot patch it
    assert runner.invoke(app, ["poison", str(shop)]).exit_code == 1  # patched 6, failed 1

    result = runner.invoke(app, ["verify", "shop", "-p", "default"])
    text = flat(result.output)
    assert result.exit_code == 1, text  # `ppd verify shop && publish` publishes nothing
    assert "not verified, and NOT protected: 1 failed" in text  # the first line, as before
    measured = verdict_words(json.loads(runner.invoke(app, ["status", "shop", "--json"]).stdout)
                             ["datasets"][0]["verdicts"]["default"]["verdict"])  # fmt: skip
    assert (f"overall: NOT protected: 1 failed, unmarked: view_99.png; the 6 patched (weakest of default): "
            f"{measured}") in text, text  # fmt: skip
    assert "overall (weakest" not in text

    as_json = runner.invoke(app, ["verify", "shop", "-p", "default", "--json"])
    assert as_json.exit_code == 1
    report = json.loads(as_json.stdout)
    assert report["verdict"] == "not_protected"
    assert report["patched_files_verdict"] == report["profiles"]["default"]["verdict"]  # SfM's, kept
    assert (report["unmarked"], report["unmarked_files"], report["num_patched"]) == (
        ["1 failed"],
        ["view_99.png"],
        6,
    )

    d = json.loads(runner.invoke(app, ["status", "shop", "--json"]).stdout)["datasets"][0]
    assert d["protection"]["state"] == "NOT protected" and d["protection"]["unmarked"] == ["1 failed"]
    patched = d["protection"]["patched_files"]["text"]  # "protected under default" when SfM says so
    assert d["protection"]["text"] == f"NOT protected: 1 failed; the 6 patched: {patched}"
    table = table_text(runner.invoke(app, ["status"]).output)
    assert f"NOT protected: 1 failed; the 6 patched: {patched}" in table, table
    page = tmp_path / "shop.html"
    assert runner.invoke(app, ["report", "shop", "--out", str(page)]).exit_code == 0
    html = page.read_text()
    assert 'data-verdict="not_protected"' in html
    assert f"Verdict: NOT protected: 1 failed, unmarked: view_99.png; the 6 patched: {patched}" in html


def test_a_photo_restored_in_place_makes_a_protected_set_not_protected(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Every attacker said protected; then the user restored one photo where it is published. The
    status table, `--json`, `ppd poison`'s closing line and the report's banner said "protected"."""
    from daemon.cli.status_queries import protection_line
    from daemon.context import AppContext

    shoot = tmp_path / "set"
    verified_shoot(shoot, 4)
    d = json.loads(runner.invoke(app, ["status", "set", "--json"]).stdout)["datasets"][0]
    assert d["protection"]["state"] == "protected" and d["protection"]["unmarked"] == []  # as before
    assert runner.invoke(app, ["restore", str(shoot / "v2.png")]).exit_code == 0

    under = "protected under default, global, hardened, masked, published"
    d = json.loads(runner.invoke(app, ["status", "set", "--json"]).stdout)["datasets"][0]
    assert d["protection"]["state"] == "NOT protected"
    assert d["protection"]["text"] == f"NOT protected: 1 restored by you; the 3 patched: {under}"
    assert d["protection"]["patched_files"] == {"state": "protected", "profiles": sorted(HEADLINE),
                                                "text": under}  # fmt: skip
    status = runner.invoke(app, ["status"])
    assert f"NOT protected: 1 restored by you; the 3 patched: {under}" in table_text(status.output)
    check = runner.invoke(app, ["status", "set", "--check"])  # its words as before: the files alone
    assert check.exit_code == 1 and flat(check.output).endswith(
        "not ready to publish: set: 1 restored by you"
    )
    ctx = AppContext.open()
    try:
        assert protection_line(ctx, "set") == f"set: NOT protected: 1 restored by you; the 3 patched: {under}"
    finally:
        ctx.close()
    page = tmp_path / "set.html"
    assert runner.invoke(app, ["report", "set", "--out", str(page)]).exit_code == 0
    html = page.read_text()
    assert 'data-verdict="protected"' not in html and "PROTECTED —" not in html
    assert f"Verdict: NOT protected: 1 restored by you, unmarked: v2.png; the 3 patched: {under}" in html
