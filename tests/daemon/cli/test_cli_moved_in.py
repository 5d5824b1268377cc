"""A patched photo moved or copied into another dataset, whose spec is another one: one dataset, one spec
(docs/STORE.md). A black-box review: it kept the first dataset's mark; the daemon logged "unchanged ...
moved from", `ppd poison` said "patched 0, unchanged 2" (exit 0), and status blamed "a re-protect".
Now it is patched again from its vault original with the dataset's spec, by `ppd poison` and the daemon,
and said; an original not in the vault fails, named. `--dataset NAME` on files another dataset holds is
refused. Real shoots, a real store and vault, a real `ppd watch`."""

from __future__ import annotations

import hashlib
import sqlite3
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from daemon.store.vault import blob_path
from testkit.cli import said
from testkit.daemon_proc import start_daemon, stop_daemon, wait_for
from testkit.photos import make_image, make_shoot

runner = CliRunner()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _row(data: Path, path: Path) -> dict[str, object]:
    conn = sqlite3.connect(f"file:{data / 'ppd.sqlite3'}?mode=ro", uri=True)
    conn.row_factory = sqlite3.Row
    try:
        row = conn.execute("SELECT * FROM files WHERE path = ?", (str(path),)).fetchone()
        return dict(row) if row is not None else {}
    finally:
        conn.close()


def _spec_id(name: str) -> str:
    import json

    return str(json.loads(runner.invoke(app, ["dataset", "show", name, "--json"]).stdout)["spec_id"])


def _two_datasets(outbox: Path) -> tuple[Path, Path, dict[str, str]]:
    """shoot (the default spec) and papers (the paper design), both patched; shoot's originals' digests."""
    shoot = make_shoot(outbox / "shoot", 3)
    originals = {p.name: _sha(p) for p in shoot.iterdir()}
    papers = outbox / "papers"
    make_image(papers / "p0.png", 30)
    assert said("dataset", "set", "papers", "--design", "paper")[0] == 0
    for folder in (shoot, papers):
        assert runner.invoke(app, ["poison", str(folder)]).exit_code == 0
    return shoot, papers, originals


def test_a_photo_moved_or_copied_in_gets_the_datasets_spec(ppd_env: dict[str, Path]) -> None:
    data = ppd_env["data"]
    shoot, papers, originals = _two_datasets(ppd_env["outbox"])
    ours, theirs = _spec_id("papers"), _spec_id("shoot")
    assert ours != theirs
    (shoot / "v1.png").rename(papers / "moved.png")
    (papers / "copied.png").write_bytes((shoot / "v2.png").read_bytes())
    code, text = said("poison", str(papers), "--dry-run")
    assert code == 0 and "would patch 2" in text, text  # before: "unchanged 3"

    code, text = said("-v", "poison", str(papers))
    assert code == 0 and "patched 2, unchanged 1" in text, text  # before: "patched 0, unchanged 3", exit 0
    came = f"it came from dataset 'shoot' (moved from {shoot / 'v1.png'})"
    assert f"re-marked with this dataset's spec: {came}" in text, text
    assert f"it came from dataset 'shoot' (copied from {shoot / 'v2.png'})" in text, text
    for name in ("moved.png", "copied.png"):
        row = _row(data, papers / name)
        assert row["dataset"] == "papers" and row["spec_id"] == ours and row["state"] == "patched", row
        assert row["poisoned_sha256"] == _sha(papers / name)
    assert _row(data, shoot / "v2.png")["spec_id"] == theirs  # the copy's source keeps its own
    code, text = said("status", "papers")
    assert code == 0 and "another spec" not in text, text  # before: "a re-protect did not finish?"
    assert said("poison", str(papers))[1].startswith("patched 0, unchanged 3"), "done once"

    assert said("restore", "papers")[0] == 0  # each one's own original, from the vault
    assert _sha(papers / "moved.png") == originals["v1.png"]
    assert _sha(papers / "copied.png") == originals["v2.png"]


def test_an_original_not_in_the_vault_fails_named(ppd_env: dict[str, Path]) -> None:
    data = ppd_env["data"]
    shoot, papers, originals = _two_datasets(ppd_env["outbox"])
    for name in ("v1.png", "v2.png"):  # lost from the vault
        blob_path(data / "vault", originals[name]).unlink()
    (shoot / "v1.png").rename(papers / "moved.png")
    (papers / "copied.png").write_bytes((shoot / "v2.png").read_bytes())
    marked = {name: _sha(papers / name) for name in ("moved.png", "copied.png")}
    result = runner.invoke(app, ["poison", str(papers)])
    text = " ".join(result.output.split())
    assert result.exit_code == 1 and "patched 0, unchanged 1, skipped 0, failed 2" in text, text
    assert "ppd: failed: " + str(papers / "moved.png") + ": the vault copy of moved.png is missing or " \
        "corrupt (it came from dataset 'shoot' (moved from " in text, text
    assert "it keeps that mark, not dataset 'papers''s)" in text, text
    assert "copied.png carries ppd's mark with another spec than dataset 'papers''s (it came from dataset " \
        "'shoot' (copied from" in text and "its original is not in the vault" in text, text
    assert {name: _sha(papers / name) for name in marked} == marked  # left as they were
    code, text = said("status", "papers")
    assert "1 patched with another spec than the dataset's (moved in from another " \
        "dataset" in text, text


def test_dataset_flag_on_files_another_dataset_holds_is_refused(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A black-box review: "patched 0, unchanged 6 ... other7: nothing patched", exit 0, the paper design
    not applied, and the new dataset's folder "held 0 files" while its photos stayed top7's."""
    top = tmp_path / "p7" / "top7"
    make_shoot(top / "sub", 3)
    make_image(top / "a.png", 40)
    assert runner.invoke(app, ["poison", str(top)]).exit_code == 0
    before = {p: _sha(p) for p in top.rglob("*.png")}
    code, text = said("poison", str(top / "sub"), "--dataset", "other7", "--design", "paper")
    assert code == 2 and text.startswith("ppd: error: ") and text.count("ppd:") == 1, text
    assert f"3 file(s) here are dataset 'top7''s, patched with its spec ({top / 'sub' / 'v0.png'}, ...): " \
        "--dataset other7 cannot take them" in text, text
    assert said("dataset", "show", "other7")[0] == 2  # not made
    assert {p: _sha(p) for p in top.rglob("*.png")} == before
    code, text = said("poison", str(top / "sub"))  # without --dataset: top7's, as before
    assert code == 0 and "unchanged 3" in text, text


def test_the_daemon_gives_a_photo_moved_in_the_datasets_spec(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """The daemon's moved-file path: it logged "unchanged ... moved from .../shoot/v1.png"."""
    data = ppd_env["data"]
    shoot, papers, originals = _two_datasets(ppd_env["outbox"])
    ours = _spec_id("papers")
    daemon = start_daemon(tmp_path, "--no-verify")
    try:
        (shoot / "v1.png").rename(papers / "moved.png")
        wait_for(lambda: _row(data, papers / "moved.png").get("spec_id") == ours, 60, "re-marked")
    finally:
        stop_daemon(daemon)
    log = daemon.log.read_text()
    assert "re-marked with this dataset's spec: it came from dataset 'shoot'" in log, log
    row = _row(data, papers / "moved.png")
    assert row["state"] == "patched" and row["poisoned_sha256"] == _sha(papers / "moved.png"), row
    assert said("restore", str(papers / "moved.png"))[0] == 0
    assert _sha(papers / "moved.png") == originals["v1.png"]
