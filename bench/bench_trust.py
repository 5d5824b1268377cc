"""Forged-seal and crop trials (issue 29), through the real CLI and a live `ppd watch`.

For each kind (JPEG, PNG, MP4), N genuine files are patched; then, from each patched file, a
*forged* file (a never-patched photo with the patched file's seal copied into it) and an *edited*
one (images: cropped by 25% with the seal kept; video: one byte of picture data changed) are
dropped beside them. Counted:
- left unpatched: a forged or edited file whose bytes ppd left as they were (it believed the seal);
- overwritten by restore: `ppd restore FILE` putting anything but the file's own bytes back;
- edits overwritten: `ppd restore FILE` on a patched file edited in place (no --force, the store
  present, then lost): anything written counts.
Phases: the CLI (`ppd poison FOLDER`, then again after deleting the store) and a live daemon.

    python -m bench.bench_trust [--n 4] [--out bench/results/trust.md]
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from daemon.states import FileState  # noqa: E402
from daemon.store import Store  # noqa: E402
from testkit.daemon_proc import stop_daemon  # noqa: E402
from testkit.forgery import edited, forged  # noqa: E402
from testkit.reliability import (  # noqa: E402
    DAEMON_ARGS,
    app_paths,
    make_media,
    start_daemon,
    subprocess_env,
    wait_for,
)

KINDS = ("jpg", "png", "mp4")


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def ppd(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", *args], env=subprocess_env(root), cwd=REPO,
        capture_output=True, text=True, check=False,
    )  # fmt: skip


def lose_store(root: Path) -> None:
    db = app_paths(root).db_path
    for suffix in ("", "-wal", "-shm"):
        Path(f"{db}{suffix}").unlink(missing_ok=True)


def impostors(folder: Path, n: int, seed0: int) -> dict[Path, bytes]:
    """From each genuine patched file in folder: a forged and an edited file (written)."""
    made: dict[Path, bytes] = {}
    for kind in KINDS:
        for i in range(n):
            patched = (folder / f"g{i}.{kind}").read_bytes()
            made[folder / f"forged{i}.{kind}"] = forged(kind, patched, seed=seed0 + i)
            made[folder / f"edited{i}.{kind}"] = edited(kind, patched)
    for path, data in made.items():
        path.write_bytes(data)
    return made


def genuine(folder: Path, n: int, seed0: int) -> None:
    for kind in KINDS:
        for i in range(n):
            make_media(folder / f"g{i}.{kind}", seed=seed0 + i)


def judge(root: Path, made: dict[Path, bytes], counts: Counter[str]) -> None:
    """Count what ppd did with the impostors, then restore each and count what came back."""
    for path, data in made.items():
        counts["impostors"] += 1
        if path.read_bytes() == data:
            counts["left unpatched"] += 1
    for path, data in made.items():
        ppd(root, "restore", str(path))
        if path.read_bytes() != data:
            counts["overwritten by restore"] += 1


def edits_in_place(root: Path, folder: Path, counts: Counter[str]) -> None:
    """A patched file cropped in place (seal kept): restore without --force, store present then
    lost; anything written counts."""
    for kind in ("jpg", "png"):
        path = folder / f"g0.{kind}"
        user = edited(kind, path.read_bytes())
        path.write_bytes(user)
        for lost in (False, True):
            if lost:
                lose_store(root)
            ppd(root, "restore", str(path))
            counts["edits tried"] += 1
            if path.read_bytes() != user:
                counts["edits overwritten"] += 1


def cli_phase(root: Path, n: int) -> Counter[str]:
    counts: Counter[str] = Counter()
    folder = root / "outbox" / "cli"
    genuine(folder, n, seed0=10)
    assert ppd(root, "poison", str(folder)).returncode == 0
    made = impostors(folder, n, seed0=100)
    ppd(root, "poison", str(folder))
    judge(root, made, counts)
    # again after a store loss: the seal alone decides
    lost = root / "outbox" / "cli-lost"
    genuine(lost, n, seed0=20)
    assert ppd(root, "poison", str(lost)).returncode == 0
    lose_store(root)
    made = impostors(lost, n, seed0=200)
    ppd(root, "poison", str(lost))
    judge(root, made, counts)
    edits_in_place(root, lost, counts)
    return counts


def daemon_phase(root: Path, n: int) -> Counter[str]:
    counts: Counter[str] = Counter()
    folder = root / "outbox" / "live"
    paths = app_paths(root)
    root.mkdir(parents=True, exist_ok=True)
    daemon = start_daemon(root, *DAEMON_ARGS)
    try:
        folder.mkdir(parents=True)
        genuine(folder, n, seed0=30)
        wanted = [folder / f"g{i}.{k}" for k in KINDS for i in range(n)]
        wait_for(lambda: _settled(paths, wanted), 600, "genuine files patched")
        made = impostors(folder, n, seed0=300)
        wait_for(lambda: _settled(paths, list(made)), 600, "impostors handled")
    finally:
        stop_daemon(daemon)
    judge(root, made, counts)
    return counts


def _settled(paths, files: list[Path]) -> bool:
    """Every file patched (a row naming what is at its path now) or left alone for a while."""
    store = Store(paths.db_path)
    try:
        rows = {f: store.file(f) for f in files}
    finally:
        store.close()
    return all(
        (r is not None and r["state"] == FileState.PATCHED and r["poisoned_sha256"] == sha(f.read_bytes()))
        or _unchanged_long_enough(f)
        for f, r in rows.items()
    )


_seen: dict[Path, tuple[float, bytes]] = {}


def _unchanged_long_enough(path: Path, quiet: float = 20.0) -> bool:
    """A file the daemon leaves alone (before issue 29: a forged one) may never get a row."""
    data = path.read_bytes()
    first = _seen.get(path)
    if first is None or first[1] != data:
        _seen[path] = (time.monotonic(), data)
        return False
    return time.monotonic() - first[0] > quiet


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=4, help="genuine files per kind (and as many forged, edited)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="ppd-trust-") as tmp:
        for name, phase in (("CLI (store, then lost)", cli_phase), ("live daemon", daemon_phase)):
            root = Path(tmp) / name.split()[0].lower()
            started = time.monotonic()
            c = phase(root, args.n)
            rows.append(
                f"| {name} | {c['impostors']} | {c['left unpatched']} | {c['overwritten by restore']} "
                f"| {c['edits overwritten']}/{c['edits tried']} | {time.monotonic() - started:.0f} |"
            )
            print(rows[-1], flush=True)
    head = (
        "| phase | forged + edited files (JPEG, PNG, MP4) | left unpatched | overwritten by restore "
        "| in-place edits overwritten by restore | seconds |\n|---|---|---|---|---|---|\n"
    )
    table = head + "\n".join(rows) + "\n"
    print(table)
    if args.out:
        args.out.write_text(table)


if __name__ == "__main__":
    main()
