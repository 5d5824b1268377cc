"""ppd's version: one source, the installed package's metadata (pyproject.toml's `version`,
written into the wheel or the editable install). No copy of the number lives in the code."""

from __future__ import annotations

import functools

DIST_NAME = "patchpoison"  # the distribution (pyproject's [project] name); the command is `ppd`


@functools.cache  # the running code's version: read once a process (it was 2-3 ms a file, twice)
def ppd_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(DIST_NAME)
    except PackageNotFoundError:  # a bare source tree on PYTHONPATH, never installed
        return "unknown (not installed: pip install the package)"
