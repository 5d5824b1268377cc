"""protect_file end to end on real files, a real SQLite store and a real vault."""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from daemon.config import Config, ConfigError, parse_length
from daemon.datasets.dataset import DEFAULT_DATASET, OutsideOutboxError, dataset_of
from daemon.paths import AppPaths
from daemon.protect.one_file import AppContext, dataset_pairs, protect_file, reprotect_dataset, restore_file
from daemon.states import FileState
from daemon.store import DatasetSpecLocked
from daemon.watch.syncdirs import find_sync_folder
from poisoner.blend import patch_coverage
from poisoner.corner import CORNERS
from poisoner.formats import PoisonReport
from poisoner.ladder import default_spec, named_spec
from poisoner.spec import PatchSpec


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def make_image(path: Path, seed: int, size: tuple[int, int] = (160, 120)) -> Path:
    """A random-texture picture (PNG unless the suffix says otherwise)."""
    rng = np.random.default_rng(seed)
    pixels = rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pixels).save(path, quality=92) if path.suffix == ".jpg" else Image.fromarray(pixels).save(
        path
    )
    return path


@pytest.fixture
def ctx(ppd_env: dict[str, Path]) -> AppContext:
    context = AppContext.open()
    yield context
    context.close()


def _no_temporaries(folder: Path) -> bool:
    return not [p for p in folder.rglob(".ppd-tmp-*")]


# ---- paths, config, datasets ---------------------------------------------------------------
def test_paths_follow_env_overrides(ppd_env: dict[str, Path]) -> None:
    paths = AppPaths.from_env()
    assert paths.data_dir == ppd_env["data"] and paths.outbox == ppd_env["outbox"]
    assert paths.config_file == ppd_env["config"] / "config.toml"
    assert paths.vault_dir.parent == paths.data_dir and paths.db_path.parent == paths.data_dir
    paths.ensure()
    assert paths.vault_dir.stat().st_mode & 0o077 == 0
    defaults = AppPaths.from_env({})
    assert defaults.outbox.name == "PPD Outbox" and "ppd" in defaults.data_dir.parts[-1]


def test_config_defaults_overrides_and_errors(ppd_env: dict[str, Path]) -> None:
    paths = AppPaths.from_env()
    assert Config.load(paths).spec == default_spec()  # the per-photo lanes, not the paper's patch
    assert default_spec() != PatchSpec() and default_spec().per_photo and default_spec().lanes == 2
    paths.config_file.write_text(
        'workers = 3\n[patch]\npatch_size = "6%"\nblock_size = 4\n'
        "[verification]\nevery_new_files = 5\n"
        '[datasets.shoot]\npublish_dir = "/srv/shoot"\n[datasets.shoot.patch]\nposition = "bottom-right"\n'
    )
    config = Config.load(paths)
    assert config.workers == 3 and config.verification.every_new_files == 5
    assert config.spec.patch_size == 0.06 and config.spec.block_size == 4
    assert config.spec_for("shoot").position == "bottom-right"
    assert config.spec_for("shoot").block_size == 4  # override sits on the default
    assert config.spec_for("other") == config.spec
    assert config.publish_dir_for("shoot") == Path("/srv/shoot")
    assert Config.from_toml(config.to_toml()).spec_for("shoot") == config.spec_for("shoot")
    paths.config_file.write_text("[patch]\npattern = 'nope'\n")
    with pytest.raises(ConfigError, match="unknown pattern"):
        Config.load(paths)
    # a config written for another design names it; fields of the old default alone say how
    paths.config_file.write_text('[patch]\ndesign = "roaming"\nmotion = "static"\n')
    assert Config.load(paths).spec == named_spec("roaming").replace(motion="static")
    paths.config_file.write_text('[patch]\npattern = "checkerboard"\nmotion = "static"\noffset = [0, 0]\n')
    with pytest.raises(ConfigError, match='design = "roaming"'):
        Config.load(paths)
    paths.config_file.write_text('[patch]\ndesign = "nope"\n')
    with pytest.raises(ConfigError, match="design: unknown 'nope'"):
        Config.load(paths)
    paths.config_file.write_text("wrokers = 2\n")
    with pytest.raises(ConfigError, match="wrokers"):
        Config.load(paths)


def test_parse_length() -> None:
    assert parse_length("48") == 48 and isinstance(parse_length("48"), int)
    assert parse_length("0.06") == 0.06
    assert parse_length("6%") == pytest.approx(0.06)
    with pytest.raises(ValueError):
        parse_length("six")
    # found on an installed ppd: "200%" was 2.0, read as 2 px (a length of 1 or more is pixels)
    for whole in ("100%", "200%", "-150%"):
        with pytest.raises(ValueError, match="give a percentage under 100%"):
            parse_length(whole)
    assert parse_length("99%") == pytest.approx(0.99)
    for nothing in ("inf", "1e400", "nan", "nan%", "-inf%"):  # found in review: a traceback, no option named
        with pytest.raises(ValueError, match="cannot read length"):
            parse_length(nothing)


def test_dataset_of(tmp_path: Path) -> None:
    outbox = tmp_path / "outbox"
    assert dataset_of(outbox, outbox / "a.jpg") == DEFAULT_DATASET
    assert dataset_of(outbox, outbox / "shoot" / "a.jpg") == "shoot"
    assert dataset_of(outbox, outbox / "shoot" / "raw" / "b.jpg") == "shoot"
    with pytest.raises(OutsideOutboxError):
        dataset_of(outbox, tmp_path / "elsewhere.jpg")


def test_sync_folder_detection(tmp_path: Path) -> None:
    synced = tmp_path / "Sync"
    (synced / ".stfolder").mkdir(parents=True)
    found = find_sync_folder(synced / "PPD Outbox")
    assert found is not None and found.client == "Syncthing" and found.root == synced
    assert find_sync_folder(tmp_path / "plain" / "outbox") is None
    assert find_sync_folder(tmp_path / "Dropbox" / "outbox").client == "Dropbox"


# ---- protect_file --------------------------------------------------------------------------
def test_protect_records_vaults_and_replaces(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    src = make_image(ppd_env["outbox"] / "shoot" / "a.png", 1)
    original = src.read_bytes()
    outcome = protect_file(src, ctx)
    assert outcome.state == "patched", outcome.reason
    assert outcome.dataset == "shoot" and outcome.kind == "image"
    assert src.read_bytes() != original
    assert outcome.original_sha256 == hashlib.sha256(original).hexdigest()
    assert outcome.poisoned_sha256 == _sha(src)
    assert ctx.vault.path_for(outcome.original_sha256).read_bytes() == original
    row = ctx.store.file(src)
    assert row["state"] == FileState.PATCHED and row["spec_id"] == ctx.store.dataset_spec("shoot").spec_id
    assert _default_with_its_corner(ctx.store.dataset_spec("shoot"))
    assert row["poisoned_sha256"] == _sha(src) and row["error"] is None
    assert [e["kind"] for e in ctx.store.events("shoot")][:2] == ["patched", "pending"]
    assert dataset_pairs(ctx, "shoot") == [(ctx.vault.path_for(outcome.original_sha256), src)]
    assert _no_temporaries(ppd_env["outbox"])


def test_second_run_is_unchanged(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    src = make_image(ppd_env["outbox"] / "a.png", 2)
    assert protect_file(src, ctx).state == "patched"
    poisoned = src.read_bytes()
    again = protect_file(src, ctx)
    assert again.state == "unchanged"
    assert src.read_bytes() == poisoned
    copy = ppd_env["outbox"] / "copy-of-a.png"  # ppd's output under another name: still ours
    copy.write_bytes(poisoned)
    assert protect_file(copy, ctx).state == "unchanged"
    assert copy.read_bytes() == poisoned


def _default_with_its_corner(spec: PatchSpec) -> bool:
    """The product's default spec: placed per photo (issue 25), so no corner is chosen for the dataset."""
    return spec == default_spec() and spec.per_photo and spec.position not in CORNERS


def test_every_file_of_a_dataset_gets_the_identical_patch(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    files = [make_image(ppd_env["outbox"] / "shoot" / f"{i}.png", 10 + i) for i in range(3)]
    outcomes = [protect_file(f, ctx) for f in files]
    spec = ctx.store.dataset_spec("shoot")
    assert _default_with_its_corner(spec)
    assert {o.spec_id for o in outcomes} == {spec.spec_id}
    placements = [o.report.placement for o in outcomes]  # each photo's own place (issue 25)
    assert len({p.box for p in placements}) == 3  # the default mark moves from image to image ...
    lanes = []
    for f, p in zip(files, placements, strict=True):
        x0, y0, x1, y1 = p.box
        written = patch_coverage(p)
        assert written.any() and not written.all()  # two lanes, the pixels between them untouched
        lanes.append(np.asarray(Image.open(f))[y0:y1, x0:x1][written])
    assert all(np.array_equal(lanes[0], other) for other in lanes[1:])  # ... but is one pattern (alpha 1)
    rest = [np.asarray(Image.open(f)).copy() for f in files]
    for picture in rest:
        for x0, y0, x1, y1 in (p.box for p in placements):
            picture[y0:y1, x0:x1] = 0
    assert not np.array_equal(rest[0], rest[1])  # the pictures themselves differ


def test_ratio_skips_unselected_files(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    spec = PatchSpec(ratio=0.5, seed=3)
    ctx.store.set_dataset_spec("shoot", spec, root=ppd_env["outbox"] / "shoot")
    files = [make_image(ppd_env["outbox"] / "shoot" / f"{i}.png", i) for i in range(12)]
    before = {f: f.read_bytes() for f in files}
    outcomes = {f: protect_file(f, ctx) for f in files}
    for f, o in outcomes.items():
        expected = "patched" if spec.selects(f.name) else "skipped"
        assert o.state == expected
        assert (f.read_bytes() == before[f]) == (expected == "skipped")
    assert {o.state for o in outcomes.values()} == {"patched", "skipped"}
    skipped = next(f for f, o in outcomes.items() if o.state == "skipped")
    assert not ctx.vault.has(hashlib.sha256(before[skipped]).hexdigest())
    assert protect_file(skipped, ctx).state == "unchanged"


def test_a_voice_memo_saved_as_mp4_is_left_as_it_is(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    """Sound and no picture (what a `.m4a` holds): nothing a reconstruction reads. It failed ("no video
    stream"), so the daemon quarantined it and the dataset never passed `ppd status --check` (a
    black-box review); now it is skipped with the reason, left byte for byte, not kept in the vault.
    A video with sound is still patched."""
    import av

    from testkit.video import Clip, make_clip, mux_sine

    memo = ppd_env["outbox"] / "shoot" / "memo.mp4"
    memo.parent.mkdir(parents=True)
    with av.open(str(memo), "w") as out:
        sound = out.add_stream("aac", rate=48000)
        sound.layout = "mono"
        mux_sine(out, sound, 24000, hz=440, amplitude=0.3, fmt="flt", layout="mono", fallback_step=960)
    before = memo.read_bytes()
    outcome = protect_file(memo, ctx)
    assert (outcome.state, outcome.reason) == ("skipped", "sound only, no picture: nothing to protect")
    assert memo.read_bytes() == before and not ctx.vault.has(hashlib.sha256(before).hexdigest())
    row = ctx.store.file(memo)
    assert row["state"] == FileState.SKIPPED and row["error"] == outcome.reason
    assert protect_file(memo, ctx).state == "unchanged"
    clip = make_clip(ppd_env["outbox"] / "shoot" / "clip.mp4", Clip(frames=6))  # a picture and sound
    assert protect_file(clip, ctx).state == "patched"


def test_hidden_and_unsupported_files_are_left_alone(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    hidden = make_image(ppd_env["outbox"] / ".hidden.png", 1)
    tmp = make_image(ppd_env["outbox"] / ".ppd-tmp-abc.png", 2)
    notes = ppd_env["outbox"] / "notes.txt"
    notes.write_text("not a picture")
    for f in (hidden, tmp, notes):
        before = f.read_bytes()
        assert protect_file(f, ctx).state == "skipped"
        assert f.read_bytes() == before
    assert ctx.store.files(DEFAULT_DATASET) == []


@pytest.mark.parametrize("content", [b"", b"this is not a PNG at all\n" * 10])
def test_bad_files_fail_cleanly(ctx: AppContext, ppd_env: dict[str, Path], content: bytes) -> None:
    bad = ppd_env["outbox"] / "shoot" / "broken.png"
    bad.parent.mkdir()
    bad.write_bytes(content)
    outcome = protect_file(bad, ctx)
    assert outcome.state == "failed"
    assert outcome.reason and "\n" not in outcome.reason
    assert bad.read_bytes() == content  # nothing lost
    row = ctx.store.file(bad)
    assert row["state"] == "failed" and row["error"] == outcome.reason
    assert _no_temporaries(ppd_env["outbox"])


def test_symlinks_are_refused(ctx: AppContext, ppd_env: dict[str, Path], tmp_path: Path) -> None:
    secret = make_image(tmp_path / "private" / "secret.png", 5)
    before = secret.read_bytes()
    link = ppd_env["outbox"] / "shoot" / "link.png"
    link.parent.mkdir()
    link.symlink_to(secret)
    outcome = protect_file(link, ctx)
    assert outcome.state == "failed" and "symlink" in outcome.reason
    assert secret.read_bytes() == before and link.is_symlink()
    # a real folder reached through a symlinked folder resolves outside the dataset too
    (ppd_env["outbox"] / "shoot" / "sub").symlink_to(secret.parent, target_is_directory=True)
    through = protect_file(ppd_env["outbox"] / "shoot" / "sub" / "secret.png", ctx)
    assert through.state == "failed" and "symlink" in through.reason
    assert secret.read_bytes() == before


def test_file_outside_the_outbox_fails(ctx: AppContext, tmp_path: Path) -> None:
    stray = make_image(tmp_path / "stray.png", 1)
    before = stray.read_bytes()
    assert protect_file(stray, ctx).state == "failed"
    assert stray.read_bytes() == before


def test_file_replaced_mid_processing_is_not_clobbered(
    ctx: AppContext, ppd_env: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    import poisoner.formats

    src = make_image(ppd_env["outbox"] / "shoot" / "a.png", 1)
    newer = make_image(ppd_env["outbox"] / ".newer.png", 99)
    newer_bytes = newer.read_bytes()
    real_poison_bytes = poisoner.formats.poison_bytes  # what poison_file and the daemon's in-memory path run

    def poison_then_user_saves_a_new_version(
        s: Path, spec: PatchSpec, **kw: Any
    ) -> tuple[bytes, PoisonReport]:
        made = real_poison_bytes(s, spec, **kw)
        if newer.exists():
            os.replace(newer, src)  # the user's editor saves a new version meanwhile (once)
        return made

    monkeypatch.setattr(poisoner.formats, "poison_bytes", poison_then_user_saves_a_new_version)
    outcome = protect_file(src, ctx)
    # The new version is never overwritten: the run starts over and patches it.
    new_sha = hashlib.sha256(newer_bytes).hexdigest()
    assert outcome.state == "patched" and outcome.original_sha256 == new_sha
    assert ctx.vault.path_for(new_sha).read_bytes() == newer_bytes
    assert src.read_bytes() != newer_bytes
    assert hashlib.sha256(src.read_bytes()).hexdigest() == outcome.poisoned_sha256
    assert _no_temporaries(ppd_env["outbox"])


def test_concurrent_protection_of_different_files(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    files = [make_image(ppd_env["outbox"] / "shoot" / f"{i}.png", 100 + i) for i in range(8)]
    files += [make_image(ppd_env["outbox"] / "other" / f"{i}.jpg", 200 + i) for i in range(4)]
    originals = {f: f.read_bytes() for f in files}
    results: dict[Path, str] = {}
    lock = threading.Lock()

    def work(chunk: list[Path]) -> None:
        for f in chunk:
            state = protect_file(f, ctx).state
            with lock:
                results[f] = state

    threads = [threading.Thread(target=work, args=(files[k::4],)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert set(results.values()) == {"patched"}
    assert ctx.store.counts("shoot")[FileState.PATCHED] == 8
    assert ctx.store.counts("other")[FileState.PATCHED] == 4
    for f, data in originals.items():
        assert ctx.vault.path_for(hashlib.sha256(data).hexdigest()).read_bytes() == data
        assert f.read_bytes() != data


def test_same_file_twice_at_once_poisons_once(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    src = make_image(ppd_env["outbox"] / "a.png", 7)
    states: list[str] = []
    barrier = threading.Barrier(3)

    def work() -> None:
        barrier.wait()
        states.append(protect_file(src, ctx).state)

    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(states) == ["patched", "unchanged", "unchanged"]


def test_publish_dir_receives_the_protected_file(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    publish = tmp_path / "www"
    (ppd_env["config"] / "config.toml").write_text(f'publish_dir = "{publish}"\n')
    ctx = AppContext.open()
    src = make_image(ppd_env["outbox"] / "shoot" / "a.png", 3)
    original = src.read_bytes()
    outcome = protect_file(src, ctx)
    assert outcome.state == "patched"
    published = publish / "shoot" / "a.png"
    assert outcome.output == published and published.is_file() and not src.exists()
    assert ctx.store.file(src)["published_path"] == str(published)
    assert dataset_pairs(ctx, "shoot")[0][1] == published
    restored = restore_file(ctx, src)
    # Never an original in the publish folder (before: the published copy became the original).
    assert restored.state == "restored" and "publish folder" in restored.reason
    assert not published.exists() and src.read_bytes() == original
    ctx.close()


def test_a_restore_from_the_publish_folder_killed_midway_is_finished_next_time(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Killed after the published copy was removed and the original written back, before its row: the
    next restore refused "a.png exists; not overwriting it" (a diff review). The file holding its
    original is taken as done; any other file there is still refused."""
    publish = tmp_path / "www"
    (ppd_env["config"] / "config.toml").write_text(f'publish_dir = "{publish}"\n')
    ctx = AppContext.open()
    src = make_image(ppd_env["outbox"] / "shoot" / "a.png", 3)
    original = src.read_bytes()
    assert protect_file(src, ctx).state == "patched"
    (publish / "shoot" / "a.png").unlink()  # what the killed restore had done, the row not told
    src.write_bytes(original)
    assert restore_file(ctx, src).state == "restored" and src.read_bytes() == original
    other = make_image(ppd_env["outbox"] / "shoot" / "b.png", 4)
    assert protect_file(other, ctx).state == "patched"
    make_image(other, 9)  # a different photo now where the original would go
    assert restore_file(ctx, other).state == "failed"
    ctx.close()


def test_restore_then_daemon_leaves_it_force_reprotects(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    src = make_image(ppd_env["outbox"] / "a.png", 4)
    original = src.read_bytes()
    protect_file(src, ctx)
    assert restore_file(ctx, src).state == "restored"
    assert src.read_bytes() == original and ctx.store.file(src)["state"] == "restored"
    assert protect_file(src, ctx).state == "unchanged"  # the user's restore is respected
    assert src.read_bytes() == original
    assert protect_file(src, ctx, force=True).state == "patched"
    assert src.read_bytes() != original


def test_restore_refuses_a_file_changed_since(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    src = make_image(ppd_env["outbox"] / "a.png", 4)
    protect_file(src, ctx)
    make_image(src, 50)  # the user overwrote the protected file with something else
    edited = src.read_bytes()
    outcome = restore_file(ctx, src)
    assert outcome.state == "failed" and "changed" in outcome.reason
    assert src.read_bytes() == edited


def test_reprotect_with_a_new_spec(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    files = [make_image(ppd_env["outbox"] / "shoot" / f"{i}.png", 30 + i) for i in range(3)]
    originals = [f.read_bytes() for f in files]
    for f in files:
        protect_file(f, ctx)
    first = [f.read_bytes() for f in files]
    new_spec = PatchSpec(position="bottom-right", patch_size=24, block_size=4)
    with pytest.raises(DatasetSpecLocked):
        ctx.store.set_dataset_spec("shoot", new_spec)
    outcomes = reprotect_dataset(ctx, "shoot", new_spec)
    assert [o.state for o in outcomes] == ["patched"] * 3
    for f, orig, old in zip(files, originals, first, strict=True):
        row = ctx.store.file(f)
        assert row["spec_id"] == new_spec.spec_id and row["poisoned_sha256"] == _sha(f)
        assert f.read_bytes() not in (orig, old)
        pixels, clean = np.asarray(Image.open(f)), np.asarray(Image.open(__import__("io").BytesIO(orig)))
        assert np.array_equal(pixels[:24, :24], clean[:24, :24])  # top-left untouched now
        assert not np.array_equal(pixels[-24:, -24:], clean[-24:, -24:])
    assert ctx.store.dataset_spec("shoot") == new_spec


def test_video_is_protected(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    av = pytest.importorskip("av")
    pytest.importorskip("poisoner.video")
    clip = ppd_env["outbox"] / "clips" / "walk.mp4"
    clip.parent.mkdir()
    with av.open(str(clip), "w") as out:
        stream = out.add_stream("libx264", rate=10)
        stream.width, stream.height, stream.pix_fmt = 128, 96, "yuv420p"
        rng = np.random.default_rng(0)
        tex = rng.integers(30, 220, (96, 200, 3), dtype=np.uint8)
        for i in range(6):
            frame = av.VideoFrame.from_ndarray(
                np.ascontiguousarray(tex[:, i * 4 : i * 4 + 128]), format="rgb24"
            )
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    original = clip.read_bytes()
    outcome = protect_file(clip, ctx)
    assert outcome.state == "patched", outcome.reason
    assert outcome.kind == "video" and clip.read_bytes() != original
    assert ctx.vault.path_for(outcome.original_sha256).read_bytes() == original
    assert protect_file(clip, ctx).state == "unchanged"


def test_interrupted_run_is_recovered_not_poisoned_twice(ctx: AppContext, ppd_env: dict[str, Path]) -> None:
    src = make_image(ppd_env["outbox"] / "shoot" / "a.png", 8)
    outcome = protect_file(src, ctx)
    poisoned = src.read_bytes()
    # a crash after the rename but before the final row: the row still says 'pending'
    ctx.store.record_file(src, "shoot", "pending", poisoned_sha256=None)
    again = protect_file(src, ctx)
    assert again.state == "unchanged" and "interrupted" in again.reason
    assert src.read_bytes() == poisoned
    row = ctx.store.file(src)
    assert row["state"] == FileState.PATCHED and row["poisoned_sha256"] == outcome.poisoned_sha256
    # a crash before the rename: the file is still the original, so it is simply protected
    ctx.store.record_file(src, "shoot", "pending", poisoned_sha256=None)
    ctx.vault.restore(outcome.original_sha256, src)
    assert protect_file(src, ctx).state == "patched"
    assert src.read_bytes() == poisoned


def test_a_renamed_dataset_folder_keeps_its_provenance(ppd_env) -> None:
    """Moving protected files (a dataset folder renamed in the outbox) must not drop them out of
    the store: the rows follow the files, and the vault pairs still resolve."""
    from daemon.protect.one_file import AppContext, dataset_pairs, protect_file

    ctx = AppContext.open()
    try:
        old_dir = ppd_env["outbox"] / "shoot"
        old_dir.mkdir()
        rng = np.random.default_rng(3)
        for i in range(3):
            Image.fromarray(rng.integers(0, 256, (96, 96, 3), dtype=np.uint8)).save(old_dir / f"v{i}.png")
            assert protect_file(old_dir / f"v{i}.png", ctx).state == "patched"
        new_dir = ppd_env["outbox"] / "shoot-final"
        old_dir.rename(new_dir)
        outcomes = [protect_file(p, ctx) for p in sorted(new_dir.glob("*.png"))]
        assert {o.state for o in outcomes} == {"unchanged"}
        assert all("moved from" in (o.reason or "") for o in outcomes)
        rows = ctx.store.files("shoot-final")
        assert len(rows) == 3 and {r["state"] for r in rows} == {FileState.PATCHED}
        assert {r["state"] for r in ctx.store.files("shoot")} == {"removed"}
        pairs = dataset_pairs(ctx, "shoot-final")
        assert len(pairs) == 3 and all(orig.exists() and prot.exists() for orig, prot in pairs)
        # A second pass is a plain no-op.
        assert {protect_file(p, ctx).reason for p in new_dir.glob("*.png")} == {"already patched"}
    finally:
        ctx.close()


def test_limits_max_megapixels_is_read_and_applied(ppd_env: dict[str, Path]) -> None:
    """The refusal tells the user to raise [limits] max_megapixels: that key must do something."""
    paths = AppPaths.from_env()
    with pytest.raises(ConfigError, match="max_megapixels"):
        Config.from_toml("[limits]\nmax_megapixels = 0\n")
    paths.config_file.write_text("[limits]\nmax_megapixels = 0.01\n")  # 10,000 pixels
    assert Config.from_toml(Config.load(paths).to_toml()).max_pixels == 10_000
    small = AppContext.open()
    big = make_image(ppd_env["outbox"] / "shoot" / "big.png", seed=1, size=(160, 120))  # 19,200 px
    before = _sha(big)
    try:
        outcome = protect_file(big, small)
    finally:
        small.close()
    assert outcome.state in ("failed", "quarantined") and "max_megapixels" in (outcome.reason or "")
    assert _sha(big) == before
    paths.config_file.write_text("[limits]\nmax_megapixels = 0.05\n")  # 50,000 pixels
    roomy = AppContext.open()
    try:
        assert protect_file(big, roomy).state == "patched"
    finally:
        roomy.close()
