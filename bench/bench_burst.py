"""Writers that reopen and append in bursts, against a live `ppd watch` with its default quiet
time (2 s) and incomplete wait (120 s): issue 29. Each writer opens its file with 'ab', writes a
quarter, closes, pauses GAP seconds, four times. All writers run at once.

Counted per gap: files split (more than one file, a quarantined fragment, or a fragment in the
vault), files whose original (the vault copy its patched row names) is not byte-identical to what
the writer wrote, and how long after the last byte the file was patched.

    python -m bench.bench_burst [--gaps 1 2.5 4 10] [--n 3] [--out bench/results/burst.md]
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from daemon.states import FileState  # noqa: E402
from daemon.store import Store  # noqa: E402
from testkit.daemon_proc import stop_daemon  # noqa: E402
from testkit.photos import burst_writer  # noqa: E402
from testkit.reliability import app_paths, start_daemon, wait_for, write_image  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gaps", type=float, nargs="+", default=[1.0, 2.5, 4.0, 10.0])
    ap.add_argument("--n", type=int, default=3, help="writers per gap")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="ppd-burst-") as tmp:
        root = Path(tmp) / "ppd"
        outbox = root / "outbox" / "burst"
        outbox.mkdir(parents=True)
        paths = app_paths(root)
        sources: dict[Path, tuple[float, bytes]] = {}
        for gap in args.gaps:
            for i in range(args.n):
                suffix = ".jpg" if i % 2 == 0 else ".png"
                src = write_image(
                    Path(tmp) / "src" / f"g{gap:g}-{i}{suffix}", seed=i + int(gap * 10), size=800
                )
                sources[outbox / src.name] = (gap, src.read_bytes())
        daemon = start_daemon(root, "--no-verify")  # the defaults: 2 s quiet time, 120 s incomplete wait
        done_at: dict[Path, float] = {}
        patched_at: dict[Path, float] = {}
        try:

            def write(path: Path, gap: float, data: bytes) -> None:
                burst_writer(path, data, 4, gap)
                done_at[path] = time.monotonic()

            threads = [threading.Thread(target=write, args=(p, g, d)) for p, (g, d) in sources.items()]
            for t in threads:
                t.start()

            def all_patched() -> bool:
                store = Store(paths.db_path)
                try:
                    for p in sources:
                        row = store.file(p)
                        if row is not None and row["state"] == FileState.PATCHED and p not in patched_at:
                            patched_at[p] = time.monotonic()
                finally:
                    store.close()
                return len(patched_at) == len(sources) and all(not t.is_alive() for t in threads)

            wait_for(all_patched, 600, "every burst-written file patched")
        finally:
            stop_daemon(daemon)
        store = Store(paths.db_path)
        rows = {p: store.file(p) for p in sources}
        store.close()
        quarantined = [q.name for q in (root / "ppd-quarantine").rglob("*") if q.is_file()]
        blobs = {b.name for b in paths.vault_dir.glob("??/*") if b.is_file()}
        wanted = {hashlib.sha256(d).hexdigest() for _, d in sources.values()}
        lines = [
            "| gap (s) | writers | split | original not byte-identical "
            "| patched after the last byte (s, max) |",
            "|---|---|---|---|---|",
        ]
        for gap in args.gaps:
            mine = [p for p, (g, _) in sources.items() if g == gap]
            split = sum(
                1
                for p in mine
                if any(q.startswith(p.stem) for q in quarantined) or sorted(outbox.glob(f"{p.stem}*")) != [p]
            )
            wrong = sum(
                1 for p in mine if rows[p]["original_sha256"] != hashlib.sha256(sources[p][1]).hexdigest()
            )
            late = max(patched_at[p] - done_at[p] for p in mine)
            lines.append(f"| {gap:g} | {len(mine)} | {split} | {wrong} | {late:.1f} |")
        lines.append(
            f"\nvault blobs that are not a whole original: {len(blobs - wanted)}; "
            f"quarantined: {len(quarantined)}"
        )
        text = "\n".join(lines) + "\n"
        print(text)
        if args.out:
            args.out.write_text(text)


if __name__ == "__main__":
    main()
