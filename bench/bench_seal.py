"""What the provenance seal costs (issue 29): sealing a finished file and verifying one, as ratios
against a plain sha256 of the same file in the same run (ppd hashes every file anyway).

    python -m bench.bench_seal [--mb 2 20 200] [--runs 5] [--out bench/results/seal.md]

Files: a JPEG-like file of the given size (random bytes after a real JPEG header with the seal in
its XMP), read from the page cache (the pipeline seals a file it has just written, and verifies
one it has just hashed). Median of --runs.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from daemon.store.vault import sha256_file
from poisoner.provenance import Marker, embed_jpeg, read_seal, seal_file

KEY = bytes(range(32))


def make(path: Path, mb: float) -> None:
    import io

    import numpy as np
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.zeros((64, 64, 3), np.uint8)).save(out, "JPEG")
    head = embed_jpeg(out.getvalue(), Marker.placeholder(KEY, "0123456789abcdef", "ab" * 32))
    rng = np.random.default_rng(0)
    path.write_bytes(head[:-2] + rng.bytes(int(mb * 1e6)) + b"\xff\xd9")


def timed(fn, runs: int) -> float:
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--mb", type=float, nargs="+", default=[2.0, 20.0, 200.0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    lines = [
        "| file (MB) | sha256 (ms) | seal_file / sha256 | read_seal, genuine / sha256 "
        "| read_seal, copied seal / sha256 | read_seal, no seal / sha256 |",
        "|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="ppd-seal-") as tmp:
        for mb in args.mb:
            path = Path(tmp) / "a.jpg"
            make(path, mb)
            blank = path.read_bytes()
            base = timed(lambda p=path: sha256_file(p), args.runs)

            def seal(p: Path = path, data: bytes = blank) -> None:
                p.write_bytes(data)  # (re)written, as the poison stage's output is: in the page cache
                seal_file(p, KEY)

            write_only = timed(lambda p=path, d=blank: p.write_bytes(d), args.runs)
            sealing = max(0.0, timed(seal, args.runs) - write_only)
            seal(path)
            assert read_seal(path, KEY) is not None
            genuine = timed(lambda p=path: read_seal(p, KEY), args.runs)
            copied = Path(tmp) / "copied.jpg"
            data = bytearray(path.read_bytes())
            data[-100] ^= 1  # one byte of the picture changed: the seal no longer fits
            copied.write_bytes(bytes(data))
            forged = timed(lambda p=copied: read_seal(p, KEY), args.runs)
            plain = Path(tmp) / "plain.jpg"
            plain.write_bytes(bytes(data).replace(b"zQ7kS1", b"xxxxxx"))
            none = timed(lambda p=plain: read_seal(p, KEY), args.runs)
            line = (
                f"| {mb:g} | {base * 1e3:.1f} | {sealing / base:.2f} | {genuine / base:.2f} "
                f"| {forged / base:.2f} | {none / base:.2f} |"
            )
            print(line, flush=True)
            lines.append(line)
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
