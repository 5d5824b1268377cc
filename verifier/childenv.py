"""The environment of ppd's own Python children (`python -m verifier.child`, `python -m
daemon.protect.child`, ...): the same interpreter, importing the same copy of ppd as the parent.

Installed (a wheel in site-packages), the child finds ppd on its own sys.path and nothing is
added. Run from a source tree that is on the parent's sys.path only through the working folder or
pytest's rootdir, the child would not find it: that folder goes first on PYTHONPATH. Nothing here
reads a path of the repository: the folder is wherever this very module was imported from.
"""

from __future__ import annotations

import os
import site
from collections.abc import Mapping
from pathlib import Path


def import_root() -> Path:
    """The folder holding the `verifier` package this process runs."""
    return Path(__file__).resolve().parents[1]


def _site_dirs() -> set[Path]:
    dirs = [*site.getsitepackages(), site.getusersitepackages()]
    return {Path(d).resolve() for d in dirs if d}


def child_env(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """`base` (default: this process's environment) with ppd importable in a child."""
    env = dict(os.environ if base is None else base)
    root = import_root()
    if root in _site_dirs():  # installed: the child's own sys.path has it
        return env
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(root), env.get("PYTHONPATH")]))
    return env
