"""One file protected end to end: dataset → its one spec → vault → poison → atomic replace →
provenance row. Shared by `ppd poison` and the daemon's workers.

Order of operations (the crash-safety argument, docs/STORE.md):
1. the original is kept in the vault (hard link or fsynced copy) before anything else;
2. a 'pending' row naming the original's sha256 is committed;
3. the poisoned file is written complete to a temporary file next to the target and fsynced;
4. the source is re-checked (inode, size, mtime, sha256): a file replaced or edited meanwhile
   is not clobbered, the temporary file is dropped;
5. rename over the target (atomic), then the 'protected' row with the poisoned sha256.
A crash between any two steps leaves the original or the complete poisoned file at the
path, and the original in the vault whenever the path may hold the poisoned one.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import shutil
import stat
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon.config import Config
from daemon.dataset import OutsideOutboxError, dataset_of, dataset_root
from daemon.paths import AppPaths
from daemon.store import Store
from daemon.vault import Vault, sha256_file
from poisoner.atomic import TEMP_PREFIX, atomic_output, fsync_dir
from poisoner.spec import PatchSpec

log = logging.getLogger(__name__)

Progress = Callable[[int, int | None], None]
OUTCOME_STATES = ("protected", "skipped", "failed", "unchanged")  # protect_file
RESTORE_STATES = ("restored", "unchanged", "failed")  # restore_file


class ProtectRefused(Exception):
    """The file must not be touched (symlink, outside its dataset, not a regular file)."""


class SourceChanged(Exception):
    """The source changed while it was being protected."""


@dataclass
class ProtectOutcome:
    path: Path
    dataset: str | None
    state: str  # one of OUTCOME_STATES (RESTORE_STATES for restore_file)
    reason: str | None = None  # why skipped/unchanged, or the one-line error when failed
    kind: str | None = None  # 'image' | 'video'
    original_sha256: str | None = None
    poisoned_sha256: str | None = None
    spec_id: str | None = None
    output: Path | None = None  # where the protected file is now
    seconds: float = 0.0
    dry_run: bool = False
    report: Any = None  # poisoner.formats.PoisonReport (poisoner.video.VideoReport is one)


@dataclass
class AppContext:
    paths: AppPaths
    config: Config
    store: Store
    vault: Vault
    _path_locks: dict[str, threading.Lock] = field(default_factory=dict, repr=False)
    _path_locks_guard: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @classmethod
    def open(cls, paths: AppPaths | None = None) -> AppContext:
        paths = paths or AppPaths.from_env()
        paths.ensure()
        config = Config.load(paths)
        return cls(
            paths=paths,
            config=config,
            store=Store(paths.db_path),
            vault=Vault(paths.vault_dir, max_bytes=config.vault.max_bytes),
        )

    def close(self) -> None:
        self.store.close()

    @contextlib.contextmanager
    def path_lock(self, path: Path) -> Iterator[None]:
        """Serialise work on one path (two events for the same file must not race)."""
        key = str(path)
        with self._path_locks_guard:
            lock = self._path_locks.setdefault(key, threading.Lock())
        with lock:
            yield


def tool_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"ppd {version('patchpoison')}"
    except PackageNotFoundError:
        return "ppd 0.1.0"


def one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def shown_name(path: Path) -> str:
    """path's name as it can be shown on one line: escaped (repr-style) when it holds a newline,
    another control character or bytes that are not UTF-8."""
    name = path.name
    return name if name.isprintable() and storable(path) else repr(name)[1:-1]


def storable(path: Path) -> bool:
    """Whether the store can record this path: SQLite text is UTF-8, and a name with bytes
    that are not UTF-8 (surrogate-escaped by Python) cannot be written to it."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def failure_message(exc: BaseException, path: Path) -> str:
    """The one-line reason for a failure; a name with a newline is escaped first, so the line
    is not cut in the middle of the file's name."""
    text = str(exc)
    if path.name and shown_name(path) != path.name:
        text = text.replace(path.name, shown_name(path))
    lines = text.strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def media_kind(path: Path) -> str | None:
    """'image', 'video' or None, by suffix (lazy imports: the poisoners load only when used)."""
    from poisoner.formats import is_supported_image

    if is_supported_image(path):
        return "image"
    try:
        from poisoner.video import is_video
    except ImportError:
        return None
    return "video" if is_video(path) else None


def poison_to(kind: str, src: Path, dst: Path, spec: PatchSpec, progress: Progress | None = None) -> Any:
    """Write the complete poisoned version of src to dst; never touches src."""
    if kind == "video":
        from poisoner.video import poison_video

        return poison_video(src, dst, spec, progress=progress)
    from poisoner.formats import poison_file

    return poison_file(src, dst, spec)


def is_ignored_name(path: Path) -> bool:
    """Dot-files and our own temporaries are never protected."""
    return path.name.startswith(".") or path.name.startswith(TEMP_PREFIX)


def _recheck_source(path: Path, before: os.stat_result, sha: str) -> None:
    now = os.lstat(path)
    same = (now.st_ino, now.st_dev, now.st_size, now.st_mtime_ns) == (
        before.st_ino, before.st_dev, before.st_size, before.st_mtime_ns,
    )  # fmt: skip
    if not same or sha256_file(path) != sha:
        raise SourceChanged(f"{path.name} changed while being protected; left as it is now")


def _check_containment(path: Path, root: Path) -> Path:
    """The resolved path, refusing symlinks and anything that resolves outside root."""
    st = os.lstat(path)
    if stat.S_ISLNK(st.st_mode):
        raise ProtectRefused(f"refusing symlink {path.name} (ppd only protects regular files)")
    if not stat.S_ISREG(st.st_mode):
        raise ProtectRefused(f"{path.name} is not a regular file")
    resolved = path.resolve(strict=True)
    if not resolved.is_relative_to(root.resolve()):
        raise ProtectRefused(f"{path} resolves outside its dataset folder {root}")
    return resolved


def publish(src: Path, dst: Path) -> Path:
    """Move src to dst atomically (rename on one filesystem; else complete copy, then unlink)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.replace(src, dst)
        fsync_dir(dst.parent)
        fsync_dir(src.parent)
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise
        with atomic_output(dst, mode_like=src) as tmp:
            shutil.copyfile(src, tmp)
        src.unlink()
        fsync_dir(src.parent)
    return dst


def _resolve_dataset(ctx: AppContext, path: Path, dataset: str | None, root: Path | None) -> tuple[str, Path]:
    outbox = ctx.paths.outbox
    if dataset is None:
        dataset = dataset_of(outbox, path)
        return dataset, root or dataset_root(outbox, dataset)
    if root is not None:
        return dataset, root
    row = ctx.store.dataset(dataset)
    if row is not None:
        return dataset, Path(row["root"])
    if path.is_relative_to(outbox.absolute()):
        return dataset, dataset_root(outbox, dataset)
    return dataset, path.parent


def protect_file(
    path: Path,
    ctx: AppContext,
    dataset: str | None = None,
    *,
    root: Path | None = None,
    out_path: Path | None = None,
    dry_run: bool = False,
    force: bool = False,
    progress: Progress | None = None,
    spec: PatchSpec | None = None,
) -> ProtectOutcome:
    """Protect one file (see the module docstring for the order of operations).

    dataset/root: default from the outbox layout (daemon.dataset); `ppd poison FOLDER` passes
    the folder's name and the folder. out_path: write the protected copy there and leave path
    as it is. force: re-protect a file the user restored. spec: the spec a dataset without one
    gets (default: the config's), and the one a dry run assumes. Never raises for a bad file: the
    outcome says 'failed' with a one-line reason, and nothing is lost.
    """
    started = time.monotonic()
    path = Path(path).absolute()
    try:
        dataset, root = _resolve_dataset(ctx, path, dataset, root)
    except OutsideOutboxError as exc:
        return ProtectOutcome(path=path, dataset=None, state="failed", reason=one_line(exc))
    with ctx.path_lock(path):
        try:
            outcome = _protect(path, ctx, dataset, root, out_path, dry_run, force, progress, spec)
        except Exception as exc:  # one bad file must not stop the others; record and go on
            outcome = _record_failure(ctx, path, dataset, root, out_path, exc, dry_run, spec)
    outcome.seconds = time.monotonic() - started
    log.log(
        logging.INFO if outcome.state in ("protected", "failed") else logging.DEBUG,
        "protect %s: %s",
        outcome.state,
        path.name,
        extra={"path": str(path), "dataset": dataset, "state": outcome.state, "reason": outcome.reason,
               "seconds": round(outcome.seconds, 3)},
    )  # fmt: skip
    return outcome


def _record_failure(
    ctx: AppContext,
    path: Path,
    dataset: str,
    root: Path,
    out_path: Path | None,
    exc: Exception,
    dry_run: bool,
    spec: PatchSpec | None,
) -> ProtectOutcome:
    message = failure_message(exc, path)
    if not isinstance(exc, ProtectRefused | SourceChanged):
        log.debug("protect failed", exc_info=exc)
    if not storable(out_path or path):  # no row can name it; the log line says why
        log.warning("not recorded: %s: %s", shown_name(path), message, extra={"path": repr(str(path))})
    elif not dry_run:
        try:
            _ensure_dataset(ctx, dataset, root, spec)
            ctx.store.record_file(
                out_path or path, dataset, "failed", error=message, event="failed",
                detail={"error": message, "exception": type(exc).__name__},
            )  # fmt: skip
        except Exception as store_exc:  # the store itself failing (disk full) must not hide the first error
            log.error(
                "could not record failure of %s: %s", shown_name(path), one_line(store_exc),
                extra={"path": str(path), "error": message},
            )  # fmt: skip
    return ProtectOutcome(path=path, dataset=dataset, state="failed", reason=message)


def _ensure_dataset(ctx: AppContext, dataset: str, root: Path, spec: PatchSpec | None) -> PatchSpec:
    """The dataset's one spec; a new dataset gets spec (else the config's) with its first file."""
    initial = spec or ctx.config.spec_for(dataset)
    _, stored = ctx.store.ensure_dataset(dataset, root, initial, ctx.config.publish_dir_for(dataset))
    return stored


def _dataset_spec(
    ctx: AppContext, dataset: str, root: Path, dry_run: bool, spec: PatchSpec | None
) -> PatchSpec:
    if dry_run:
        return spec or ctx.store.dataset_spec(dataset) or ctx.config.spec_for(dataset)
    return _ensure_dataset(ctx, dataset, root, spec)


def _carry_moved_row(
    ctx: AppContext, earlier: dict[str, Any], path: Path, dataset: str, root: Path
) -> bool:
    """A protected file that was moved or renamed (a dataset folder renamed in the outbox, say)
    keeps its provenance: its row follows it to the new path instead of dropping out of the
    store, so status, restore and verification still see it. Copies (the old path still there)
    are left as they are."""
    old = Path(earlier["path"])
    if old == path or old.exists() or earlier["state"] not in ("protected", "removed"):
        return False
    fields = {k: earlier[k] for k in ("original_sha256", "poisoned_sha256", "spec_id", "tool_version")}
    # A dataset first seen through moved files (a renamed folder) inherits their patch spec.
    _ensure_dataset(ctx, dataset, root, ctx.store.get_spec(earlier["spec_id"]))
    st = path.stat()
    ctx.store.record_file(
        path, dataset, "protected", event="moved", detail={"from": str(old)},
        size=st.st_size, mtime_ns=st.st_mtime_ns, **fields,
    )  # fmt: skip
    ctx.store.record_file(old, earlier["dataset"], "removed", event="moved_away", detail={"to": str(path)})
    return True


def _protect(
    path: Path,
    ctx: AppContext,
    dataset: str,
    root: Path,
    out_path: Path | None,
    dry_run: bool,
    force: bool,
    progress: Progress | None,
    wanted_spec: PatchSpec | None,
) -> ProtectOutcome:
    def outcome(state: str, reason: str | None = None, **kw: Any) -> ProtectOutcome:
        return ProtectOutcome(path=path, dataset=dataset, state=state, reason=reason, dry_run=dry_run, **kw)

    if is_ignored_name(path):
        return outcome("skipped", "hidden or temporary file")
    if not storable(path):
        raise ProtectRefused(
            f"{shown_name(path)}: the file name is not valid UTF-8; rename it to protect it "
            "(ppd records names as UTF-8)"
        )
    resolved = _check_containment(path, root)
    kind = media_kind(path)
    record_path = Path(out_path).absolute() if out_path is not None else path
    if kind is None:  # not ours to judge (sidecars, notes): left alone, no row
        return outcome("skipped", "not a supported image or video")
    before = os.lstat(path)
    if before.st_size == 0:
        raise ValueError(f"{path.name} is empty (0 bytes); it may still be being written")
    sha = sha256_file(path)
    row = ctx.store.file(record_path)

    # Never poison twice: ppd's own output (here or anywhere) is left alone.
    if out_path is None and row is not None and row["poisoned_sha256"] == sha:
        return outcome("unchanged", "already protected", kind=kind, poisoned_sha256=sha, output=path)
    # An interrupted run of this very path first: its output may equal another file's (the same
    # photo in two datasets), which the look-up below would take as "someone else's output" and
    # leave this row pending for ever.
    interrupted = out_path is None and row is not None and row["state"] == "pending" and not dry_run
    if interrupted and _recover_pending(ctx, row, path, sha, kind):
        return outcome("unchanged", "recovered after an interrupted run", kind=kind, poisoned_sha256=sha)
    earlier = ctx.store.find_poisoned(sha)
    if earlier is not None:
        if out_path is None and not dry_run and _carry_moved_row(ctx, earlier, path, dataset, root):
            return outcome("unchanged", f"moved from {earlier['path']}", kind=kind, poisoned_sha256=sha)
        return outcome("unchanged", "already ppd output", kind=kind, poisoned_sha256=sha)
    if row is not None and row["state"] == "restored" and row["original_sha256"] == sha and not force:
        return outcome("unchanged", "restored by the user (use --force to protect it again)", kind=kind)

    spec = _dataset_spec(ctx, dataset, root, dry_run, wanted_spec)
    if (
        out_path is not None
        and row is not None
        and row["state"] == "protected"
        and row["original_sha256"] == sha
        and row["spec_id"] == spec.spec_id
        and record_path.is_file()
        and sha256_file(record_path) == row["poisoned_sha256"]
    ):
        return outcome("unchanged", "protected copy is up to date", kind=kind, output=record_path)

    rel = resolved.relative_to(root.resolve()).as_posix()
    if not spec.selects(rel):
        same = row is not None and row["state"] == "skipped" and row["original_sha256"] == sha
        if same and row is not None and row["spec_id"] == spec.spec_id:
            return outcome("unchanged", "not selected by the spec's ratio", kind=kind)
        if not dry_run:
            if out_path is not None:  # the copy is published as it is
                with atomic_output(record_path, mode_like=path) as tmp:
                    shutil.copyfile(path, tmp)
            ctx.store.record_file(
                record_path, dataset, "skipped", original_sha256=sha, spec_id=spec.spec_id,
                poisoned_sha256=None, error=None, event="skipped", detail={"reason": "ratio"},
            )  # fmt: skip
        return outcome("skipped", "not selected by the spec's ratio", kind=kind, spec_id=spec.spec_id)

    if dry_run:
        return outcome("protected", "would protect", kind=kind, original_sha256=sha, spec_id=spec.spec_id)

    # 1. the original goes to the vault first (a copy when the original stays in place).
    kept = ctx.vault.keep(path, link=out_path is None)
    if kept != sha:
        raise SourceChanged(f"{path.name} changed while being protected; left as it is now")
    # 2. a pending row: after a crash we know this path's original is in the vault.
    ctx.store.record_file(
        record_path, dataset, "pending", original_sha256=sha, spec_id=spec.spec_id, poisoned_sha256=None,
        error=None, tool_version=tool_version(), event="pending", detail={"kind": kind},
    )  # fmt: skip
    # 3-5. complete poisoned file next to the target, re-check the source, rename.
    if out_path is not None:
        record_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(record_path, mode_like=path) as tmp:
        report = poison_to(kind, path, tmp, spec, progress)
        poisoned_sha = sha256_file(tmp)
        _recheck_source(path, before, sha)
    final = record_path
    publish_dir = _publish_dir(ctx, dataset) if out_path is None else None
    if publish_dir is not None:
        final = publish(record_path, publish_dir / rel)
    st = final.stat()
    ctx.store.record_file(
        record_path, dataset, "protected", original_sha256=sha, poisoned_sha256=poisoned_sha,
        spec_id=spec.spec_id, tool_version=tool_version(), size=st.st_size, mtime_ns=st.st_mtime_ns,
        error=None, published_path=str(final) if final != record_path else None,
        event="protected", detail=_report_detail(report),
    )  # fmt: skip
    return outcome(
        "protected", None, kind=kind, original_sha256=sha, poisoned_sha256=poisoned_sha,
        spec_id=spec.spec_id, output=final, report=report,
    )  # fmt: skip


def _recover_pending(ctx: AppContext, row: dict[str, Any], path: Path, sha: str, kind: str) -> bool:
    """A 'pending' row means a run stopped between keeping the original and recording the
    result. If the file now differs from the original, it may be our complete output (the
    rename happened, the final row did not): poisoning is deterministic, so poison the vault
    original again and compare. True (and the row completed) when it is ours."""
    original_sha = row["original_sha256"]
    if not original_sha or sha == original_sha or not ctx.vault.verify(original_sha):
        return False
    spec = ctx.store.get_spec(row["spec_id"])
    with _named_vault_copy(ctx, original_sha, path.name) as original:
        scratch = original.with_name(f"redo{path.suffix}")
        try:
            poison_to(kind, original, scratch, spec)
        except Exception:  # cannot redo it: treat the file as new content
            return False
        if sha256_file(scratch) != sha:
            return False
    st = path.stat()
    ctx.store.record_file(
        path, row["dataset"], "protected", poisoned_sha256=sha, size=st.st_size, mtime_ns=st.st_mtime_ns,
        error=None, event="recovered", detail={"from": "pending"},
    )  # fmt: skip
    return True


def _publish_dir(ctx: AppContext, dataset: str) -> Path | None:
    row = ctx.store.dataset(dataset)
    return Path(row["publish_dir"]) if row and row["publish_dir"] else None


def _report_detail(report: Any) -> dict[str, Any]:
    detail: dict[str, Any] = {}
    for name in ("format", "width", "height", "preserved", "notes", "frames", "codec"):
        if hasattr(report, name):
            detail[name] = getattr(report, name)
    placement = getattr(report, "placement", None)
    if placement is not None:
        detail["placement"] = {
            "x": placement.x,
            "y": placement.y,
            "size": placement.size,
            "block": placement.block,
        }
    return detail


# ---- datasets as a whole ---------------------------------------------------------------------
def dataset_pairs(ctx: AppContext, dataset: str) -> list[tuple[Path, Path]]:
    """(original in the vault, protected file) for every protected file of a dataset whose two
    files both still exist (missing ones are logged, not returned)."""
    pairs = []
    for row in ctx.store.files(dataset, state="protected"):
        original = ctx.vault.path_for(row["original_sha256"])
        protected = Path(row["published_path"] or row["path"])
        if original.is_file() and protected.is_file():
            pairs.append((original, protected))
        else:
            log.warning("pair missing", extra={"dataset": dataset, "path": row["path"]})
    return pairs


def restore_file(ctx: AppContext, path: Path, *, force: bool = False) -> ProtectOutcome:
    """Put a protected file's original back where the protected file is (atomic). Refuses
    when the file there is no longer ppd's output (the user changed it) unless force."""
    path = Path(path).absolute()
    row = ctx.store.file(path)
    if row is None:
        return ProtectOutcome(path=path, dataset=None, state="failed", reason=f"{path} is not in the store")
    dataset = row["dataset"]
    if row["state"] != "protected" or not row["original_sha256"]:
        return ProtectOutcome(
            path=path, dataset=dataset, state="unchanged", reason=f"state is {row['state']}"
        )
    target = Path(row["published_path"] or row["path"])
    with ctx.path_lock(path):
        try:
            if target.exists() and not force and sha256_file(target) != row["poisoned_sha256"]:
                raise ProtectRefused(
                    f"{target.name} changed since ppd protected it; not overwriting (use --force)"
                )
            ctx.vault.restore(row["original_sha256"], target)
        except Exception as exc:
            return ProtectOutcome(path=path, dataset=dataset, state="failed", reason=one_line(exc))
        ctx.store.record_file(
            path,
            dataset,
            "restored",
            event="restored",
            detail={"to": str(target), "sha256": row["original_sha256"]},
        )
    return ProtectOutcome(
        path=path, dataset=dataset, state="restored", reason=None,
        original_sha256=row["original_sha256"], output=target,
    )  # fmt: skip


def reprotect_dataset(ctx: AppContext, dataset: str, spec: PatchSpec) -> list[ProtectOutcome]:
    """Give a dataset a new spec and re-poison its protected files from their vault originals.

    The new poisoned file is made from the vault copy and renamed over the old poisoned one,
    so the original never reappears at the published path, not even briefly.
    """
    row = ctx.store.dataset(dataset)
    if row is None:
        raise ValueError(f"no dataset {dataset!r}")
    root = Path(row["root"])
    ctx.store.set_dataset_spec(dataset, spec, allow_protected=True)
    outcomes = []
    for file_row in ctx.store.files(dataset):
        path = Path(file_row["path"])
        if file_row["state"] == "protected":
            outcomes.append(_reprotect_one(ctx, file_row, root, spec))
        elif file_row["state"] in ("skipped", "failed", "pending") and path.is_file():
            outcomes.append(protect_file(path, ctx, dataset, root=root))
    return outcomes


def _reprotect_one(ctx: AppContext, row: dict[str, Any], root: Path, spec: PatchSpec) -> ProtectOutcome:
    path = Path(row["path"])
    dataset = row["dataset"]
    target = Path(row["published_path"] or row["path"])
    with ctx.path_lock(path):
        try:
            if not target.is_file() or sha256_file(target) != row["poisoned_sha256"]:
                raise ProtectRefused(f"{target.name} changed since ppd protected it; not re-protecting it")
            if not ctx.vault.verify(row["original_sha256"]):
                raise ProtectRefused(f"the vault copy of {path.name} is missing or corrupt")
            kind = media_kind(path) or "image"
            rel = path.relative_to(root).as_posix() if path.is_relative_to(root) else path.name
            with (
                _named_vault_copy(ctx, row["original_sha256"], path.name) as original,
                atomic_output(target) as tmp,
            ):
                if spec.selects(rel):
                    report = poison_to(kind, original, tmp, spec)
                    state = "protected"
                else:
                    shutil.copyfile(original, tmp)
                    report, state = None, "skipped"
                new_sha = sha256_file(tmp)
            st = target.stat()
            ctx.store.record_file(
                path, dataset, state, poisoned_sha256=new_sha if state == "protected" else None,
                spec_id=spec.spec_id, tool_version=tool_version(), size=st.st_size, mtime_ns=st.st_mtime_ns,
                error=None, event="reprotected", detail={"spec_id": spec.spec_id, **_report_detail(report)},
            )  # fmt: skip
        except Exception as exc:
            return ProtectOutcome(path=path, dataset=dataset, state="failed", reason=one_line(exc))
    return ProtectOutcome(
        path=path, dataset=dataset, state=state, original_sha256=row["original_sha256"],
        poisoned_sha256=new_sha if state == "protected" else None, spec_id=spec.spec_id, output=target,
    )  # fmt: skip


@contextlib.contextmanager
def _named_vault_copy(ctx: AppContext, sha256: str, name: str) -> Iterator[Path]:
    """The vault blob under its original file name (poisoners pick the format by suffix), as a
    hard link in a private temporary folder inside the vault."""
    folder = Path(tempfile.mkdtemp(prefix=".named-", dir=ctx.vault.vault_dir))
    link = folder / name
    try:
        try:
            os.link(ctx.vault.path_for(sha256), link)
        except OSError:
            shutil.copyfile(ctx.vault.path_for(sha256), link)
        yield link
    finally:
        shutil.rmtree(folder, ignore_errors=True)
