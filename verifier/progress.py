"""How far a verification has got: per profile, the stage (features, matching, verification,
mapping), how far (images, blocks of pairs), elapsed time and an estimate of the stage's rest.

pycolmap runs inside SfM child processes and says nothing to its parent while it works, but it logs
each step to stderr (the child's `sfm.log`): "Processed file [12/40]" while extracting, "Processing
block [1/2, 1/2]" while matching, "Registering image #5 (num_reg_frames=3)" while mapping. A
`ProgressBoard` tails the logs of the running children (a thread, once a second), keeps one
`ProfileProgress` per profile, writes the whole board as a small JSON file atomically (what
`ppd status` reads: `read_progress`, `progress_line`) and calls back whoever shows it on a terminal.
The parsing and the words are pure functions (`apply_log_line`, `progress_line`).
"""

from __future__ import annotations

import contextlib
import os
import re
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import msgspec

from poisoner.atomic import atomic_write_bytes

POLL_S = 1.0  # how often the running children's logs are read

_EXTRACTED = re.compile(r"Processed file \[(\d+)/(\d+)\]")
_BLOCK = re.compile(r"Processing block \[(\d+)/(\d+), (\d+)/(\d+)\]")
_VERIFYING = re.compile(r"=== Geometric verification ===|Generating existing image pairs")
_REGISTERED = re.compile(r"Registering image #\d+ \(num_reg_frames=(\d+)\)")
_INITIAL_PAIR = re.compile(r"Registering initial image pair")
_GLOBAL = re.compile(r"global_(pipeline|mapper)\.cc|rotation_averaging\.cc")

STAGES = ("waiting", "features", "matching", "verification", "mapping", "done")


class ProfileProgress(msgspec.Struct):
    """One profile's progress: which side (clean, poisoned) is running, its stage and how far."""

    profile: str
    side: str = ""
    stage: str = "waiting"
    done: int = 0  # images extracted / blocks matched / images registered
    total: int = 0
    unit: str = ""  # "images" or "blocks"
    started_at: float | None = None
    stage_started_at: float | None = None
    finished_at: float | None = None
    verdict: str | None = None


class BoardState(msgspec.Struct):
    """What the progress file holds (JSON)."""

    label: str  # the dataset or folder being verified
    pid: int
    started_at: float
    updated_at: float
    num_images: int
    profiles: list[ProfileProgress]


def apply_log_line(p: ProfileProgress, line: str, num_images: int, now: float) -> bool:
    """Update p from one line of pycolmap's log; whether anything changed."""

    def enter(stage: str, total: int, unit: str) -> None:
        if p.stage != stage:
            p.stage, p.stage_started_at, p.done = stage, now, 0
        p.total, p.unit = total, unit

    if m := _EXTRACTED.search(line):
        enter("features", int(m.group(2)), "images")
        p.done = int(m.group(1))
    elif m := _BLOCK.search(line):
        i, n, j, k = (int(g) for g in m.groups())
        enter("matching", n * k, "blocks")
        p.done = (i - 1) * k + j - 1  # this block is being matched: the ones before it are done
    elif _VERIFYING.search(line):
        enter("verification", 0, "")
    elif m := _REGISTERED.search(line):
        enter("mapping", num_images, "images")
        p.done = max(p.done, int(m.group(1)))
    elif _INITIAL_PAIR.search(line):
        enter("mapping", num_images, "images")
        p.done = max(p.done, 2)
    elif _GLOBAL.search(line) and p.stage != "mapping":
        enter("mapping", 0, "")  # the global mapper logs no per-image count
    else:
        return False
    return True


def stage_estimate_s(p: ProfileProgress, now: float) -> float | None:
    """Seconds left in p's stage at its rate so far (None: nothing to go on yet)."""
    if p.stage_started_at is None or p.total <= 0 or p.done <= 0 or p.done >= p.total:
        return None
    elapsed = now - p.stage_started_at
    return elapsed / p.done * (p.total - p.done)


def _minutes(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def profile_words(p: ProfileProgress, now: float) -> str:
    """One profile in a few words: `poisoned mapping 12/40 images, 3 min, ~1 min left`."""
    if p.stage == "done":
        took = (p.finished_at or now) - (p.started_at or now)
        return f"{p.verdict or 'done'} ({_minutes(took)})"
    if p.stage == "waiting":
        return "waiting"
    count = f" {p.done}/{p.total} {p.unit}" if p.total > 0 else ""
    words = f"{p.side + ' ' if p.side else ''}{p.stage}{count}, {_minutes(now - (p.started_at or now))}"
    left = stage_estimate_s(p, now)
    return words + (f", ~{_minutes(left)} left in this stage" if left is not None else "")


def progress_line(state: BoardState, now: float | None = None) -> str:
    """What `ppd status` says of a running verification: `verifying, 4 min, default 2/5: ...`."""
    now = time.time() if now is None else now
    profiles = state.profiles
    running = [i for i, p in enumerate(profiles) if p.stage not in ("waiting", "done")]
    head = f"verifying, {_minutes(now - state.started_at)}"
    if not running:
        finished = sum(p.stage == "done" for p in profiles)
        return f"{head}, {finished}/{len(profiles)} profiles done"
    n = len(profiles)
    parts = [f"{profiles[i].profile} {i + 1}/{n}: {profile_words(profiles[i], now)}" for i in running]
    return f"{head}, " + "; ".join(parts)


def read_progress(path: Path) -> BoardState | None:
    """A running verification's progress file; None when there is none, it is unreadable, or the
    process that wrote it is gone (a verification that was killed leaves its file behind)."""
    try:
        state = msgspec.json.decode(path.read_bytes(), type=BoardState)
    except (OSError, msgspec.DecodeError):
        return None
    try:
        os.kill(state.pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:  # alive, someone else's
        pass
    return state


class ProgressBoard:
    """The progress of one verification, kept up to date from its children's logs."""

    def __init__(
        self,
        profiles: Sequence[str],
        num_images: int,
        label: str,
        path: Path | None = None,
        on_change: Callable[[BoardState], None] | None = None,
    ) -> None:
        now = time.time()
        self.path = path
        self._on_change = on_change
        self._lock = threading.Lock()
        rows = [ProfileProgress(p) for p in profiles]
        self._state = BoardState(label, os.getpid(), now, now, num_images, rows)
        # profile -> its running sides' logs, first started first: the row follows the first (both
        # sides of a profile can run at once; the row shows one, then the other when it ends)
        self._running: dict[str, list[tuple[str, Path]]] = {}
        self._offsets: dict[Path, int] = {}  # how far each followed log has been read
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _profile(self, name: str) -> ProfileProgress:
        return next(p for p in self._state.profiles if p.profile == name)

    def start(self) -> None:
        if self.path is not None:
            with contextlib.suppress(OSError):
                self.path.parent.mkdir(parents=True, exist_ok=True)
        self._publish()
        self._thread = threading.Thread(target=self._loop, name="ppd-verify-progress", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop reading logs and remove the progress file (the verification is over)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        if self.path is not None:
            with contextlib.suppress(OSError):
                self.path.unlink()

    @contextlib.contextmanager
    def side(self, profile: str, side: str, log_path: Path) -> Iterator[None]:
        """While one SfM child of profile runs (writing log_path), its log is followed; when both
        sides of a profile run at once, the row follows the one that started first."""
        with self._lock:
            running = self._running.setdefault(profile, [])
            running.append((side, log_path))
            if len(running) == 1:
                self._follow(profile, side, log_path)
        self._publish()
        try:
            yield
        finally:
            self._read_logs()
            with self._lock:
                running = self._running[profile]
                followed = running[0] == (side, log_path)
                running.remove((side, log_path))
                self._offsets.pop(log_path, None)
                if followed and running:  # the other side goes on: the row follows it from its start
                    self._follow(profile, *running[0])
                if not running:
                    self._running.pop(profile, None)

    def _follow(self, profile: str, side: str, log_path: Path) -> None:
        """The row of profile shows this side from its log's start (called with the lock held). The
        stage starts again only for the other side: the same side's next child (mapping after its
        features) moves the row on from where it is, as its log says."""
        now = time.time()
        p = self._profile(profile)
        if p.stage in ("waiting", "done") or p.side != side:
            p.stage, p.stage_started_at, p.done, p.total, p.unit = "features", now, 0, 0, ""
        p.side, p.started_at = side, p.started_at or now
        self._offsets[log_path] = 0

    def finish(self, profile: str, verdict: str) -> None:
        with self._lock:
            p = self._profile(profile)
            p.stage, p.verdict, p.finished_at = "done", verdict, time.time()
            p.started_at = p.started_at or p.finished_at
        self._publish()

    def snapshot(self) -> BoardState:
        with self._lock:
            return msgspec.json.decode(msgspec.json.encode(self._state), type=BoardState)

    def _read_logs(self) -> bool:
        changed = False
        with self._lock:
            followed = {profile: sides[0] for profile, sides in self._running.items() if sides}
        for profile, (side, path) in followed.items():
            try:
                with open(path, "rb") as fh:
                    fh.seek(self._offsets.get(path, 0))
                    data = fh.read()
            except OSError:
                continue
            end = data.rfind(b"\n") + 1  # whole lines only; the rest is read next time
            now = time.time()
            with self._lock:
                sides = self._running.get(profile)
                if not sides or sides[0] != (side, path) or path not in self._offsets:
                    continue  # it ended, or the row moved to the other side, while this was read
                p = self._profile(profile)
                for line in data[:end].decode(errors="replace").splitlines():
                    changed |= apply_log_line(p, line, self._state.num_images, now)
                self._offsets[path] += end
        return changed

    def _publish(self) -> None:
        state = self.snapshot()
        state.updated_at = time.time()
        if self.path is not None:
            with contextlib.suppress(OSError):  # progress is a courtesy: never fails a verification
                atomic_write_bytes(self.path, msgspec.json.encode(state))
        if self._on_change is not None:
            self._on_change(state)

    def _loop(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(POLL_S):
            # every second on a terminal; the file at least every 5 s (the age it shows moves on)
            if self._read_logs() or time.monotonic() - last >= 5 or self._on_change is not None:
                self._publish()
                last = time.monotonic()


def state_to_json(state: BoardState) -> dict[str, Any]:
    """The progress as `ppd status --json` carries it, with the line it prints."""
    return {**msgspec.to_builtins(state), "line": progress_line(state)}
