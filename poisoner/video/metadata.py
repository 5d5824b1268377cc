"""What a video carries besides its pictures: container and stream tags (copied, location left
out unless kept), GPS telemetry streams, HDR static metadata for x265, the provenance marker,
and the list of what was preserved."""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import av
import numpy as np

from poisoner import location, provenance
from poisoner.provenance import Marker
from poisoner.video.model import EncoderChoice, SourceInfo

# FFmpeg's own tags: rewritten by the muxer, never copied.
_FFMPEG_TAGS = {
    "encoder",
    "duration",
    "rotate",
    "_statistics_tags",
    "major_brand",
    "minor_version",
    "compatible_brands",
}
MARKER_TAG_MUXERS = ("matroska", "webm")  # the marker is a tag (provenance.MKV_TAG)
MARKER_BOX_MUXERS = ("mp4", "mov")  # the marker is a uuid box appended to the file


class Tagged(Protocol):
    """What carries tags in PyAV: an output container or one of its streams."""

    @property
    def metadata(self) -> dict[str, str]: ...


def copy_metadata(
    src: dict[str, str], dst_obj: Tagged, keep_location: bool = True, removed: list[str] | None = None
) -> None:
    """Copy tags, except FFmpeg's own and (unless keep_location) those naming a place."""
    for key, value in src.items():
        if (
            key.lower() in _FFMPEG_TAGS
            or key.upper().startswith("_STATISTICS")
            or key.upper() in {"DURATION", "ENCODER"}
        ):
            continue
        if not keep_location and location.is_location_tag(key):
            if removed is not None:
                removed.append(f"tag {key}")
            continue
        if key.upper() in provenance.MKV_TAGS:
            continue  # an older seal or marker: the new one (if any) is written by add_marker_tag
        try:
            dst_obj.metadata[key] = value
        except (ValueError, TypeError):
            continue


def is_mdta_key(key: str) -> bool:
    """A QuickTime `mdta` key: reverse-DNS ("com.apple.quicktime.make", "com.android.version");
    FFmpeg's own names for the classic udta/ilst tags have no dot ("title", "creation_time")."""
    return "." in key


def muxer_options(muxer: str, mdta_tags: bool) -> dict[str, str] | None:
    """The output container's options: Matroska bit-exact (the same inputs give the same bytes: the
    daemon re-poisons to check crash recovery); MP4/MOV with reverse-DNS tags written as `mdta` keys,
    which FFmpeg's mov muxer leaves out unless told (an iPhone's make, model and capture date were
    dropped: black-box review 9)."""
    if muxer in ("matroska", "webm"):
        return {"fflags": "+bitexact"}
    if muxer in MARKER_BOX_MUXERS and mdta_tags:
        return {"movflags": "use_metadata_tags"}
    return None


def tags_left_out(src: dict[str, str], dst: dict[str, str], removed: list[str]) -> list[str]:
    """The source's container tags that dst lacks, but FFmpeg's own, a seal or marker, and those in
    removed (location, said apart)."""
    said = {item.removeprefix("tag ") for item in removed}
    return [
        key
        for key in src
        if key not in dst and key not in said and key.lower() not in _FFMPEG_TAGS
        and key.upper() not in provenance.MKV_TAGS and not key.upper().startswith("_STATISTICS")
    ]  # fmt: skip


def codec_tag(stream: av.stream.Stream) -> str:
    """The stream's codec tag, lower case; a data stream's from the file's sample entries (PyAV gives
    a data stream none: every GPS telemetry track was copied into the published video)."""
    try:
        tag = str(getattr(stream, "codec_tag", "") or "").strip("\x00 ").lower()
    except (AttributeError, ValueError):
        tag = ""
    if not tag and stream.type == "data":
        from poisoner.video.sample_entries import sample_entries

        tag = sample_entries(Path(stream.container.name)).get(stream.id, "")
    return tag


def is_location_stream(stream: av.stream.Stream) -> bool:
    """A GPS telemetry data stream (GoPro gpmd, CAMM, Apple mebx)."""
    return stream.type == "data" and codec_tag(stream) in location.LOCATION_DATA_CODEC_TAGS


def is_timecode_stream(stream: av.stream.Stream) -> bool:
    """A QuickTime/MP4 timecode track (`tmcd`: a data stream FFmpeg's demuxer tags with its start)."""
    return stream.type == "data" and "timecode" in stream.metadata


def add_marker_tag(out: av.container.OutputContainer, muxer: str, marker: Marker | None) -> None:
    """Matroska/WebM: the marker as a container tag (written with the header)."""
    if marker is not None and muxer in MARKER_TAG_MUXERS:
        out.metadata[provenance.MKV_TAG] = marker.text


def append_marker_box(dst: Path, muxer: str, marker: Marker | None) -> None:
    """MP4/MOV: the marker as a uuid box after the last box of the finished file."""
    if marker is not None and muxer in MARKER_BOX_MUXERS:
        # Appended after the last box: nothing in the file points past it, so no offset moves.
        with open(dst, "ab") as f:
            f.write(provenance.mp4_box(marker))


def x265_hdr_params(hdr: dict[str, bytes]) -> str:
    """x265-params for the source's mastering display and light level (HDR10 static metadata)."""
    parts: list[str] = []
    md = hdr.get("MASTERING_DISPLAY_METADATA")
    if md and len(md) >= 88:
        v = np.frombuffer(md[:88], "<i4")
        rat = [v[i] / v[i + 1] if v[i + 1] else 0.0 for i in range(0, 20, 2)]
        (rx, ry, gx, gy, bx, by, wx, wy, lmin, lmax) = rat
        has_primaries, has_luminance = int(v[20]), int(v[21])
        if has_primaries and has_luminance:
            c = lambda q: int(round(q * 50000))  # noqa: E731 - x265 chromaticity unit 0.00002
            parts.append(
                f"master-display=G({c(gx)},{c(gy)})B({c(bx)},{c(by)})R({c(rx)},{c(ry)})"
                f"WP({c(wx)},{c(wy)})L({int(round(lmax * 10000))},{int(round(lmin * 10000))})"
            )
    cll = hdr.get("CONTENT_LIGHT_LEVEL")
    if cll and len(cll) >= 8:
        max_cll, max_fall = np.frombuffer(cll[:8], "<u4")
        parts.append(f"max-cll={int(max_cll)},{int(max_fall)}")
    return ":".join(parts)


def preserved_list(info: SourceInfo, choice: EncoderChoice) -> list[str]:
    kept = [
        "frame timestamps (rate, time base, duration)",
        "frame count",
        f"pixel format {info.pix_fmt}",
        "colour tags (range, matrix, primaries, transfer)",
        "audio/subtitle/data packets (copied)",
        "container and stream metadata",
    ]
    if choice.same_codec:
        kept.append(f"codec {info.codec}")
    if info.display_matrix is not None:
        kept.append(f"display matrix (rotation {info.rotation} deg)")
    if info.hdr_side_data and choice.encoder == "libx265":
        kept.append("HDR10 mastering display / content light level")
    return kept
