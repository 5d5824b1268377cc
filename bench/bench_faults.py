"""Faults: SIGKILL crash trials on `ppd watch`, full-disk runs on a real small filesystem, the
hostile input corpus through protect_file and through the daemon, and a fuzz run of the file
readers (hypothesis; atheris is not used, see docs/RELIABILITY.md).

    python -m bench.bench_faults [--trials 208] [--chains 8] [--fuzz-examples 1500]

Writes the `faults` section of bench/results/reliability.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import signal
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from daemon.states import FileState
from testkit.disk_full import MountUnavailable, run_disk_full, small_filesystem
from testkit.hostile_inputs import build_hostile_corpus
from testkit.reliability import (
    DAEMON_ARGS,
    CrashTrialOptions,
    CrashTrialReport,
    app_paths,
    kill_daemon,
    run_crash_trials,
    start_daemon,
    wait_for,
    write_results_section,
)

# A refused file is recorded failed, or quarantined (moved out of the outbox) by the daemon.
REFUSED = (FileState.FAILED, FileState.QUARANTINED)
DECIDED = (FileState.PATCHED, *REFUSED)


@dataclass
class CorpusResult:
    inputs: int = 0
    protected: int = 0
    refused: int = 0
    left_alone: int = 0  # links, FIFOs, folders, a non-UTF-8 name: no row, nothing touched
    unexpected: list[str] = field(default_factory=list)
    daemon_exit_code: int | None = None
    daemon_alive_after: bool = False


@dataclass
class FuzzResult:
    examples: int = 0
    refused: int = 0
    written: int = 0
    other_exceptions: list[str] = field(default_factory=list)
    seconds: float = 0.0


def crash_trials(root: Path, trials: int, chains: int) -> tuple[list[CrashTrialReport], list[str]]:
    """`trials` SIGKILLs in `chains` independent outboxes (each chain ends with a recovery run).
    A chain that raises (a recovery that never finishes) is a finding: its folder is kept."""
    reports, failures = [], []
    per_chain = -(-trials // chains)
    for chain in range(chains):
        options = CrashTrialOptions(trials=per_chain, images_per_trial=10, image_size=384, video_every=3,
                                    seed=chain, kill_after_s=(0.1, 1.0))  # fmt: skip
        try:
            report = run_crash_trials(root / f"chain{chain}", options)
        except Exception as exc:
            kept = Path(tempfile.mkdtemp(prefix=f"ppd-faults-chain{chain}-"))
            with contextlib.suppress(shutil.Error):  # the notify socket cannot be copied
                shutil.copytree(root / f"chain{chain}", kept, dirs_exist_ok=True, symlinks=True,
                                ignore=shutil.ignore_patterns("*.sock"))  # fmt: skip
            failures.append(f"chain {chain}: {type(exc).__name__}: {exc} (kept in {kept})")
            print(failures[-1], flush=True)
            continue
        print(f"chain {chain}: {report.trials} kills, {report.files} files, pending at kill "
              f"{report.killed_with_work_pending}, {dict(report.kill_phases)}, lost {report.lost}, "
              f"corrupted {report.corrupted}, not once {len(report.not_exactly_once)}, "
              f"{report.seconds:.0f} s", flush=True)  # fmt: skip
        for violation in report.violations_after_kill + report.violations_final:
            print(f"chain {chain}: {violation}", flush=True)
        reports.append(report)
        shutil.rmtree(root / f"chain{chain}", ignore_errors=True)
    return reports, failures


def plain(report: CrashTrialReport) -> dict[str, object]:
    """The report as JSON-able data (dataclasses.asdict would rebuild its Counters wrongly)."""
    return {f.name: dict(v) if isinstance(v, Counter) else v
            for f in fields(report) if (v := getattr(report, f.name)) is not None}  # fmt: skip


def disk_full_runs(root: Path, leaves: list[int]) -> list[dict[str, object]]:
    out = []
    for i, leave in enumerate(leaves):
        try:
            with small_filesystem(root / f"fs{i}") as fs:
                out.append(asdict(run_disk_full(fs, leave, files=5)))
        except MountUnavailable as exc:
            return [{"skipped": f"cannot mount a tmpfs: {exc}"}]
    return out


def corpus_run(root: Path) -> CorpusResult:
    """The hostile corpus moved into a running `ppd watch` as one folder."""
    from daemon.store import Store

    paths = app_paths(root)
    result = CorpusResult()
    items = build_hostile_corpus(root / "stage" / "hostile", root / "outside")
    result.inputs = len(items)
    expected_rows = [i for i in items if i.expect != "left"]
    daemon = start_daemon(root, *DAEMON_ARGS)
    try:
        (root / "stage" / "hostile").rename(paths.outbox / "hostile")
        store = Store(paths.db_path)

        def decided() -> bool:
            rows = {r["path"]: r["state"] for r in store.files("hostile")}
            return sum(s in DECIDED for s in rows.values()) >= len(expected_rows)

        wait_for(decided, 180, "the corpus to be decided")
        time.sleep(1.0)
        rows = {Path(r["path"]).name: r for r in store.files("hostile")}
        store.close()
        result.daemon_alive_after = daemon.proc.poll() is None
    finally:
        result.daemon_exit_code = kill_daemon(daemon, signal.SIGTERM)
    for item in items:
        row = rows.get(item.path.name)
        state = row["state"] if row else None
        result.protected += state == FileState.PATCHED
        result.refused += state in REFUSED
        result.left_alone += state is None
        patched = FileState.PATCHED
        ok = {"protected": (patched,), "refused": REFUSED, "either": (patched, *REFUSED),
              "left": (None, *REFUSED)}[item.expect]  # fmt: skip
        if state not in ok or (state in REFUSED and "\n" in (row["error"] or "\n")):
            result.unexpected.append(f"{item.what}: {state} ({row and row['error']})")
    return result


def _count(result: FuzzResult, outcome: str) -> None:
    result.examples += 1
    result.refused += outcome == "refused"
    result.written += outcome == "ok"


def _fuzz_images(folder: Path, examples: int, result: FuzzResult) -> None:
    """Mutated PNG/JPEG/WebP/TIFF seeds and random bytes through poison_file's reader."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from testkit.fuzz import SEEDS, fuzz_image_reader, mutate

    seeds = {**SEEDS, ".bin": b""}

    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))  # fmt: skip
    @given(
        suffix=st.sampled_from(sorted(seeds)),
        edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=16),
        cut=st.one_of(st.none(), st.integers(0, 6000)),
        noise=st.binary(max_size=3000),
    )
    def images(suffix: str, edits: list[tuple[int, int]], cut: int | None, noise: bytes) -> None:
        data = mutate(seeds[suffix], edits, cut) if seeds[suffix] else noise
        name = suffix if suffix != ".bin" else ".png"
        try:
            _count(result, fuzz_image_reader(folder, name, data))
        except Exception as exc:  # anything but ImageFormatError is a finding
            result.other_exceptions.append(f"{name}: {type(exc).__name__}: {exc}"[:300])
            result.examples += 1

    images()


def _fuzz_videos(folder: Path, clip: bytes, examples: int, result: FuzzResult) -> None:
    """Mutated MP4s through poison_video (a fifteenth as many examples as images, at least 20)."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from poisoner.spec import PatchSpec
    from poisoner.video import VideoFormatError, poison_video
    from testkit.fuzz import mutate

    @settings(max_examples=max(20, examples // 15), deadline=None, database=None,
              suppress_health_check=list(HealthCheck))  # fmt: skip
    @given(edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=16),
           cut=st.one_of(st.none(), st.integers(0, len(clip))))  # fmt: skip
    def videos(edits: list[tuple[int, int]], cut: int | None) -> None:
        src, dst = folder / "fuzz.mp4", folder / "out.mp4"
        src.write_bytes(mutate(clip, edits, cut) or b"\0")
        try:
            poison_video(src, dst, PatchSpec(patch_size=8, block_size=2))
            _count(result, "ok")
        except VideoFormatError as exc:
            assert "\n" not in str(exc)
            _count(result, "refused")
        except Exception as exc:
            result.other_exceptions.append(f"mp4: {type(exc).__name__}: {exc}"[:300])
            result.examples += 1

    videos()


def fuzz_run(root: Path, examples: int) -> FuzzResult:
    """Mutated PNG/JPEG/WebP/TIFF files and random bytes through poison_file, and mutated MP4s
    through poison_video: only their one-line error types may come out."""
    from testkit.reliability import make_video

    result = FuzzResult()
    started = time.monotonic()
    folder = root / "fuzz"
    folder.mkdir(parents=True, exist_ok=True)
    clip = make_video(folder / "seed.mp4", seed=1).read_bytes()
    _fuzz_images(folder, examples, result)
    _fuzz_videos(folder, clip, examples, result)
    result.seconds = time.monotonic() - started
    return result


def render(crash: list[CrashTrialReport], crash_failures: list[str], disk: list[dict[str, object]],
           corpus: CorpusResult, fuzz: FuzzResult, command: str) -> str:  # fmt: skip
    trials = sum(r.trials for r in crash)
    files = sum(r.files for r in crash)
    lines = [
        "## Faults (`bench_faults`)", "", f"Command: `{command}`", "",
        "### SIGKILL crash trials (`ppd watch` killed at a random instant 0.1-1.0 s after a drop)", "",
        "| figure | value |", "|---|---|",
        f"| trials (SIGKILLs) | {trials} in {len(crash)} completed chains |",
        f"| chains whose recovery run did not finish (findings) | {len(crash_failures)} "
        f"{crash_failures or ''} |",
        f"| files dropped (10 PNG/JPEG of 384 px per trial, a 160x120 MP4 every 3rd) | {files} "
        f"({sum(r.videos for r in crash)} videos) |",
        f"| kills that left a `pending` row or a `.ppd-tmp-*` file (this trial's or earlier) | "
        f"{sum(r.killed_with_work_pending for r in crash)} |",
        f"| kills that interrupted this trial's own protects, and where (files) | "
        f"{dict(sum((r.kill_phases for r in crash), start=Counter()))} |",
        f"| invariant checks after a kill with no violation | "
        f"{trials - len({v.split(':')[0] for r in crash for v in r.violations_after_kill})} of {trials} |",
        f"| files lost | {sum(r.lost for r in crash)} |",
        f"| files corrupted / store disagreeing with disk | {sum(r.corrupted for r in crash)} |",
        f"| files protected exactly once after the recovery run | "
        f"{files - sum(len(r.not_exactly_once) for r in crash)} of {files} |",
        f"| exit statuses of the killed daemons | {dict(sum((r.exit_codes for r in crash), start=Counter()))} |",  # noqa: E501
        f"| `.ppd-tmp-*` leftovers after recovery (deleted by a start once 60 s old) | "
        f"{sum(r.leftover_temporaries for r in crash)} |",
        f"| time | {sum(r.seconds for r in crash):.0f} s |",
        "",
        "### Full disk (3 MiB tmpfs holding outbox, store and vault; protect_file in-process)", "",
        "| bytes left | failed while full | protected while full | unclear errors "
        "| violations (full / after) | protected after space returned |",
        "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for run in disk:
        if "skipped" in run:
            lines.append(f"| {run['skipped']} | | | | | |")
            continue
        lines.append(
            f"| {run['leave_bytes']} | {run['failed_while_full']} | {run['protected_while_full']} | "
            f"{len(run['unclear_reasons'])} | {len(run['violations_while_full'])} / "
            f"{len(run['violations_after'])} | {run['protected_after_space_returned']} of {run['files']} |"
        )
    lines += [
        "", "### Hostile input corpus (moved into a running `ppd watch` as one folder)", "",
        "| figure | value |", "|---|---|",
        f"| inputs | {corpus.inputs} |",
        f"| protected / refused with a one-line error / left alone (links, FIFO, folder, non-UTF-8 name) | "
        f"{corpus.protected} / {corpus.refused} / {corpus.left_alone} |",
        f"| handled otherwise than expected | {len(corpus.unexpected)} {corpus.unexpected or ''} |",
        f"| daemon alive after the corpus; exit status on SIGTERM | {corpus.daemon_alive_after}; "
        f"{corpus.daemon_exit_code} |",
        "", "### Fuzz run (hypothesis; mutated and random files through the readers)", "",
        "| figure | value |", "|---|---|",
        f"| inputs tried | {fuzz.examples} ({fuzz.seconds:.0f} s) |",
        f"| refused with the reader's one-line error / written as a complete file | {fuzz.refused} / {fuzz.written} |",  # noqa: E501
        f"| other exceptions (findings) | {len(fuzz.other_exceptions)} {fuzz.other_exceptions[:5] or ''} |",
        "",
    ]  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=208)
    parser.add_argument("--chains", type=int, default=8)
    parser.add_argument("--fuzz-examples", type=int, default=1500)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv if argv is not None else [])
    root = Path(tempfile.mkdtemp(prefix="ppd-bench-faults-"))
    try:
        crash, crash_failures = crash_trials(root / "crash", args.trials, args.chains)
        disk = disk_full_runs(root / "disk", [0, 16 << 10, 64 << 10, 128 << 10, 256 << 10, 512 << 10])
        print("disk:", json.dumps(disk, default=str)[:1500], flush=True)
        corpus = corpus_run(root / "corpus")
        print("corpus:", json.dumps(asdict(corpus), default=str), flush=True)
        fuzz = fuzz_run(root, args.fuzz_examples)
        print("fuzz:", json.dumps(asdict(fuzz), default=str)[:1500], flush=True)
        if args.json:
            raw = {"crash": [plain(r) for r in crash], "crash_failures": crash_failures, "disk": disk,
                   "corpus": asdict(corpus), "fuzz": asdict(fuzz)}  # fmt: skip
            args.json.write_text(json.dumps(raw, default=str))
        command = ("python -m bench.bench_faults " + " ".join(argv or [])).strip()
        write_results_section("faults", render(crash, crash_failures, disk, corpus, fuzz, command))
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
