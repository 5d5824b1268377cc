"""One line per dataset saying what kind of scene it is for ppd's mark (poisoner/scene.py): what
`ppd poison` and `ppd auto` print so that a creator knows up front whether sets like this were
protected in our tests. It never says "protected": only a verification can.

Cheap (a few thumbnails per dataset, well under a second each) and imported lazily by the
commands, so `ppd poison --help` never loads numpy or PIL.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

PREFIX = "hint: "


def scene_line(dataset: str, images: Sequence[Path]) -> str | None:
    """The hint's sentence for a dataset's images; None when it cannot tell (no image read)."""
    from poisoner.scene import scene_hint

    hint = scene_hint(dataset, images)
    return None if hint is None else PREFIX + hint.sentence


def print_scene_notes(
    console: Any, datasets: Mapping[str, Sequence[Path]], original: Callable[[Path], Path] = lambda p: p
) -> None:
    """One line per dataset (sorted by name) for the images among its files; nothing for a dataset
    without images (videos only) or whose images cannot be read. original(path): the file to read
    for a sampled path (`ppd poison`: its vault original, so the hint judges the scene, not ppd's
    own mark written into its plainest place a moment ago); the sample is drawn by the names."""
    from poisoner.media import is_image
    from poisoner.scene import SAMPLE, evenly_spaced

    for name in sorted(datasets):
        images = [original(p) for p in evenly_spaced([p for p in datasets[name] if is_image(p)], SAMPLE)]
        line = scene_line(name, images) if images else None
        if line:  # word-wrapped on a terminal (a terminal's own wrap breaks mid-word), one line in a pipe
            console.print(line, markup=False, highlight=False, soft_wrap=not console.is_terminal)
