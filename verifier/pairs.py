"""(original, protected) pairs laid out as two folders with the same names, for verify_folders.

Images are hard-linked (or copied); videos are sampled into frames (poisoner.video); files COLMAP
cannot read are left out, and named (not_staged): no verdict covers them.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from pathlib import Path


def _flat_name(path: Path, index: int, used: set[str]) -> str:
    name = path.name
    if name in used:
        name = f"{index:05d}_{name}"
    used.add(name)
    return name


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def stage_pairs(pairs: Sequence[tuple[Path, Path]], clean_dir: Path, poisoned_dir: Path) -> str:
    """Lay out (original, protected) pairs as two folders with the same names.

    Images are hard-linked (or copied). Videos are sampled into frames with poisoner.video.
    Returns the matching mode to use ("sequential" when frames came from videos)."""
    clean_dir.mkdir(parents=True, exist_ok=True)
    poisoned_dir.mkdir(parents=True, exist_ok=True)
    used: set[str] = set()
    any_video = False
    for i, (original, protected) in enumerate(pairs):
        protected, original = Path(protected), Path(original)
        if _is_video(protected):
            from poisoner.video import sample_frames

            any_video = True
            tmp_c, tmp_p = clean_dir / f".v{i}", poisoned_dir / f".v{i}"
            frames_c = sample_frames(original, tmp_c)
            frames_p = sample_frames(protected, tmp_p)
            for k, (fc, fp) in enumerate(zip(frames_c, frames_p, strict=False)):
                name = f"{protected.stem}_frame{k:05d}{fc.suffix}"
                os.replace(fc, clean_dir / name)
                os.replace(fp, poisoned_dir / name)
            shutil.rmtree(tmp_c, ignore_errors=True)
            shutil.rmtree(tmp_p, ignore_errors=True)
            continue
        sfm_name = _sfm_name(protected)
        if sfm_name is None:
            continue  # formats COLMAP cannot read (e.g. HEIC) are left out of the SfM check (not_staged)
        name = _flat_name(Path(sfm_name), i, used)
        _link_or_copy(original, clean_dir / name)
        _link_or_copy(protected, poisoned_dir / name)
    return "sequential" if any_video else "auto"


# What COLMAP reads by its content under any name, and the suffix its image list takes it by
# What COLMAP reads by its content under any name, with the suffix its image list takes it by
_SFM_SUFFIX = {"jpeg": ".jpg", "png": ".png", "webp": ".webp"}


def _sfm_name(path: Path) -> str | None:
    """The name path is staged under for COLMAP: its own where its suffix is one COLMAP's image list
    takes; a JPEG, PNG or WebP under another name (.jfif, none: ppd patches them, an attacker's COLMAP
    reads them by content) with its format's suffix added; None for the rest (HEIC)."""
    from poisoner.media import SFM_SUFFIXES, image_format, read_head

    if path.suffix.lower() in SFM_SUFFIXES:
        return path.name
    suffix = _SFM_SUFFIX.get(image_format(read_head(path)) or "")
    return None if suffix is None else path.name + suffix


def not_staged(pairs: Sequence[tuple[Path, Path]]) -> list[str]:
    """The patched photos stage_pairs leaves out (formats COLMAP cannot read: HEIC, AVIF, ...), by
    name: no verdict measures them (the report names them, VerifyOptions.not_staged)."""
    return sorted(Path(p).name for _, p in pairs if not _is_video(Path(p)) and _sfm_name(Path(p)) is None)


def _is_video(path: Path) -> bool:
    from poisoner.media import is_video

    return is_video(path)
