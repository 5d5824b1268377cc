"""Races against protect_file at random instants (issue 20, rows 1 and 3); bench/bench_races.py
runs them at length, tests/daemon/protect/test_pipeline.py a few trials. The scenarios are
bench_races' docstring's:
a folder or file swapped for a symlink during protection, a new version renamed over the file."""

from __future__ import annotations

import os
import random
import statistics
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from daemon.protect.one_file import AppContext, protect_file
from testkit.reliability import app_paths, make_media, sha256


@dataclass
class RaceResult:
    scenario: str
    trials: int = 0
    violations: list[str] = field(default_factory=list)
    outcomes: Counter[str] = field(default_factory=Counter)
    window_s: float = 0.0  # swaps fall uniformly in [0, window_s] after protect_file starts


def _tree(folder: Path) -> dict[str, str]:
    if not folder.exists():
        return {}
    out = {}
    for p in sorted(folder.rglob("*")):
        out[str(p)] = f"-> {os.readlink(p)}" if p.is_symlink() else sha256(p) if p.is_file() else "dir"
    return out


def _temporaries(*folders: Path) -> list[Path]:
    return [p for f in folders if f.exists() for p in f.rglob(".ppd-tmp-*")]


def _vault_links(ctx: AppContext) -> list[Path]:
    return [p for p in ctx.paths.vault_dir.rglob("*") if p.is_symlink()]


def _timed_protect(ctx: AppContext, path: Path) -> float:
    started = time.monotonic()
    protect_file(path, ctx)
    return time.monotonic() - started


def _window(ctx: AppContext, root: Path, suffix: str) -> float:
    """1.3 x the median time protect_file takes on such a file here (the swap instants' range)."""
    times = [_timed_protect(ctx, make_media(root / "warmup" / f"w{i}{suffix}", 900 + i)) for i in range(3)]
    return 1.3 * statistics.median(times)


def _race(action: Callable[[], None], delay: float, ctx: AppContext, path: Path) -> str:
    def later() -> None:
        time.sleep(delay)
        action()

    swapper = threading.Thread(target=later)
    swapper.start()
    outcome = protect_file(path, ctx)
    swapper.join()
    return str(outcome.state)


def run_symlink_races(root: Path, trials: int, seed: int = 0, suffix: str = ".png") -> RaceResult:
    """Alternate folder and file swaps for symlinks (see the module docstring)."""
    rng = random.Random(seed)
    ctx = AppContext.open(app_paths(root))
    result = RaceResult(f"symlink swap ({suffix})")
    try:
        result.window_s = window = _window(ctx, root / "outbox", suffix)
        for i in range(trials):
            ds = ctx.paths.outbox / f"ds{i}"
            sub, private, away = ds / "sub", root / f"private{i}", root / f"away{i}"
            photo = make_media(sub / f"a{suffix}", seed * 10_000 + i)
            make_media(private / f"a{suffix}", seed * 10_000 + 5000 + i)
            before = _tree(private)
            if i % 2 == 0:
                what = "folder"

                def swap(sub: Path = sub, away: Path = away, private: Path = private) -> None:
                    os.rename(sub, away)
                    sub.symlink_to(private, target_is_directory=True)
            else:
                what = "file"

                def swap(photo: Path = photo, private: Path = private, suffix: str = suffix) -> None:
                    tmp = photo.with_name(f"link{suffix}")
                    tmp.symlink_to(private / f"a{suffix}")
                    os.replace(tmp, photo)

            state = _race(swap, rng.uniform(0, window), ctx, photo)
            result.trials += 1
            result.outcomes[f"{what}: {state}"] += 1
            if _tree(private) != before:
                result.violations.append(f"trial {i} ({what}): the private folder changed")
            if leftovers := _temporaries(ctx.paths.outbox, away, private):
                result.violations.append(f"trial {i} ({what}): temporaries left: {leftovers}")
            if links := _vault_links(ctx):
                result.violations.append(f"trial {i} ({what}): symlink in the vault: {links}")
    finally:
        ctx.close()
    return result


def run_replace_races(root: Path, trials: int, seed: int = 0, suffix: str = ".png") -> RaceResult:
    """A new version renamed over the file at a random instant during protection."""
    rng = random.Random(seed)
    ctx = AppContext.open(app_paths(root))
    result = RaceResult(f"replace during protect ({suffix})")
    try:
        result.window_s = window = _window(ctx, root / "outbox", suffix)
        stage = root / "stage"
        for i in range(trials):
            path = make_media(ctx.paths.outbox / f"ds{i}" / f"a{suffix}", seed * 10_000 + i)
            newer = make_media(stage / f"n{i}{suffix}", seed * 10_000 + 5000 + i)
            second = sha256(newer)
            state = _race(
                lambda newer=newer, path=path: os.replace(newer, path), rng.uniform(0, window), ctx, path
            )
            if state == "skipped":  # still changing after the retries: the daemon's requeue does this
                state = f"{state}+again:{protect_file(path, ctx).state}"
            result.trials += 1
            result.outcomes[state] += 1
            at_path, row = sha256(path), ctx.store.file(path)
            # The new version must be at the path, or patched: kept in the vault as the original
            # of what is at the path. (The first version replaced by the user before ppd opened it
            # is the user's doing, not a lost update.)
            patched_new = (
                row is not None and row["original_sha256"] == second and row["poisoned_sha256"] == at_path
            )
            if at_path != second and not (patched_new and ctx.vault.verify(second)):
                result.violations.append(f"trial {i}: the new version was lost (path holds {at_path[:12]})")
            if leftovers := _temporaries(ctx.paths.outbox):
                result.violations.append(f"trial {i}: temporaries left: {leftovers}")
    finally:
        ctx.close()
    return result
