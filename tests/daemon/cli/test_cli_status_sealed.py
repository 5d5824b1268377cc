"""ppd's output that no row names (a review, rev8 F7): after `ppd dataset forget NAME --force` (the
vault freed of a published shoot whose patched files stay in the outbox), status called them "NOT
protected, no dataset holds yet" for good, while the advice (`ppd watch`, `ppd poison`) only answered
"unchanged (already ppd output)", so `--check` could never pass again. Now a file whose seal verifies
under this installation's key is said to carry the mark (its original forgotten: not restorable) and
`--check` passes over it; a copy edited since (its seal no longer verifies) is still not patched."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from testkit.cli import said, verified_shoot
from testkit.photos import make_shoot

runner = CliRunner()
SEALED = "3 file(s) carry ppd's mark, their originals forgotten: protected as patched, not restorable"


def test_marked_files_of_a_forgotten_dataset_are_not_called_unprotected(ppd_env: dict[str, Path]) -> None:
    outbox = ppd_env["outbox"]
    verified_shoot(outbox / "castle", 2)  # ready to publish: the check's answer is the outbox's
    shoot = make_shoot(outbox / "s01", 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    assert said("dataset", "forget", "s01", "--force")[0] == 0
    code, text = said("status")
    assert f"outbox: {SEALED} (s01/v0.png, s01/v1.png, s01/v2.png)" in text, text
    assert "no dataset holds yet" not in text and "NOT protected" not in text, text
    code, text = said("status", "--check")
    assert code == 0 and "not ready" not in text, text
    code, text = said("status", "s01")
    assert code == 0 and text == f"s01: a folder of the outbox no dataset holds: {SEALED}", text
    listed = json.loads(runner.invoke(app, ["status", "--json"]).output)
    assert listed["outbox_sealed"]["original_forgotten"] == [str(shoot / f"v{i}.png") for i in range(3)]
    assert listed["outbox_no_dataset"] == [] and listed["ready_to_publish"] is True
    # `ppd poison` (the advice it gave) leaves them as they are, and records nothing: still said so
    assert "unchanged 3" in said("poison", str(shoot))[1]
    assert f"outbox: {SEALED}" in said("status")[1]
    # a copy edited since: its seal no longer verifies, so it is a photo to patch, not ppd's output
    data = bytearray((shoot / "v0.png").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (shoot / "edited.png").write_bytes(bytes(data))
    code, text = said("status", "--check")
    assert code == 1 and "not ready to publish: outbox: 1 photo(s) or video(s) not patched yet" in text, text
    assert "outbox: 1 photo(s) or video(s) no dataset holds yet, NOT protected (s01/edited.png)" in text, text


def test_marked_files_of_a_forgotten_nested_dataset_are_not_its_parents_to_patch(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The same inside a dataset's folder: a shoot's `day2`, patched as a dataset of its own and forgotten
    with --force, is the shoot's again; its files are not "not patched yet" (`ppd poison` would leave
    them unchanged), and the shoot's verdict still stands."""
    trip = tmp_path / "trip"
    verified_shoot(trip, 2)
    day2 = make_shoot(trip / "day2", 2)
    assert runner.invoke(app, ["poison", str(day2)]).exit_code == 0
    assert said("dataset", "forget", "day2", "--force")[0] == 0
    code, text = said("status", "trip", "--check")
    assert code == 0 and "not patched yet" not in text, text
    assert "files 4: carrying ppd's mark with no record (their dataset forgotten?) 2, patched 2" in text, text
    assert (
        "2 file(s) carry ppd's mark, their originals forgotten: protected as patched, not restorable" in text
    )
