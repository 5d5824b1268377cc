"""The poisoner called on a private copy: in this process (poison_to) or isolated in a child
(poison_isolated, `python -m daemon.protect.child`: a file that kills its process kills only the
child); the provenance seal; ppd's private work folders inside the vault, and vault originals
under their file names. Whether a failure is the file's own (file_is_the_cause)."""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.datasets.subject_masks import load_keep_out
from daemon.protect.job import IncompleteFile, Progress, ProtectRefused
from daemon.store.vault import WORK_LOCK, WORK_PREFIX
from poisoner.errors import ExitStatus, PpdError
from poisoner.spec import PatchSpec

if TYPE_CHECKING:
    from daemon.context import AppContext


def poison_to(
    kind: str,
    src: Path,
    dst: Path,
    spec: PatchSpec,
    progress: Progress | None = None,
    subject_masks: Path | None = None,
    **options: Any,
) -> Any:
    """Write the complete poisoned version of src to dst; never touches src. subject_masks: a folder
    whose mask for src's name (daemon.datasets.subject_masks.load_keep_out) marks pixels the mark never
    changes;
    a folder without one for this image patches it without keep-out (logged)."""
    if kind == "video":
        from poisoner.video import poison_video

        return poison_video(src, dst, spec, progress=progress, **options)
    from poisoner.formats import poison_file

    return poison_file(src, dst, spec, **_image_options(src, subject_masks, options))


def poison_image_bytes(
    src: Path, data: bytes, spec: PatchSpec, subject_masks: Path | None = None, **options: Any
) -> tuple[bytes, Any]:
    """poison_to for an image whose bytes (data, src's) are in memory: the complete poisoned file's
    bytes, not written anywhere (the caller seals, hashes and writes them once), and the report."""
    from poisoner.formats import poison_bytes

    return poison_bytes(src, spec, data=data, **_image_options(src, subject_masks, options))


def _image_options(src: Path, subject_masks: Path | None, options: dict[str, Any]) -> dict[str, Any]:
    """The image poisoner's options: the subject mask loaded (keep_out), Pillow's limit raised."""
    from poisoner.image.read import raise_bomb_limit

    # Pillow's own bomb check would refuse what the user's raised [limits] allows.
    raise_bomb_limit(options.get("max_pixels"))
    if subject_masks is not None:
        keep_out = load_keep_out(Path(subject_masks), src)
        if keep_out is not None:
            options["keep_out"] = keep_out
    return options


class PoisonerDied(PpdError):
    """The isolated poisoner process died (a signal: out of memory, a decoder crash)."""

    exit_status = ExitStatus.FAILED


def poison_isolated(
    kind: str,
    src: Path,
    dst: Path,
    spec: PatchSpec,
    marker: Any,
    keep_location: bool,
    subject_masks: Path | None = None,
    **limits: int,
) -> Any:
    """poison_to in a child process: a file that kills its process kills only the child. A child
    killed by a signal raises PoisonerDied; one that fails raises its last error line. The mask
    folder crosses as a path; the child loads the mask. Returns the child's report (where the mark
    went and why, what was kept), as poison_to does: a file patched here is said like any other."""
    import json
    import pickle
    import subprocess
    import sys

    args = {
        "kind": kind, "src": os.fsdecode(src), "dst": os.fsdecode(dst), "spec": spec.to_dict(),
        "marker": {"text": marker.text},  # the placeholder only: the key never leaves this process
        "keep_location": keep_location, "limits": limits,
        "subject_masks": os.fsdecode(subject_masks) if subject_masks is not None else None,
    }  # fmt: skip
    # the report comes back through a file beside dst (ppd's private work folder): stdout is the
    # poisoner's to write on; pickle, since the report is the poisoner's own dataclasses, between this
    # process and its own child
    report_file = dst.with_name(f"{dst.name}.report")
    args["report"] = os.fsdecode(report_file)
    from verifier.childenv import child_env
    from verifier.supervise import child_setup_env

    done = subprocess.run(  # the child dies with this process: no patch finishing on its own
        [sys.executable, "-m", "daemon.protect.child", json.dumps(args)],
        capture_output=True, text=True, env={**child_env(), **child_setup_env()}, check=False,
    )  # fmt: skip
    if done.returncode < 0:
        raise PoisonerDied(
            f"{src.name}: patching it killed its process twice (signal {-done.returncode}: out of memory or "
            "a decoder crash); not retried"
        )
    try:
        if done.returncode != 0:
            lines = [line for line in done.stderr.strip().splitlines() if line.strip()]
            raise RuntimeError(lines[-1] if lines else f"the isolated poisoner failed ({done.returncode})")
        return pickle.loads(report_file.read_bytes())
    finally:
        report_file.unlink(missing_ok=True)


def file_is_the_cause(exc: BaseException) -> bool:
    """Whether a failure is the file's own (its format, structure, size or name), so retrying it
    changes nothing (the daemon quarantines such files); disk, store, lock and vault-limit
    failures are not."""
    from poisoner.formats import ImageFormatError

    causes: tuple[type[BaseException], ...] = (ProtectRefused, IncompleteFile, PoisonerDied, ImageFormatError)
    try:
        from poisoner.video import VideoFormatError

        causes += (VideoFormatError,)
    except ImportError:  # PyAV missing
        pass
    return isinstance(exc, causes) or (isinstance(exc, ValueError) and not isinstance(exc, OSError))


def provenance_marker(ctx: AppContext, spec_id: str, original_sha256: str | None) -> Any:
    """The seal placeholder every patched file carries (poisoner.provenance); `seal_output` seals
    the finished file: ppd knows its own output without a row, nobody else can read or forge it."""
    from poisoner.provenance import Marker

    return Marker.placeholder(ctx.seal_key(), spec_id, original_sha256 or "")


def seal_output(ctx: AppContext, path: Path) -> None:
    """Seal a finished patched file in place (its placeholder's tag over exactly its bytes)."""
    from poisoner.provenance import seal_file

    seal_file(path, ctx.seal_key())


def seal_in_memory(ctx: AppContext, data: bytearray, name: str) -> None:
    """seal_output for a finished patched file held in memory (sealed in place)."""
    from poisoner.provenance import seal_bytes

    seal_bytes(data, ctx.seal_key(), name)


def link_or_copy(src: Path, dst: Path) -> None:
    """A hard link between two of ppd's private files (the vault and its work folders), else a copy."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


NAME_MAX = 255  # bytes in one file name (Linux filesystems)


def work_copy_name(prefix: str, name: str) -> str:
    """prefix + name for a private work copy, shortened (the suffix kept: poisoners pick the
    format by it) when that would pass NAME_MAX: a 255-byte name is still patched."""
    full = prefix + name
    if len(os.fsencode(full)) <= NAME_MAX:
        return full
    import hashlib

    suffix = Path(name).suffix if len(os.fsencode(Path(name).suffix)) <= 32 else ""
    return f"{prefix}{hashlib.sha256(os.fsencode(name)).hexdigest()[:32]}{suffix}"


def work_folder(ctx: AppContext, held: contextlib.ExitStack | None = None) -> Path:
    """A private scratch folder inside the vault (same filesystem: the vault links from it),
    flock()ed while in use (held owns the lock). Opening the vault removes those a killed process
    left (daemon.store.vault.clear_stale_work_folders)."""
    folder = Path(tempfile.mkdtemp(prefix=WORK_PREFIX, dir=ctx.vault.vault_dir))
    if held is not None:
        fd = os.open(folder / WORK_LOCK, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        fcntl.flock(fd, fcntl.LOCK_EX)
        held.callback(os.close, fd)
    return folder


@contextlib.contextmanager
def named_vault_copy(ctx: AppContext, sha256: str, name: str) -> Iterator[Path]:
    """The vault blob under its original file name (poisoners pick the format by suffix), as a
    hard link in a private work folder inside the vault (locked while used: a killed process's is
    removed by the next that opens the vault)."""
    with contextlib.ExitStack() as held:
        folder = work_folder(ctx, held)
        link = folder / name
        try:
            try:
                os.link(ctx.vault.path_for(sha256), link)
            except OSError:
                shutil.copyfile(ctx.vault.path_for(sha256), link)
            yield link
        finally:
            shutil.rmtree(folder, ignore_errors=True)
