"""Photos reached through a symlinked folder in the outbox (a review, rev8 F3): a link that is a whole
"dataset" (`OUTBOX/garden -> elsewhere`) and one inside a dataset (`OUTBOX/kitchen/day2 -> elsewhere`).
ppd never follows a link, so their photos stay unmarked, and a publisher that follows links (a web
server, rsync -L) ships them. `ppd poison` said so; `ppd status` and `--check` never did. Now status
counts them as it counts photos under names ppd does not patch, `--check` fails on them, and `--json`
names them; a link into the outbox itself (its files counted where they are) is no such folder."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from testkit.cli import said
from testkit.photos import make_shoot

runner = CliRunner()


def test_photos_behind_symlinked_folders_are_counted_and_fail_the_check(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    outbox, elsewhere = ppd_env["outbox"], tmp_path / "elsewhere dir"
    kitchen = make_shoot(outbox / "kitchen", 2)
    assert runner.invoke(app, ["poison", str(kitchen)]).exit_code == 0
    make_shoot(elsewhere, 3)
    (kitchen / "day2").symlink_to(elsewhere)
    (outbox / "garden").symlink_to(elsewhere)
    code, text = said("status")
    assert code == 0, text
    assert (f"kitchen: 3 photo(s) or video(s) in 1 symlinked folder(s) ppd does not follow (day2 -> "
            f"{elsewhere}: 3), NOT protected: a publisher that follows links") in text, text  # fmt: skip
    assert (f"outbox: 3 photo(s) or video(s) in 1 symlinked folder(s) ppd does not follow (garden -> "
            f"{elsewhere}: 3), NOT protected") in text, text  # fmt: skip
    assert "put the folder itself in place of the link" in text
    code, text = said("status", "--check")
    assert code == 1, text
    assert "not ready to publish: kitchen: 3 in symlinked folders ppd does not follow" in text, text
    assert (
        "not ready to publish: outbox: 3 photo(s) or video(s) in symlinked folders ppd does not follow"
        in text
    )
    said_json = json.loads(runner.invoke(app, ["status", "--json"]).output)
    assert said_json["ready_to_publish"] is False
    assert said_json["outbox_linked_folders"] == [{"path": str(outbox / "garden"), "target": str(elsewhere),
                                                   "photos": 3}]  # fmt: skip
    (kitchen_said,) = said_json["datasets"]
    assert kitchen_said["counts"]["linked"] == 3 and kitchen_said["counts"]["files"] == 2
    assert kitchen_said["linked_folders"][0]["path"] == str(outbox / "kitchen" / "day2")
    # `ppd poison` on the same folder says the same, in the same words (one mechanism)
    code, text = said("poison", str(outbox / "kitchen"))
    assert (
        code == 1
        and f"3 photo(s) or video(s) in 1 symlinked folder(s) ppd does not follow (day2 -> {elsewhere}: 3)"
        in text
    ), text
    # the advice followed (no link left), and a link into the outbox: its photos are the outbox's,
    # counted where they are, so it is no such folder
    (outbox / "kitchen" / "day2").unlink()
    (outbox / "garden").unlink()
    (outbox / "kitchen-again").symlink_to(outbox / "kitchen")
    assert "symlinked" not in said("status")[1]
    assert json.loads(runner.invoke(app, ["status", "--json"]).output)["outbox_linked_folders"] == []
