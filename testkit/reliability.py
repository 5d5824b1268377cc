"""Shared helpers of the reliability tests and `bench/bench_faults.py`, `bench/bench_load.py`:
build an outbox, run `ppd watch` as a real process and SIGKILL it, and check the invariants
that must hold at any instant (docs/RELIABILITY.md):

* every file in the outbox is the untouched original or ppd's complete protected output;
* every original is in place or verified in the vault;
* the store agrees with the disk (a patched row names the bytes on disk, a 'pending' row
  names an original in the vault and the disk holds that original or its exact poisoned form);
* the SQLite file passes `PRAGMA integrity_check`.

Used from pytest and from `python -m bench`; the real-process daemon helpers are
testkit/daemon_proc.py's, the image/clip writers testkit/photos.py's and testkit/video.py's.
"""

from __future__ import annotations

import contextlib
import math
import os
import random
import shutil
import signal
import socket
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import PIL.Image  # before anything that could load pycolmap (pillow 13 import-order crash)
import PIL.PngImagePlugin

from daemon.paths import AppPaths
from daemon.protect.one_file import media_kind, poison_to
from daemon.states import FileState
from daemon.store import Store
from daemon.store.vault import sha256_file as sha256  # the vault's own hash, so audits agree with it
from poisoner.atomic import TEMP_PREFIX
from poisoner.spec import PatchSpec
from testkit.daemon_proc import Daemon, start_daemon, status_kb, wait_for
from testkit.photos import texture, write_image

REPO = Path(__file__).resolve().parents[1]

# no SfM children in fault runs; an incomplete file is quarantined after 2 s unchanged (default 120)
DAEMON_ARGS = ("--no-verify", "--debounce", "0.05", "-j", "2", "--incomplete-wait", "2")

__all__ = [
    "DAEMON_ARGS", "RESULTS", "CrashTrialOptions", "CrashTrialReport", "app_paths", "check_invariants",
    "drop_files", "kill_daemon", "leftover_temporaries", "make_media", "patched_then_store_lost",
    "percentile",
    "protected_counts", "run_crash_trials", "sha256", "start_daemon", "status_kb", "wait_all_protected",
    "wait_for", "write_image", "write_results_section",
]  # fmt: skip


def app_paths(root: Path) -> AppPaths:
    """The AppPaths of bench_daemon.start_daemon's layout: root/{data,config,outbox,cache}."""
    return AppPaths.from_env({
        "PPD_DATA_DIR": str(root / "data"), "PPD_CONFIG_DIR": str(root / "config"),
        "PPD_OUTBOX": str(root / "outbox"), "PPD_CACHE_DIR": str(root / "cache"),
    })  # fmt: skip


# ---- media ----------------------------------------------------------------------------------------
def subprocess_env(root: Path) -> dict[str, str]:
    """The environment for a `ppd` child process whose data, config, outbox and cache live under root."""
    env = dict(os.environ)
    env.update(
        PPD_DATA_DIR=str(root / "data"), PPD_CONFIG_DIR=str(root / "config"),
        PPD_OUTBOX=str(root / "outbox"), PPD_CACHE_DIR=str(root / "cache"), PYTHONPATH=str(REPO),
    )  # fmt: skip
    env.pop("NOTIFY_SOCKET", None)
    return env


def make_video(path: Path, seed: int, frames: int = 12) -> Path:
    """A small H.264 MP4 (160x120, no audio), distinct per seed."""
    from testkit.video import Clip, make_clip  # lazy: loads PyAV

    make_clip(path, Clip(width=160, height=120, frames=frames, audio=None))
    # make_clip's scene is the same for every clip: mark each one by appending a free atom,
    # so the content (and its sha256) differs per seed; MP4 readers skip 'free' boxes.
    with open(path, "ab") as fh:
        fh.write((16).to_bytes(4, "big") + b"free" + seed.to_bytes(8, "big"))
    return path


def make_media(path: Path, seed: int, size: int = 192) -> Path:
    """An image (PNG/JPEG/WebP by suffix) or, for a video suffix, a small MP4."""
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    if suffix in (".mp4", ".mov", ".m4v"):
        return make_video(path, seed)
    if suffix in (".png", ".jpg", ".jpeg"):
        return write_image(path, seed, size)
    PIL.Image.fromarray(texture(seed, size)).save(path)  # WebP, TIFF: Pillow picks by suffix
    return path


def drop_files(
    stage: Path, dest: Path, names_and_seeds: list[tuple[str, int]], size: int = 192
) -> dict[Path, str]:
    """Write files in stage, then rename each into dest (complete on arrival: a moved-in
    event). Returns {outbox path: sha256 of the original}."""
    dest.mkdir(parents=True, exist_ok=True)
    stage.mkdir(parents=True, exist_ok=True)
    written = {}
    for name, seed in names_and_seeds:
        src = make_media(stage / name, seed, size)
        written[dest / name] = sha256(src)
    for name, _ in names_and_seeds:
        os.rename(stage / name, dest / name)
    return written


# ---- invariants -------------------------------------------------------------------------------
def _all_rows(store: Store) -> dict[str, dict]:
    return {r["path"]: r for ds in store.datasets() for r in store.files(ds["name"])}


def _vault_ok(paths: AppPaths, digest: str | None) -> bool:
    if not digest:
        return False
    blob = paths.vault_dir / digest[:2] / digest
    return blob.is_file() and sha256(blob) == digest


def _what_it_holds(paths: AppPaths, path: Path, on_disk: str | None, expected: str | None) -> str:
    """For the failure message: enough to tell a torn file from another seal or another encode."""
    from daemon.store.sealkey import load_key
    from poisoner.provenance import has_token, read_seal

    seal = read_seal(path, load_key(paths.data_dir, create=False))
    named = f"a seal naming {seal.original_sha256[:12]} / {seal.spec_id}" if seal else "no valid seal"
    token = "a seal token" if has_token(path) else "no seal token"
    return (f"{path.stat().st_size} bytes, sha256 {(on_disk or '')[:12]}, {named}, {token}; "
            f"re-poisoning gives {(expected or 'nothing')[:12]}")  # fmt: skip


def expected_output(paths: AppPaths, store: Store, row: dict) -> str | None:
    """sha256 of what ppd writes for this row's original under its spec (poisoning is
    deterministic): the only non-original content a 'pending' path may hold."""
    kind = media_kind(Path(row["path"]))
    if kind is None or not row["spec_id"] or not _vault_ok(paths, row["original_sha256"]):
        return None
    spec = store.get_spec(row["spec_id"])
    with tempfile.TemporaryDirectory(prefix="ppd-expect-") as scratch:
        original = Path(scratch) / Path(row["path"]).name
        shutil.copyfile(paths.vault_dir / row["original_sha256"][:2] / row["original_sha256"], original)
        out = Path(scratch) / f"out{original.suffix}"
        # The daemon's output carries a provenance seal (its key, over these bytes): so must ours.
        from daemon.store.sealkey import load_key
        from poisoner.provenance import Marker, seal_file

        key = load_key(paths.data_dir, create=False)
        if key is None:  # nothing was ever sealed here
            return None
        marker = Marker.placeholder(key, row["spec_id"], row["original_sha256"])
        poison_to(kind, original, out, spec, marker=marker)
        seal_file(out, key)
        return sha256(out)


def check_invariants(paths: AppPaths, originals: Mapping[Path, str] | None = None) -> list[str]:
    """Every violation of the no-loss invariants, one line each ('lost: ...', 'corrupted: ...',
    'store: ...', 'vault: ...'); [] when all hold. originals: {outbox path: original sha256}
    of the files the caller put there (without it only the store's rows are checked)."""
    originals = dict(originals or {})
    problems: list[str] = []
    store = Store(paths.db_path)
    try:
        integrity = store.db.conn.execute("PRAGMA integrity_check").fetchone()[0]
        if integrity != "ok":
            problems.append(f"store: integrity_check says {integrity}")
        rows = _all_rows(store)
        for path_text, row in rows.items():
            problems += _row_problems(paths, store, row, originals.get(Path(path_text)))
        for path, original in originals.items():
            problems += _file_problems(paths, path, original, rows.get(str(path)))
    finally:
        store.close()
    return problems


def _row_problems(paths: AppPaths, store: Store, row: dict, original: str | None) -> list[str]:
    path = Path(row["published_path"] or row["path"])
    state = row["state"]
    on_disk = sha256(path) if path.is_file() else None
    if state == FileState.PATCHED:
        if on_disk is None:
            return [f"store: protected row but no file at {path}"]
        if on_disk != row["poisoned_sha256"]:
            return [f"store: protected row's poisoned_sha256 is not the file at {path}"]
        if not _vault_ok(paths, row["original_sha256"]):
            return [f"vault: original of protected {path.name} missing or corrupt"]
    elif state == "pending":
        if not _vault_ok(paths, row["original_sha256"]):
            return [f"vault: pending row's original of {path.name} missing or corrupt"]
        from daemon.store.sealkey import load_key
        from poisoner.provenance import sealed_for

        original_sha, key = row["original_sha256"], load_key(paths.data_dir, create=False)
        if on_disk in (None, original_sha) or sealed_for(path, key, original_sha, row["spec_id"]):
            return []  # the original, or a file ppd finished for this row (its seal says so)
        if on_disk != (expected := expected_output(paths, store, row)):
            return [f"corrupted: pending {path.name} holds neither its original nor its protected form "
                    f"({_what_it_holds(paths, path, on_disk, expected)})"]  # fmt: skip
    elif state in ("failed", "skipped") and original is not None and on_disk not in (None, original):
        return [f"corrupted: {state} {path.name} was changed on disk"]
    return []


def _file_problems(paths: AppPaths, path: Path, original: str, row: dict | None) -> list[str]:
    if not path.is_file():
        return [] if _vault_ok(paths, original) else [f"lost: {path} gone and its original not in the vault"]
    on_disk = sha256(path)
    if on_disk == original:
        return []
    if not _vault_ok(paths, original):
        return [f"lost: {path.name} was replaced and its original is not in the vault"]
    if row is None:
        return [f"corrupted: {path.name} changed and the store has no row for it"]
    if row["state"] == FileState.PATCHED and row["poisoned_sha256"] == on_disk:
        if row["original_sha256"] != original:  # ppd's output taken for an original: poisoned twice
            return [f"corrupted: {path.name} was protected from something other than its original"]
        return []
    if row["state"] == "pending":
        return []  # checked against the deterministic output in _row_problems
    return [f"corrupted: {path.name} is neither the original nor the recorded protected file"]


def leftover_temporaries(paths: AppPaths) -> list[Path]:
    """`.ppd-tmp-*` files in the outbox (harmless; a start deletes those older than 60 s)."""
    return sorted(p for p in paths.outbox.rglob(f"{TEMP_PREFIX}*") if p.is_file())


def protected_counts(paths: AppPaths) -> Counter[str]:
    """Per path: 'patched' + 'recovered' events (a file done once counts exactly 1)."""
    store = Store(paths.db_path)
    try:
        events = store.events(limit=10_000_000)
    finally:
        store.close()
    return Counter(e["path"] for e in events if e["kind"] in ("patched", "recovered"))


def wait_all_protected(paths: AppPaths, files: list[Path], timeout: float) -> None:
    """Wait until every file has a patched row; on timeout the error says what the others are."""
    rows: dict[str, dict] = {}

    def done() -> bool:
        nonlocal rows
        store = Store(paths.db_path)
        try:
            rows = _all_rows(store)
        finally:
            store.close()
        return all(rows.get(str(f), {}).get("state") == FileState.PATCHED for f in files)

    try:
        wait_for(done, timeout, f"{len(files)} files protected")
    except AssertionError as exc:
        stuck = {f.name: (rows.get(str(f), {}).get("state"), rows.get(str(f), {}).get("error"))
                 for f in files if rows.get(str(f), {}).get("state") != FileState.PATCHED}  # fmt: skip
        raise AssertionError(f"{exc}; not protected: {dict(list(stuck.items())[:10])}") from None


# ---- the daemon as a process -----------------------------------------------------------------------
def kill_daemon(daemon: Daemon, sig: int = signal.SIGKILL) -> int:
    """Send sig (default SIGKILL: no handler, no cleanup) and reap; the exit status."""
    with contextlib.suppress(ProcessLookupError):
        os.kill(daemon.pid, sig)
    code = daemon.proc.wait(60)
    with contextlib.suppress(OSError):
        daemon.sock.shutdown(socket.SHUT_RDWR)  # wakes bench_daemon's drain thread
    daemon.sock.close()
    return code


@dataclass(frozen=True)
class CrashTrialOptions:
    trials: int = 10
    images_per_trial: int = 4
    image_size: int = 192  # px (square)
    video_every: int = 4  # trial i drops one small MP4 when i % video_every == 0 (0: never)
    kill_after_s: tuple[float, float] = (0.0, 1.2)  # uniform delay after the drop
    # Every n-th trial (0: none) waits, up to 10 s, until the daemon is seen working (a pending row or
    # a temporary) and kills it 0-40 ms later: a kill mid-work however fast the machine protects and
    # however slow the daemon starts (four 640 px photos take ~0.1 s, so a fixed window after the drop
    # can miss the work in every trial).
    kill_when_working_every: int = 0
    seed: int = 0
    final_timeout_s: float = 180.0


@dataclass
class CrashTrialReport:
    trials: int = 0
    files: int = 0  # originals dropped
    videos: int = 0
    killed_with_work_pending: int = 0  # kills that left a 'pending' row or a temporary file
    # Where the kills that interrupted this trial's own work landed (see kill_phases()).
    kill_phases: Counter[str] = field(default_factory=Counter)
    violations_after_kill: list[str] = field(default_factory=list)
    violations_final: list[str] = field(default_factory=list)
    not_exactly_once: list[str] = field(default_factory=list)
    leftover_temporaries: int = 0  # after the final run (young leftovers wait for 60 s)
    exit_codes: Counter[int] = field(default_factory=Counter)
    seconds: float = 0.0

    @property
    def lost(self) -> int:
        return sum(v.startswith("lost:") for v in self.violations_after_kill + self.violations_final)

    @property
    def corrupted(self) -> int:
        return sum(not v.startswith("lost:") for v in self.violations_after_kill + self.violations_final)


def kill_phases(paths: AppPaths, since: float) -> Counter[str]:
    """What work a kill interrupted, from the state it left (only files touched after `since`):
    'writing' (a `.ppd-tmp-*` being written), 'kept-not-written' (a pending row, the original
    still at the path: between the vault and the rename), 'renamed-not-recorded' (a pending
    row, the protected file already in place: between the rename and the final row)."""
    phases: Counter[str] = Counter()
    phases["writing"] = sum(p.stat().st_mtime >= since for p in leftover_temporaries(paths))
    store = Store(paths.db_path)
    try:
        for row in _all_rows(store).values():
            if row["state"] != "pending" or row["updated_at"] < since:
                continue
            path = Path(row["path"])
            renamed = path.is_file() and sha256(path) != row["original_sha256"]
            phases["renamed-not-recorded" if renamed else "kept-not-written"] += 1
    finally:
        store.close()
    return +phases


def _work_pending(paths: AppPaths) -> bool:
    if leftover_temporaries(paths):
        return True
    store = Store(paths.db_path)
    try:
        return any(r["state"] == "pending" for r in _all_rows(store).values())
    finally:
        store.close()


def _wait_for_work(paths: AppPaths, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not (paths.db_path.exists() and _work_pending(paths)):
        time.sleep(0.005)


def run_crash_trials(
    root: Path, options: CrashTrialOptions, on_trial: Callable[[int, CrashTrialReport], None] | None = None
) -> CrashTrialReport:
    """Start `ppd watch`, drop files, SIGKILL it at a random instant, check the invariants,
    repeat (each start also recovers the previous kill); finally let a start finish the work
    and check that every file is protected exactly once."""
    rng = random.Random(options.seed)
    root.mkdir(parents=True, exist_ok=True)
    paths = app_paths(root)
    report = CrashTrialReport()
    originals: dict[Path, str] = {}
    started = time.monotonic()
    for trial in range(options.trials):
        trial_started = time.time()
        daemon = start_daemon(root, *DAEMON_ARGS)
        names = [(f"t{trial:03d}-{i}{rng.choice(('.png', '.jpg'))}", trial * 100 + i)
                 for i in range(options.images_per_trial)]  # fmt: skip
        if options.video_every and trial % options.video_every == 0:
            names.append((f"t{trial:03d}-clip.mp4", trial * 100 + 99))
            report.videos += 1
        dest = paths.outbox / f"set{trial % 3}"
        originals.update(drop_files(root / "stage", dest, names, options.image_size))
        every = options.kill_when_working_every
        if every and trial % every == every - 1:
            _wait_for_work(paths, 10.0)
            time.sleep(rng.uniform(0.0, 0.04))
        else:
            time.sleep(rng.uniform(*options.kill_after_s))
        report.exit_codes[kill_daemon(daemon)] += 1
        report.trials += 1
        report.killed_with_work_pending += int(_work_pending(paths))
        phases = kill_phases(paths, trial_started)
        report.kill_phases.update(phases)
        report.kill_phases["kills that interrupted this trial's work"] += int(bool(phases))
        report.violations_after_kill += [f"trial {trial}: {v}" for v in check_invariants(paths, originals)]
        if on_trial is not None:
            on_trial(trial, report)
    report.files = len(originals)
    daemon = start_daemon(root, *DAEMON_ARGS)
    try:
        wait_all_protected(paths, list(originals), options.final_timeout_s)
    finally:
        kill_daemon(daemon, signal.SIGTERM)
    report.violations_final = check_invariants(paths, originals)
    counts = protected_counts(paths)
    report.not_exactly_once = [f"{p.name}: {counts[str(p)]}" for p in originals if counts[str(p)] != 1]
    report.leftover_temporaries = len(leftover_temporaries(paths))
    report.seconds = time.monotonic() - started
    return report


# ---- results file shared by bench_faults and bench_load ------------------------------------------------
RESULTS = REPO / "bench" / "results" / "reliability.md"
RESULTS_HEADER = (
    "# Reliability under faults, load and hostile input\n\n"
    "Written by `python -m bench faults` and `python -m bench load` (each rewrites its own section).\n"
    "See docs/RELIABILITY.md for what each figure means.\n"
)


def write_results_section(name: str, markdown: str, results: Path = RESULTS) -> None:
    """Replace the section `name` of the results file (between its markers), keeping the rest."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    text = results.read_text() if results.exists() else RESULTS_HEADER
    block = f"{start}\n{markdown.rstrip()}\n{end}"
    if start in text and end in text:
        before, rest = text.split(start, 1)
        text = before + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    results.parent.mkdir(parents=True, exist_ok=True)
    results.write_text(text)


def percentile(values: list[float], q: float) -> float:
    """Nearest-rank percentile (q in 0..100) of a non-empty list."""
    ordered = sorted(values)
    rank = max(1, math.ceil(q / 100 * len(ordered)))
    return ordered[rank - 1]


def sealed_patch(src: Path, dst: Path, spec: PatchSpec, original_sha256: str, data_dir: Path) -> None:
    """What the pipeline's poison stage writes: the patched file with its seal, made with the
    installation's key in data_dir (made here when there is none: ppd makes it before it vaults the
    first original, and refuses to make one beside a vault that holds originals)."""
    import secrets

    from daemon.store.sealkey import install_key, load_key
    from poisoner.formats import poison_file
    from poisoner.provenance import KEY_BYTES, Marker, seal_file

    key = load_key(data_dir, create=False)
    if key is None:
        install_key(data_dir, secrets.token_bytes(KEY_BYTES), replace=False)
        key = load_key(data_dir, create=False)
    assert key is not None
    poison_file(src, dst, spec, marker=Marker.placeholder(key, spec.spec_id, original_sha256))
    seal_file(dst, key)


def patched_then_store_lost(folder: Path, seed: int) -> tuple[Path, bytes]:
    """A photo ppd patched in `folder` (an outbox dataset), then the store deleted: (photo, its
    original bytes). What is left to find it by is the vault and the file's seal."""
    from daemon.protect.one_file import AppContext, protect_file

    photo = write_image(folder / "a.png", seed=seed)
    original = photo.read_bytes()
    ctx = AppContext.open()
    assert protect_file(photo, ctx).state == "patched"
    db = ctx.paths.db_path
    ctx.close()
    for suffix in ("", "-wal", "-shm"):
        Path(f"{db}{suffix}").unlink(missing_ok=True)
    return photo, original


def act_after_poisoning(monkeypatch: object, action: Callable[[], object]) -> None:
    """Run action() once, at the worst instant for a concurrent change: right after the poisoner made
    the patched file (in memory, or a work file), before protect_file compares and swaps it in."""
    import daemon.protect.stages as stages

    done: list[bool] = []

    def then_act(real: Callable[..., object]) -> Callable[..., object]:
        def poison_then_act(*args: object, **kw: object) -> object:
            result = real(*args, **kw)
            if not done:
                done.append(True)
                action()
            return result

        return poison_then_act

    for name in ("poison_to", "poison_image_bytes"):
        monkeypatch.setattr(stages, name, then_act(getattr(stages, name)))  # type: ignore[attr-defined]
