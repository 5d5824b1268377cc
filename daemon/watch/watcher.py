"""`ppd watch`: the daemon around the event layer (daemon.watch.outbox).

WatchDaemon owns the outbox lock, a catch-up scan at start (and after lost events), the worker
pool (daemon.watch.workers: threads, back-pressure), the per-file worker processes
(daemon.protect.pool: each file's stages run there, so this process stays free of numpy, PIL
and PyAV), quarantine of hopeless files, retries once disk space returns, verification
scheduling, and the systemd protocol (daemon.watch.notify). Its main thread sleeps until an event
needs it; the one timer is systemd's watchdog (and a worker process's idle exit).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import stat
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.datasets.linked_folders import LinkedFolder, LinkWarnings, linked_folders, linked_folders_under
from daemon.locks import outbox_lock
from daemon.protect.job import Outcome, media_kind
from daemon.states import FileState
from daemon.watch.notify import SystemdNotifier
from daemon.watch.outbox import (
    OutboxWatcher,
    WatchOptions,
    folder_identity,
    is_candidate,
    scan_outbox,
    signature,
    walk_files,
)
from daemon.watch.outcomes import (
    DaemonCounts,
    is_no_space,
    is_under,
    row_matches_disk,
    say,
    say_outcome,
    say_removed,
    status_line,
)
from daemon.watch.waiting import FolderWaits, SpaceWaits, WriterWaits
from daemon.watch.workers import PoolOptions, WorkerPool, release_free_memory
from poisoner.media import MEDIA_SUFFIXES

__all__ = ["DaemonOptions", "WatchDaemon", "WatchOptions", "is_no_space", "scan_outbox"]

log = logging.getLogger(__name__)

GONE_MID_WORK = "deleted or moved away while it was being patched"
REMEMBER_REMOVED = 10_000  # paths counted removed, remembered so that none counts twice


# ---- the daemon: watcher + catch-up + workers + systemd ---------------------------------------
@dataclass(frozen=True)
class DaemonOptions:
    watch: WatchOptions = WatchOptions()
    workers: int = 2
    queue_size: int = 256
    max_pending: int = 100_000
    tmp_grace_s: float = 60.0  # younger `.ppd-tmp-*` files may belong to a running `ppd poison`
    no_space_poll_s: float = 5.0  # while files wait for disk space: how often free space is checked
    no_space_retry_s: float = 300.0  # ... and retried anyway (space freed elsewhere, quota raised)
    verify: bool = True  # run the VerificationScheduler (daemon.verification.scheduler)
    # Each file is protected in a worker process (daemon.protect.pool), so this process never
    # loads numpy, PIL or PyAV; the workers exit after worker_idle_s without a file.
    worker_processes: bool = True
    worker_idle_s: float = 30.0
    # A file whose structure is incomplete is re-checked (its writer may append more after a
    # pause) and quarantined only once it has not changed for this long (config: [daemon]).
    incomplete_wait_s: float = 120.0
    # A renamed outbox wakes the daemon at once (IN_MOVE_SELF); one moved with a folder above it, or
    # replaced while the daemon slept, is noticed within this (its folder identity is compared).
    outbox_check_s: float = 30.0

    @classmethod
    def from_config(cls, config: Any, **overrides: Any) -> DaemonOptions:
        """Options from daemon.config.Config (workers, debounce_seconds, verification.enabled)."""
        base = cls(
            watch=WatchOptions(
                settle_s=float(config.debounce_seconds),
                max_settle_s=float(config.daemon.max_debounce_seconds),
            ),
            workers=int(config.workers),
            verify=bool(config.verification.enabled),
            incomplete_wait_s=float(config.daemon.incomplete_wait_seconds),
        )
        settle = overrides.pop("settle_s", None)
        if settle is not None:
            base = dataclasses.replace(base, watch=dataclasses.replace(base.watch, settle_s=settle))
        return dataclasses.replace(base, **{k: v for k, v in overrides.items() if v is not None})


class WatchDaemon:
    """`ppd watch`: catch-up scan, live watching, the worker pool, verification scheduling
    and the systemd protocol, until `request_stop()` (SIGTERM/SIGINT)."""

    def __init__(self, ctx: Any, options: DaemonOptions, notifier: SystemdNotifier | None = None) -> None:
        self.ctx = ctx  # daemon.protect.one_file.AppContext
        self.outbox = Path(ctx.paths.outbox).absolute()
        self.options = options
        self.notifier = notifier or SystemdNotifier()
        self.suffixes = MEDIA_SUFFIXES
        self.counts = DaemonCounts()
        self._counts_lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._rescan_needed = threading.Event()
        self.ready = threading.Event()  # set once watching (tests, embedding)
        self._trim_due = threading.Event()
        self.space_waits = SpaceWaits((self.outbox, Path(ctx.paths.data_dir)), options.no_space_retry_s)
        self.waits = WriterWaits(
            ctx.store, options.incomplete_wait_s, options.watch.settle_s, options.watch.max_settle_s
        )  # incomplete files waited for
        self.folder_waits = FolderWaits()  # files waiting for their dataset's subject masks
        self.link_warnings = LinkWarnings()  # symlinked folders warned of, each once
        # Paths counted removed, until a file is processed there again: a file counts once, however
        # many jobs find it gone (its own, its folder's, its deletion event's); oldest forgotten first.
        self._removed: OrderedDict[Path, None] = OrderedDict()
        self._removal_lock = threading.Lock()
        self.pool = WorkerPool(
            self.process,
            PoolOptions(
                workers=options.workers, queue_size=options.queue_size, max_pending=options.max_pending
            ),
            on_idle=self._on_pool_idle,
        )
        self.watcher = self._new_watcher()
        self.scheduler: Any = None
        self._owner = contextlib.ExitStack()
        self.protectors: Any = None  # daemon.protect.pool.ProtectWorkers, made on start

    # ---- lifecycle ----------------------------------------------------------------------------
    def request_stop(self) -> None:
        """Safe from a signal handler: only sets two events."""
        self._stop.set()
        self._wake.set()

    def start(self) -> None:
        """Raises daemon.locks.LockHeld (one line naming the holder's pid) when another
        `ppd watch` already watches this outbox."""
        self.outbox.mkdir(parents=True, exist_ok=True)
        self._owner.enter_context(outbox_lock(self.ctx.paths.data_dir, self.outbox))
        self.scheduler = self._start_scheduler() if self.options.verify else None
        if self.options.worker_processes:
            from daemon.protect.pool import ProtectWorkers

            self.protectors = ProtectWorkers(self.ctx, self.options.workers, self.options.worker_idle_s)
            self.protectors.warm()  # ready means the first files need not wait for a worker's imports
        self.pool.start()
        self.watcher.start()  # before the scan: nothing written during the scan is missed
        self.catch_up(remove_leftovers=True)

    def run(self) -> int:
        """Start, serve until asked to stop, shut down; the exit status (0 on a clean stop)."""
        self.start()
        self.notifier.ready(self.status())
        self.ready.set()
        log.info("ppd watch ready", extra={"outbox": str(self.outbox), "workers": self.options.workers})
        ping = self.notifier.watchdog_interval
        last_status = ""
        while not self._stop.is_set():
            # Sleeps until an event needs the main thread; the only timer is systemd's watchdog.
            self._wake.wait(timeout=self._wake_timeout(ping))
            self._wake.clear()
            if self._stop.is_set():
                break
            self._keep_watching()
            self._retry_waiting()
            if self.pool.take_overflow():
                self._rescan_needed.set()
            if self._rescan_needed.is_set() and self._idle_enough():
                self._rescan_needed.clear()
                self.catch_up()
            if self._trim_due.is_set() and self._idle_enough():
                self._trim_due.clear()
                release_free_memory()
            if self.protectors is not None:
                self.protectors.end_idle()
            if ping and self.watcher.is_alive():
                self.notifier.watchdog()  # only while events can still arrive
            status = self.status()
            if status != last_status:
                self.notifier.status(status)
                last_status = status
        self.shutdown()
        return 0

    def shutdown(self) -> None:
        self.notifier.stopping("stopping: finishing files in flight")
        log.info("stopping: no new work; waiting for files in flight", extra=self._stats_extra())
        self.watcher.stop()
        dropped = self.pool.stop()
        if self.protectors is not None:
            self.protectors.close()
        if dropped:
            log.info("%d queued file(s) left for the next start's catch-up scan", len(dropped))
        if self.scheduler is not None:
            try:
                self.scheduler.stop()
            except Exception:
                log.exception("verification scheduler did not stop cleanly")
        log.info("stopped: %s", self.status())
        self._owner.close()  # the outbox lock

    # ---- helpers of the main loop -------------------------------------------------------------
    def _start_scheduler(self) -> Any:
        from daemon.verification.scheduler import (
            VerificationScheduler,  # light: the verifier loads when a run starts
        )

        scheduler = VerificationScheduler(self.ctx)
        scheduler.start()
        return scheduler

    def _on_pool_idle(self) -> None:
        self._trim_due.set()
        self._wake.set()

    def _on_lost_events(self) -> None:
        self._rescan_needed.set()
        self._wake.set()

    def _wake_timeout(self, ping: float | None) -> float | None:
        """How long the main loop may sleep: systemd's watchdog, a pending rescan, files
        waiting for disk space."""
        waits = [ping] if ping else []
        # The outbox moved with a folder above it gives no event: its identity is checked this often.
        waits.append(self.options.outbox_check_s)
        if self._rescan_needed.is_set():
            waits.append(5.0)
        if self.space_waits or self.folder_waits:
            waits.append(self.options.no_space_poll_s)
        if self.protectors is not None and (idle_in := self.protectors.end_idle()) is not None:
            waits.append(idle_in + 0.05)  # then the idle workers exit
        return min(waits)

    def _retry_waiting(self) -> None:
        """Queue again the files whose subject masks are back, and those that failed for lack of
        space once space has returned (SpaceWaits)."""
        for path in [*self.folder_waits.back(), *self.space_waits.due()]:
            self.watcher.forget(path)  # its signature was recorded as processed
            self.pool.submit(path)

    def _idle_enough(self) -> bool:
        stats = self.pool.stats()
        return stats.queued + stats.pending == 0

    def _new_watcher(self) -> OutboxWatcher:
        return OutboxWatcher(
            self.outbox, self.pool.submit, self.options.watch, self.suffixes, self._on_lost_events,
            on_moved=self._wake.set,  # a folder renamed: perhaps the outbox (checked by _keep_watching)
        )  # fmt: skip

    def _keep_watching(self) -> None:
        """Restart the observer when the outbox was deleted or moved away (and recreate it), or when
        the folder at its path is another one: moved away and a folder of the same name made again,
        the observer alive on the old one (the daemon went deaf for good: a black-box review)."""
        now = folder_identity(self.outbox)
        alive = self.watcher.is_alive()
        if alive and now is not None and now == self.watcher.identity and self.outbox.is_dir():
            return
        if alive and now is not None and self.outbox.is_dir():
            log.warning(
                "the outbox %s is another folder now (the one watched was moved away); watching it and "
                "rescanning", self.outbox, extra={"outbox": str(self.outbox)},
            )  # fmt: skip
        else:
            log.error("outbox watch lost; recreating %s and rescanning", self.outbox)
        self.watcher.stop()
        try:
            self.outbox.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            log.error("cannot recreate the outbox %s: %s", self.outbox, exc.strerror)
            self._rescan_needed.set()  # retried on the next wake-up (every 5 s while needed)
            return
        self._lock_outbox_again(self.watcher.identity)
        self.watcher = self._new_watcher()
        self.watcher.start()
        self._rescan_needed.set()

    def _lock_outbox_again(self, watched: Any) -> None:
        """The outbox lock is the folder's (daemon.locks): a new folder at the path gets it, so that no
        second `ppd watch` is let in on the folder this daemon now watches; the old one's goes."""
        from daemon.locks import LockHeld

        if watched is not None and folder_identity(self.outbox) == watched:
            return  # the same folder (its observer died): its lock is held already
        fresh = contextlib.ExitStack()
        try:
            fresh.enter_context(outbox_lock(self.ctx.paths.data_dir, self.outbox))
        except LockHeld as exc:  # another daemon took the new folder meanwhile: it is said, not fought
            log.error("%s; this daemon watches it too", exc)
            return
        self._owner.close()
        self._owner = fresh

    def status(self) -> str:
        with self._counts_lock:
            counts = dataclasses.replace(self.counts)
        return status_line(counts, self.pool.stats(), self.watcher.armed_count)

    def _stats_extra(self) -> dict[str, Any]:
        return {"status": self.status()}

    def _count(self, state: str) -> None:
        with self._counts_lock:
            if hasattr(self.counts, state):
                setattr(self.counts, state, getattr(self.counts, state) + 1)
        self._wake.set()  # the main loop refreshes STATUS=

    # ---- catch-up -----------------------------------------------------------------------------
    def catch_up(self, remove_leftovers: bool = False) -> int:
        """Reconcile the outbox with the store after a downtime (or lost events).

        remove_leftovers: delete old `.ppd-tmp-*` files, crash leftovers. Only at start-up:
        later, this daemon's own workers have temporaries in progress (a video's for minutes).

        Queues every candidate file whose (size, mtime) differ from its patched row (new or
        changed while ppd was down; protect_file itself says 'unchanged' for its own output),
        and every path the store knows but the disk no longer has (recorded 'removed').
        Returns how many paths were queued.
        """
        started = time.monotonic()
        if remove_leftovers:
            self._report_crashed_attempts()
        grace = self.options.tmp_grace_s if remove_leftovers else None
        result = scan_outbox(self.outbox, self.suffixes, grace)
        for tmp in result.stale_temps_removed:
            log.info("removed leftover temporary file %s", tmp, extra={"path": str(tmp)})
        self._warn_links(linked_folders_under(self.outbox, own=[self.outbox]))
        rows = self._known_rows()
        queued = 0
        on_disk = set()
        for path in result.files:
            on_disk.add(str(path))
            row = rows.get(str(path))
            if row is not None and row_matches_disk(row, path):
                self.watcher.mark_settled(path)
                continue
            queued += int(self.pool.submit(path))
        for path_text, row in rows.items():
            gone = path_text not in on_disk and row["state"] != FileState.REMOVED
            if gone and is_under(self.outbox, path_text):
                queued += int(self.pool.submit(Path(path_text)))
        seconds = round(time.monotonic() - started, 3)
        log.info(
            "catch-up scan: %d file(s) on disk, %d queued", len(result.files), queued,
            extra={"files": len(result.files), "queued": queued, "seconds": seconds},
        )  # fmt: skip
        return queued

    def _report_crashed_attempts(self) -> None:
        """Files whose last attempt died with ppd: their next attempt runs the poisoner in a child
        process (daemon.protect.poisoning.poison_isolated), and a child that dies gets the file
        quarantined."""
        from daemon.protect.quarantine import crashed_attempts

        for crashed in crashed_attempts(self.ctx.paths.data_dir):
            log.warning(
                "ppd died while patching %s (pid %d); its next attempt runs isolated",
                crashed.path, crashed.pid,
                extra={"path": str(crashed.path)},
            )  # fmt: skip

    def _warn_links(self, links: list[LinkedFolder]) -> None:
        """A symlinked folder in the outbox: never followed, so its photos stay unmarked, and a publisher
        that follows links ships them. Warned of once per link (it was an info line when made while the
        daemon ran, and nothing when there at its start: a black-box review)."""
        for link in self.link_warnings.new(links):
            log.warning(
                "symlinked folder %s -> %s: %d photo(s) or video(s) in it NOT protected (ppd never follows a "
                "link; a publisher that does ships them): put the folder itself in place of the link",
                link.path, link.target, link.photos, extra={"path": str(link.path), "photos": link.photos},
            )  # fmt: skip

    def _quarantine_link(self, path: Path) -> None:
        """A photo's name that is a symlink: ppd never follows one (it would patch a file outside the
        outbox), and a publisher that does (`cp -L`, `rsync -L`, a web server) would ship the file it
        points to unprotected. The link itself (never its target) leaves the outbox, as DAEMON.md says;
        it was left in place, logged at info on every start (a black-box review)."""
        from daemon.datasets.dataset import dataset_of
        from daemon.protect.quarantine import quarantine

        reason = f"{path.name} is a symlink: ppd never follows one; put the file itself in the outbox"
        started, event, dataset = time.monotonic(), self._event_of(path), dataset_of(self.outbox, path)
        try:
            moved = quarantine(self.ctx, path, dataset, reason)
        except OSError as exc:
            log.error("cannot quarantine %s: %s", path, exc.strerror, extra={"path": str(path)})
            return
        if moved is not None:  # the line every file gets (it was free text without them: a review)
            self.watcher.forget(path)
            self._count("quarantined")
            say(event, path, dataset, Outcome.QUARANTINED.value, time.monotonic() - started, reason, moved)

    def _quarantine_if_hopeless(self, path: Path, outcome: Any) -> Path | None:
        """A file that failed for a reason a retry will not change leaves the outbox: where it went."""
        if outcome.state != Outcome.FAILED or not outcome.hopeless:
            return None  # a full disk or vault, a busy store, another ppd's lock: retried, not moved
        reason = outcome.reason or ""
        from daemon.protect.quarantine import quarantine

        try:
            moved = quarantine(self.ctx, path, outcome.dataset, reason)
        except OSError as exc:
            log.error("cannot quarantine %s: %s", path, exc.strerror, extra={"path": str(path)})
            return None
        if moved is not None:
            self.watcher.forget(path)
        return moved

    def _known_rows(self) -> dict[str, dict[str, Any]]:
        store = self.ctx.store
        return {row["path"]: row for ds in store.datasets() for row in store.files(ds["name"])}

    # ---- the worker's job ---------------------------------------------------------------------
    def process(self, path: Path) -> None:
        """Whatever the path now is: protect a file, walk a moved-in folder, record a removal."""
        try:
            st = os.stat(path, follow_symlinks=False)
        except FileNotFoundError:
            self.watcher.forget(path)
            self._record_removed(path)
            return
        except OSError as exc:
            log.warning("cannot stat %s: %s", path, exc.strerror, extra={"path": str(path)})
            st = None
        if st is not None and stat.S_ISDIR(st.st_mode):
            self._warn_links(linked_folders_under(path, own=[self.outbox]))  # moved in with links in it
            for child in walk_files(path):
                if is_candidate(self.outbox, child, self.suffixes) and not self.watcher.is_settled(child):
                    self.pool.submit(child)
            return
        named = is_candidate(self.outbox, path, self.suffixes, by_content=False)  # a folder has no suffix
        # a link with no suffix to a photo is published as the photo too (a diff review): judged by its target
        linked = st is not None and stat.S_ISLNK(st.st_mode)
        if linked and path.is_dir():  # a symlinked folder: never followed, warned of
            self._warn_links(linked_folders([path], own=[self.outbox]))
            return
        if linked and (named or (is_candidate(self.outbox, path, self.suffixes) and media_kind(path))):
            self._quarantine_link(path)
            return
        if st is not None and not stat.S_ISREG(st.st_mode):
            log.info("not a regular file, left alone: %s", path, extra={"path": str(path)})
            return
        if self.watcher.is_settled(path):
            return
        if not named and media_kind(path) is None:  # its bytes are no photo ppd patches (a sidecar)
            self.watcher.mark_settled(path)  # judged again once it changes
            return
        judged = signature(path)
        with self._removal_lock:
            self._removed.pop(path, None)  # a file here again: its removal counts again
        event = self.waits.event_of(path) or self._event_of(path)
        started = time.monotonic()
        outcome = self._protect(path)
        if outcome.state == Outcome.FAILED and not os.path.lexists(path):
            self._gone_mid_work(path, outcome)
            return
        if (
            outcome.state == Outcome.FAILED
            and outcome.incomplete
            and self.waits.wait(path, judged, event, self.watcher)
        ):
            self._count("skipped")
            self.waits.record(path, outcome)
            return
        self.waits.done(path)
        # The signature of what ppd judged or wrote, not of what is there now: a version that
        # arrived meanwhile must not be taken for an echo of ppd's own work.
        if outcome.signature is None and outcome.state == Outcome.FAILED:
            self.watcher.mark_settled(path)  # the same bytes fail the same way: no event loop
        else:
            self.watcher.settle_as(path, outcome.signature)
        if outcome.requeue:
            self.pool.submit(path)  # runs once more after this job (daemon.watch.workers)
        if self.space_waits.note(path, outcome.reason if outcome.state == Outcome.FAILED else None):
            self._wake.set()  # the main loop's wait now includes the no-space poll
        self.folder_waits.note(path, outcome.waits_for if outcome.state == Outcome.FAILED else None)
        moved = self._quarantine_if_hopeless(path, outcome)
        state = Outcome.QUARANTINED.value if moved is not None else str(outcome.state)
        self._count(state)  # one count per file: a quarantined file is not also "failed"
        say_outcome(event, path, outcome, state, time.monotonic() - started, moved)
        if outcome.state == Outcome.PATCHED and self.scheduler is not None and outcome.dataset:
            try:
                self.scheduler.on_protected(outcome.dataset)
            except Exception:
                log.exception("verification scheduler failed", extra={"dataset": outcome.dataset})

    def _event_of(self, path: Path) -> str:
        """`changed`: a row says ppd saw a file here before (not one removed since); else `new`."""
        from daemon.protect.job import storable  # a name the store cannot hold has no row

        row = self.ctx.store.file(path) if storable(path) else None
        return "changed" if row is not None and row["state"] != FileState.REMOVED else "new"

    def _protect(self, path: Path) -> Any:
        """protect_file, in a worker process unless the options say in this one."""
        if self.protectors is not None:
            return self.protectors.protect(path)
        from daemon.protect.one_file import protect_file  # lazy: keeps `import daemon.watch.watcher` light

        return protect_file(path, self.ctx)

    def _gone_mid_work(self, path: Path, outcome: Any) -> None:
        """A file deleted, or its folder renamed, while it was being patched: counted and said once,
        as removed (info), not as failed (a warning, `failed 1` in the stop summary and STATUS=, then
        `removed` as well for the same file: a black-box review). Its deletion event, queued meanwhile,
        then finds its row removed already."""
        from daemon.protect.job import storable

        self.watcher.forget(path)
        self.waits.done(path)
        self.space_waits.note(path, None)
        if self._record_removed(path, GONE_MID_WORK):
            return
        with self._removal_lock:
            if path in self._removed or (storable(path) and self.ctx.store.file(path) is not None):
                return  # counted by its folder's job meanwhile (or quarantined)
            self._removed[path] = None
        self._count("removed")  # no row was written for it: still one count and one line
        say_removed(path, outcome.dataset, GONE_MID_WORK)

    def _record_removed(self, path: Path, reason: str | None = None) -> int:
        """Rows for path, or for every file under path when it was a folder, become 'removed'; how
        many were counted (and said) now. One job at a time: a folder's job and its files' jobs
        both find a file gone, and each counted and said it (`removed` twice: a black-box review)."""
        from daemon.protect.job import storable

        if not storable(path):
            return 0  # a name the store cannot hold has no row (quarantined ones included)
        with self._removal_lock:
            return self._record_removed_locked(path, reason)

    def _record_removed_locked(self, path: Path, reason: str | None) -> int:
        store = self.ctx.store
        row = store.file(path)
        rows = [row] if row is not None else []
        if not rows and not is_candidate(self.outbox, path, self.suffixes, by_content=False):
            # Perhaps a folder: its files' rows. (A media name is taken for a file, so deleting
            # 10k unknown files does not scan the store 10k times.)
            prefix = str(path) + os.sep
            rows = [r for r in self._known_rows().values() if r["path"].startswith(prefix)]
        counted = 0
        for r in rows:
            if r["state"] in (FileState.REMOVED, FileState.QUARANTINED) or Path(r["path"]).exists():
                continue
            published = r.get("published_path")
            if r["state"] == FileState.PATCHED and published and Path(published).exists():
                continue  # moved to its publish folder by ppd itself, not removed
            store.record_file(
                r["path"],
                r["dataset"],
                FileState.REMOVED,
                event="removed",
                detail={"previous_state": r["state"]},
            )
            gone = Path(r["path"])
            if gone in self._removed:
                continue  # counted already (its worker wrote its row again after): the row only
            self._removed[gone] = None
            if len(self._removed) > REMEMBER_REMOVED:
                self._removed.popitem(last=False)
            self._count("removed")  # DaemonCounts.removed
            say_removed(gone, r["dataset"], reason)
            counted += 1
        return counted

