"""(original, protected) pairs laid out as two folders with the same names, for verify_folders.

Images are hard-linked (or copied); photos in a format COLMAP does not read (HEIC, AVIF) are staged
as lossless PNGs of their decoded pixels, original and patched alike: no COLMAP reads them, so an
attacker converts them first, and the PNG is what any converter gives. Videos are sampled into
frames (poisoner.video). A photo that does not decode is left out, and named (Staged.left_out): no
verdict covers it. `stage_photos` lays out one side the same way (automatic mode's sample and each
candidate's poisoned copies of it).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Staged:
    """What stage_pairs laid out: the matching mode to use ("sequential" when frames came from videos)
    and the patched photos it could not give COLMAP, by name, each with why (one line)."""

    matching: str
    left_out: dict[str, str] = field(default_factory=dict)
    # each video's frames measured, in words (sampled_line): the verdict rests on them, not every frame
    video_frames: tuple[str, ...] = ()


def _flat_name(path: Path, index: int, used: set[str]) -> str:
    name = path.name
    if name in used:
        name = f"{index:05d}_{name}"
    used.add(name)
    return name


def link_or_copy(src: Path, dst: Path) -> None:
    """A hard link (the verifier only reads what it stages), else a copy."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def stage_pairs(pairs: Sequence[tuple[Path, Path]], clean_dir: Path, poisoned_dir: Path) -> Staged:
    """Lay out (original, protected) pairs as two folders with the same names.

    Images COLMAP reads are hard-linked (or copied); the others are converted (stage_photo).
    Videos are sampled into frames with poisoner.video."""
    clean_dir.mkdir(parents=True, exist_ok=True)
    poisoned_dir.mkdir(parents=True, exist_ok=True)
    used: set[str] = set()
    videos: list[str] = []
    left_out: dict[str, str] = {}
    for i, (original, protected) in enumerate(pairs):
        protected, original = Path(protected), Path(original)
        if _is_video(protected):
            videos.append(_stage_frames(original, protected, clean_dir, poisoned_dir, i))
            continue
        staged = staged_as(protected)
        if staged is None:
            left_out[protected.name] = f"{protected.name}: not a photo ppd patches"
            continue
        name = _flat_name(Path(staged[0]), i, used)
        if why := _stage_pair(original, protected, clean_dir / name, poisoned_dir / name, staged[1]):
            left_out[protected.name] = why
    return Staged("sequential" if videos else "auto", dict(sorted(left_out.items())), tuple(videos))


def stage_photos(photos: Sequence[tuple[Path, str]], folder: Path) -> list[str]:
    """Each (file, its name in the set) laid out in folder for COLMAP as stage_pairs lays out a side,
    in order; returns the names staged under. The same names in the same order are staged under the
    same names: a clean sample and each candidate's poisoned copies of it pair up. ImageFormatError
    (one line) for a photo that does not decode or is not one ppd patches."""
    from poisoner.errors import ImageFormatError

    folder.mkdir(parents=True, exist_ok=True)
    used: set[str] = set()
    names = []
    for i, (src, name) in enumerate(photos):
        staged = staged_as(Path(src), name)
        if staged is None:
            raise ImageFormatError(f"{name}: not a photo ppd patches")
        names.append(_flat_name(Path(staged[0]), i, used))
        stage_photo(Path(src), folder / names[-1], staged[1])
    return names


def _stage_frames(original: Path, protected: Path, clean_dir: Path, poisoned_dir: Path, index: int) -> str:
    """A video pair's sampled frames, under the same names in both folders; which were taken, in
    words (sampled_line)."""
    from poisoner.video import sample_frames

    tmp_c, tmp_p = clean_dir / f".v{index}", poisoned_dir / f".v{index}"
    frames_c = sample_frames(original, tmp_c)
    frames_p = sample_frames(protected, tmp_p)
    taken = [int(f.stem.rsplit("_", 1)[-1]) for f in frames_p]  # frame_000012.png: the frame's index
    for k, (fc, fp) in enumerate(zip(frames_c, frames_p, strict=False)):
        name = f"{protected.stem}_frame{k:05d}{fc.suffix}"
        os.replace(fc, clean_dir / name)
        os.replace(fp, poisoned_dir / name)
    shutil.rmtree(tmp_c, ignore_errors=True)
    shutil.rmtree(tmp_p, ignore_errors=True)
    return sampled_line(protected.name, taken)


def sampled_line(name: str, taken: Sequence[int]) -> str:
    """What a video's verdict rests on: the frames measured, not every frame. A review found a clip
    "protected" on 8 frames 6 apart whose first 12 consecutive frames were only "weak" (42% of the
    cameras): an attacker picks the frames, so the line says which were measured."""
    if len(taken) < 2:
        return f"{name}: {len(taken)} frame measured (the whole clip)"
    step = taken[1] - taken[0]
    every = "every frame" if step == 1 else f"every {_ordinal(step)} frame"
    return (f"{name}: {len(taken)} frames measured, {every} from frame {taken[0]} to {taken[-1]}; "
            "an attacker may take others (closer together or more of them): not measured")  # fmt: skip


def _ordinal(n: int) -> str:
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def _stage_pair(original: Path, protected: Path, clean: Path, poisoned: Path, converted: bool) -> str | None:
    """Both sides of a pair staged (stage_photo); None when both are, else why not (one line), and
    neither is."""
    from poisoner.errors import ImageFormatError

    try:
        stage_photo(original, clean, converted)
        stage_photo(protected, poisoned, converted)
    except ImageFormatError as exc:  # e.g. a patched file replaced since by one that does not decode
        clean.unlink(missing_ok=True)
        return str(exc)
    return None


def stage_photo(src: Path, dst: Path, converted: bool) -> None:
    """One photo at dst for COLMAP: hard-linked (or copied), or (converted: HEIC, AVIF, which COLMAP
    does not read) written as a PNG of its decoded pixels, lossless: what the attacker's converter
    decodes, COLMAP reads. ImageFormatError (one line) when it does not decode."""
    if not converted:
        link_or_copy(src, dst)
        return
    from poisoner.image.read import PNG_MODES, open_decoded

    with open_decoded(src, src.read_bytes()) as im:
        (im if im.mode in PNG_MODES else im.convert("RGB")).save(dst, "PNG", compress_level=1)


# What COLMAP reads by its content under any name, with the suffix its image list takes it by
_SFM_SUFFIX = {"jpeg": ".jpg", "png": ".png", "webp": ".webp"}


def staged_as(path: Path, name: str | None = None) -> tuple[str, bool] | None:
    """The name a photo is staged under for COLMAP, and whether it is converted (stage_photo): its
    own name where its suffix is one COLMAP's image list takes; a JPEG, PNG or WebP under another name
    (.jfif, none: ppd patches them, an attacker's COLMAP reads them by content) with its format's suffix
    added; any other photo ppd patches (HEIC, AVIF) with .png added, converted; None for the rest.
    name: the photo's name in its set where path is not named so (a vault original); else path's."""
    from poisoner.media import IMAGE_SUFFIXES, SFM_SUFFIXES, image_format, read_head

    name = name or path.name
    suffix = Path(name).suffix.lower()
    if suffix in SFM_SUFFIXES:
        return name, False
    found = image_format(read_head(path)) or ""
    if found in _SFM_SUFFIX:
        return name + _SFM_SUFFIX[found], False
    if found == "heif" or suffix in IMAGE_SUFFIXES:
        return name + ".png", True
    return None


def _is_video(path: Path) -> bool:
    from poisoner.media import is_video

    return is_video(path)
