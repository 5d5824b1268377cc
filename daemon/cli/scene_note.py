"""One line per dataset saying what kind of scene it is for ppd's mark (poisoner/scene.py): what
`ppd poison` and `ppd auto` print so that a creator knows up front whether sets like this were
protected in our tests. It never says "protected": only a verification can.

Cheap (a few thumbnails per dataset, well under a second each) and imported lazily by the
commands, so `ppd poison --help` never loads numpy or PIL.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

PREFIX = "hint: "


def scene_line(dataset: str, images: Sequence[Path]) -> str | None:
    """The hint's sentence for a dataset's images; None when it cannot tell (no image read)."""
    from poisoner.scene import scene_hint

    hint = scene_hint(dataset, images)
    return None if hint is None else PREFIX + hint.sentence


def print_scene_notes(console: Any, datasets: Mapping[str, Sequence[Path]]) -> None:
    """One line per dataset (sorted by name) for the images among its files; nothing for a dataset
    without images (videos only) or whose images cannot be read."""
    from poisoner.media import is_image

    for name in sorted(datasets):
        images = [p for p in datasets[name] if is_image(p)]
        line = scene_line(name, images) if images else None
        if line:  # word-wrapped on a terminal (a terminal's own wrap breaks mid-word), one line in a pipe
            console.print(line, markup=False, highlight=False, soft_wrap=not console.is_terminal)
