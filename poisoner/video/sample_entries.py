"""The sample entry (fourcc) of each track of an MP4/MOV, read from its `moov` box.

PyAV 18 gives a data stream no codec tag, so a GoPro's GPS telemetry (`gpmd`), a CAMM track or
Apple's timed metadata (`mebx`) could not be told from any other data track, and ppd copied them
into the published video while it removed the container's location tags (found reading the video
code after a black-box review). The file says it in `moov/trak/mdia/minf/stbl/stsd`; the track's
`tkhd` gives its ID, which is FFmpeg's stream id for MP4/MOV.
"""

from __future__ import annotations

import functools
import os
import struct
from pathlib import Path
from typing import BinaryIO

_MAX_MOOV = 64 << 20  # a moov larger than this is not read (no real camera file has one)


def sample_entries(path: Path) -> dict[int, str]:
    """{track ID: its first sample entry's fourcc, lower case} of an MP4/MOV file; {} for another
    format or a file that does not parse (nothing is guessed)."""
    try:
        st = os.stat(path)
    except OSError:
        return {}
    return dict(_cached(str(path), st.st_size, st.st_mtime_ns))


@functools.lru_cache(maxsize=32)
def _cached(path: str, size: int, mtime_ns: int) -> tuple[tuple[int, str], ...]:
    try:
        with open(path, "rb") as fh:
            moov = _top_level_box(fh, size, b"moov")
    except OSError:
        return ()
    if moov is None:
        return ()
    found: dict[int, str] = {}
    for trak in _boxes(moov, b"trak"):
        track_id, fourcc = _track(trak)
        if track_id is not None and fourcc:
            found[track_id] = fourcc
    return tuple(sorted(found.items()))


def _top_level_box(fh: BinaryIO, size: int, wanted: bytes) -> bytes | None:
    """The payload of the first top-level box of that type, read by seeking past the others."""
    at = 0
    while at + 8 <= size:
        fh.seek(at)
        head = fh.read(16)
        if len(head) < 8:
            return None
        length, kind = struct.unpack(">I4s", head[:8])
        header = 8
        if length == 1:  # a 64-bit size follows
            if len(head) < 16:
                return None
            length, header = struct.unpack(">Q", head[8:16])[0], 16
        elif length == 0:  # to the end of the file
            length = size - at
        if length < header:
            return None
        if kind == wanted:
            if length > _MAX_MOOV:
                return None
            fh.seek(at + header)
            return bytes(fh.read(length - header))
        at += length
    return None


def _boxes(data: bytes, wanted: bytes) -> list[bytes]:
    """The payloads of the boxes of that type directly in data."""
    found, at = [], 0
    while at + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[at : at + 8])
        header = 8
        if length == 1 and at + 16 <= len(data):
            length, header = struct.unpack(">Q", data[at + 8 : at + 16])[0], 16
        elif length == 0:
            length = len(data) - at
        if length < header or at + length > len(data):
            break
        if kind == wanted:
            found.append(data[at + header : at + length])
        at += length
    return found


def _track(trak: bytes) -> tuple[int | None, str]:
    """(track ID from tkhd, the first sample entry's fourcc from mdia/minf/stbl/stsd)."""
    track_id = None
    for tkhd in _boxes(trak, b"tkhd")[:1]:
        if len(tkhd) >= 4:
            version = tkhd[0]
            at = 4 + (16 if version == 1 else 8)  # creation and modification times
            if len(tkhd) >= at + 4:
                track_id = struct.unpack(">I", tkhd[at : at + 4])[0]
    level = [trak]
    for name in (b"mdia", b"minf", b"stbl", b"stsd"):
        level = [box for parent in level for box in _boxes(parent, name)]
    for stsd in level[:1]:
        # version and flags (4), entry count (4), then the first entry: size (4), fourcc (4)
        if len(stsd) >= 16:
            fourcc = stsd[12:16].decode("latin-1").strip("\x00 ").lower()
            return track_id, fourcc
    return track_id, ""
