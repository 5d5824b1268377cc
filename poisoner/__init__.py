"""PatchPoison's poisoner: patch specs, patterns, blending and faithful file I/O."""

from poisoner.blend import apply_patch, poison_array
from poisoner.spec import PatchPlacement, PatchSpec, SpecError

__all__ = ["PatchPlacement", "PatchSpec", "SpecError", "apply_patch", "poison_array"]
