"""PatchPoison's poisoner: patch specs, patterns, blending and faithful file I/O.

The names below load on first use (PEP 562): `import poisoner.spec` alone must not pull numpy in,
so the CLI and daemon start without it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from poisoner.blend import apply_patch, poison_array
    from poisoner.spec import PatchPlacement, PatchSpec, SpecError

__all__ = ["PatchPlacement", "PatchSpec", "SpecError", "apply_patch", "poison_array"]

_HOME = {
    "PatchPlacement": "poisoner.spec",
    "PatchSpec": "poisoner.spec",
    "SpecError": "poisoner.spec",
    "apply_patch": "poisoner.blend",
    "poison_array": "poisoner.blend",
}


def __getattr__(name: str) -> Any:
    if name in _HOME:
        value = getattr(importlib.import_module(_HOME[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'poisoner' has no attribute {name!r}")
