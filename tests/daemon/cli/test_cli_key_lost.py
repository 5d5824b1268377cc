"""A lost seal key beside a vault of originals (a black-box review: after `rm ppd.sqlite3 seal.key`,
`ppd poison` made a new key with only a warning, patched the patched files again and vaulted their
once-marked bytes as "originals"; `ppd restore` then said "restored 4" and wrote them back). Now
every command that seals refuses with one line, exit 3, and touches nothing, until the old key is
imported or `ppd key new` starts a new one knowingly."""

from __future__ import annotations

import hashlib
from pathlib import Path

from typer.testing import CliRunner

from daemon.cli import app
from daemon.paths import AppPaths
from daemon.store.sealkey import key_path
from testkit.photos import make_image, make_shoot

runner = CliRunner()


def _shas(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def _vault(paths: AppPaths) -> list[str]:
    return sorted(p.name for p in paths.vault_dir.glob("??/*"))


def test_poison_and_watch_refuse_without_the_key_that_sealed_the_vault(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_shoot(shoot, 3)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    exported = tmp_path / "saved.key"
    assert runner.invoke(app, ["key", "export", str(exported)]).exit_code == 0
    patched, vaulted = _shas(shoot), _vault(paths)
    for lost in (paths.db_path, key_path(paths.data_dir)):
        lost.unlink()

    for args in (["poison", str(shoot)], ["poison", str(shoot), "--dry-run"], ["watch"]):
        refused = runner.invoke(app, args)
        assert refused.exit_code == 3, (args, refused.output)
        errors = [line for line in refused.stderr.splitlines() if "error" in line]
        assert len(errors) == 1 and "ppd: error: no seal key" in errors[0], (args, refused.stderr)
        assert "`ppd key import FILE`" in errors[0] and "`ppd key new`" in errors[0]
        assert _shas(shoot) == patched and _vault(paths) == vaulted  # nothing patched twice, nothing vaulted
        assert not key_path(paths.data_dir).exists()  # and no key made behind the user's back

    assert runner.invoke(app, ["key", "import", str(exported)]).exit_code == 0  # the old key back
    again = runner.invoke(app, ["poison", str(shoot)])
    assert again.exit_code == 0 and "patched 0, unchanged 3" in again.output, again.output
    assert _shas(shoot) == patched and _vault(paths) == vaulted


def test_key_new_starts_a_new_key_only_when_asked_and_only_where_there_is_none(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    paths = AppPaths.from_env()
    shoot = tmp_path / "shoot"
    make_image(shoot / "v0.png", 0)
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    old = key_path(paths.data_dir).read_bytes()
    refused = runner.invoke(app, ["key", "new"])
    assert refused.exit_code == 2 and "already holds a key" in refused.stderr, refused.output
    assert key_path(paths.data_dir).read_bytes() == old
    key_path(paths.data_dir).unlink()
    made = runner.invoke(app, ["key", "new"])
    assert made.exit_code == 0 and "`ppd key export FILE`" in made.stdout, made.output
    assert key_path(paths.data_dir).read_bytes() != old
    assert key_path(paths.data_dir).stat().st_mode & 0o777 == 0o600
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0  # the store still knows v0 by hash
