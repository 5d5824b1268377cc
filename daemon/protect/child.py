"""`python -m daemon.protect.child ARGS_JSON`: one file patched in a child process
(daemon.protect.poisoning.poison_isolated), so that a file that kills its process kills only the child.

ARGS_JSON: kind, src, dst, spec (PatchSpec.to_dict), marker (Marker fields), keep_location,
limits (keyword arguments of poison_to), subject_masks (a folder or null), report (where the
report is written, pickled, for the parent).
"""

from __future__ import annotations

import json
import pickle
import sys
from pathlib import Path

from daemon.protect.poisoning import poison_to


def main(argv: list[str]) -> None:
    from verifier.supervise import adopt_child_setup

    adopt_child_setup()  # dies with the process that patches through it
    from poisoner.provenance import Marker
    from poisoner.spec import PatchSpec

    a = json.loads(argv[0])
    masks = Path(a["subject_masks"]) if a["subject_masks"] is not None else None
    report = poison_to(
        a["kind"], Path(a["src"]), Path(a["dst"]), PatchSpec.from_dict(a["spec"]), subject_masks=masks,
        marker=Marker(**a["marker"]), keep_location=a["keep_location"], **a["limits"],
    )  # fmt: skip
    Path(a["report"]).write_bytes(pickle.dumps(report))


if __name__ == "__main__":
    main(sys.argv[1:])
