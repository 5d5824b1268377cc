"""Child-process entry for one SfM job: `python -m verifier.child` with the job JSON on stdin.

Lowers its own priority first (nice 10, idle I/O class), runs the job (verifier.sfm.SfmJob), and
writes the result (SfmOk or SfmFailed) as JSON to the job's result_path atomically. pycolmap's own
logging goes to stderr (a log file the parent keeps). Exit codes: 0 result written (outcome ok or
failed), 2 bad request; a negative return code seen by the parent means a signal (a pycolmap
segfault).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import platform
import sys
import traceback
from pathlib import Path

# PIL before pycolmap in any process that has both (pillow 13 + pycolmap 4.2.1 crash otherwise).
import PIL.Image  # noqa: F401

_IOPRIO_SET = {"x86_64": 251, "aarch64": 30}
_IOPRIO_CLASS_IDLE = 3
_IOPRIO_WHO_PROCESS = 1


def lower_priority() -> None:
    """nice +10 and, when `ionice` did not already do it, the idle I/O class via ioprio_set."""
    with contextlib.suppress(OSError):
        os.nice(10)
    number = _IOPRIO_SET.get(platform.machine())
    if number is None:
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.syscall(number, _IOPRIO_WHO_PROCESS, 0, _IOPRIO_CLASS_IDLE << 13)
    except (OSError, AttributeError):
        pass


def logs_to_stderr() -> None:
    """COLMAP's glog writes a log file per process into $TMPDIR (`.vm.<user>.log.INFO.<date>.<pid>`:
    hundreds after a few verifications, never removed: a black-box review); to stderr instead, which
    is this child's log in its run folder (verifier.supervise)."""
    import pycolmap

    pycolmap.logging.logtostderr = True


def main() -> int:
    from verifier.supervise import adopt_child_setup

    adopt_child_setup()
    lower_priority()
    import msgspec

    from poisoner.atomic import atomic_write_bytes
    from verifier.sfm import SfmFailed, SfmJob, SfmResult, execute_job

    try:
        job = msgspec.json.decode(sys.stdin.buffer.read(), type=SfmJob)
    except msgspec.DecodeError as exc:
        print(f"bad SfM job: {exc}", file=sys.stderr)
        return 2
    result: SfmResult
    logs_to_stderr()
    try:
        result = execute_job(job)
    except Exception as exc:  # any error becomes a result the parent can record
        traceback.print_exc()
        result = SfmFailed(error=f"{type(exc).__name__}: {exc}".splitlines()[0])
    if job.result_path:
        atomic_write_bytes(Path(job.result_path), msgspec.json.encode(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
