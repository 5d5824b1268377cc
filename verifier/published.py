"""The `published` profile's input: what a platform does to a picture on upload (downscale, JPEG).

The attacker who downloads published pictures sees these, not the originals; the verifier runs the
same round trip on both sides so the comparison stays like for like.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from poisoner.atomic import atomic_output


def round_trip(src_dir: Path, dst_dir: Path, names: Sequence[str], long_edge: int, quality: int) -> Path:
    """What a platform does on upload: downscale the long edge to long_edge, re-encode JPEG q=quality.

    Output names keep the source name (with .jpg appended when needed) so poses compare by stem."""
    from PIL import Image

    dst_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        out = dst_dir / published_name(name)
        if out.exists():
            continue
        with Image.open(src_dir / name) as im:
            im.load()
            rgb = to_rgb(im)
        scale = long_edge / max(rgb.size)
        if scale < 1:
            rgb = rgb.resize((round(rgb.width * scale), round(rgb.height * scale)), Image.Resampling.LANCZOS)
        with atomic_output(out) as tmp:
            rgb.save(tmp, "JPEG", quality=quality)
    return dst_dir


def published_name(name: str) -> str:
    return name if Path(name).suffix.lower() in (".jpg", ".jpeg") else name + ".jpg"


def to_rgb(im: Any) -> Any:
    from PIL import Image

    if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
        rgba = im.convert("RGBA")
        white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        return Image.alpha_composite(white, rgba).convert("RGB")
    return im.convert("RGB")


def unpublish_names(poses: dict[str, Any], names: Sequence[str]) -> dict[str, Any]:
    back = {published_name(n): n for n in names}
    return {back.get(k, k): v for k, v in poses.items()}
