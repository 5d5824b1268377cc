"""A video's cover pictures: its `attached_pic` streams (an MP4's `covr` pictures, a Matroska file's
image attachments, as FFmpeg reads them) and any other Matroska attachment whose bytes are a picture
(a WebP, a BMP, a JPEG under "image/jpg": demux.is_cover). Copied as they were, a cover (often a frame
of the video, which phones and editing apps set) published an unmarked picture beside the marked
frames: the leak an EXIF thumbnail was for a photo (poisoner.image.previews).

Each cover is marked as a photo of its own size is, by the image path itself
(poisoner.formats.poison_bytes: the spec placed on it, the same blend, written in its own format, a
JPEG by the DCT splice with its own tables), and written where it was: MP4 as the cover stream's
picture (`covr`), Matroska as an attachment of the same name and type. Where that cannot be done
(a picture ppd does not write or cannot decode, one too small for the mark, a container FFmpeg
writes no cover into: MOV, WebM) the cover is left out. The report says it once per file
(CoverPlan.notes; `ppd poison`'s summary counts the notes: daemon.cli.poison_cmd.CHANGE_NOTES).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import av

from poisoner.errors import PpdError
from poisoner.media import SNIFF_BYTES, image_format
from poisoner.scratch import owned_temp_dir
from poisoner.spec import PatchSpec
from poisoner.video.demux import is_cover, iter_packets, open_input
from poisoner.video.errors import one_line

MARKED = "cover picture marked"  # the notes' words (ppd poison's summary finds them)
REMOVED = "cover picture removed"
SCRATCH_PREFIX = "ppd-cover-"  # poisoner.scratch.PREFIXES: a killed run's copy is swept
_SUFFIX = {"jpeg": ".jpg", "png": ".png", "webp": ".webp", "heif": ".heic"}  # the image path picks by suffix
# Where FFmpeg writes a cover, and how: MP4 takes the picture as its attached_pic stream's packet (its
# `covr`); Matroska takes it as an attachment (an attached_pic *stream* it writes as a second video
# track). The mov and webm muxers write none.
COVER_WRITERS = {"mp4": "stream", "matroska": "attachment"}
_NO_COVER = {"mov": "MOV", "webm": "WebM"}


@dataclass
class CoverPlan:
    """What the output carries for each of the source's cover pictures, by source stream index."""

    marked: dict[int, bytes] = field(default_factory=dict)  # the marked picture's file bytes
    shown: list[str] = field(default_factory=list)  # "32x24 JPEG", one per marked cover
    removed: list[str] = field(default_factory=list)  # why, one per cover left out
    location_removed: list[str] = field(default_factory=list)  # from a cover's own metadata

    def notes(self) -> list[str]:
        """At most one note per kind, for the whole file."""
        notes = []
        if self.shown:
            notes.append(f"{MARKED} ({_counted(self.shown, ', ')})")
        if self.removed:
            notes.append(f"{REMOVED} ({_counted(self.removed, '; ')})")
        return notes


def _counted(items: list[str], sep: str) -> str:
    return items[0] if len(items) == 1 else f"{len(items)} of them: " + sep.join(items)


def plan_covers(src: Path, spec: PatchSpec, muxer: str, keep_location: bool) -> CoverPlan:
    """Each cover of src marked with spec (what the output writes in its place), or why it is left out."""
    plan = CoverPlan()
    with open_input(src) as inp:
        covers = [s.index for s in inp.streams if is_cover(s)]
        if not covers:
            return plan
        if muxer not in COVER_WRITERS:
            why = f"FFmpeg writes no cover picture into {_NO_COVER.get(muxer, muxer)}"
            plan.removed += [why] * len(covers)
            return plan
        pictures = _pictures(inp, set(covers), src.name)
    with owned_temp_dir(SCRATCH_PREFIX) as folder:
        for index in covers:
            picture = pictures.get(index)
            done = _marked(picture, spec, keep_location, folder / f"cover-{index}") if picture else None
            if isinstance(done, tuple):
                plan.marked[index], shown, removed = done
                plan.shown.append(shown)
                plan.location_removed += [f"cover picture {r}" for r in removed]
            else:
                plan.removed.append(done or "no picture in its stream")
    return plan


def _pictures(inp: av.container.InputContainer, indexes: set[int], name: str) -> dict[int, bytes]:
    """Each cover stream's picture: an attachment's are its bytes; an attached_pic's its one packet,
    which FFmpeg gives first, so this stops early."""
    found = {i: s.data for i in indexes if isinstance(s := inp.streams[i], av.stream.AttachmentStream)}
    if len(found) == len(indexes):
        return found  # only attachments: no packet to read
    for packet in iter_packets(inp, name):
        idx = packet.stream.index
        if idx in indexes and packet.size and idx not in found:
            found[idx] = bytes(packet)
            if len(found) == len(indexes):
                break
    return found


def _marked(
    picture: bytes, spec: PatchSpec, keep_location: bool, stem: Path
) -> tuple[bytes, str, list[str]] | str:
    """(the marked picture, "WxH FORMAT", location removed from it), or why it cannot be marked."""
    from poisoner.formats import poison_bytes  # the image writers: loaded when a video has a cover
    from poisoner.image.read import open_decoded

    fmt = image_format(picture[:SNIFF_BYTES])
    if fmt is None:
        return "not a JPEG, PNG, WebP or HEIF picture, which ppd writes"
    path = stem.with_suffix(_SUFFIX[fmt])  # a fixed name: a moving spec resolves the same on every run
    try:
        with open_decoded(path, picture, load=False) as im:  # the header, read as a photo's is
            size = im.size
        if (small := spec.too_small(*size)) is not None:
            return small
        path.write_bytes(picture)
        out, report = poison_bytes(path, spec, data=picture, keep_location=keep_location)
    except PpdError as exc:  # ImageFormatError, MarkNotWritten: said as the image path says it
        return one_line(exc).removeprefix(f"{path.name}: ")
    return out, f"{report.width}x{report.height} {report.format}", report.location_removed


def add_cover(
    out: av.container.OutputContainer, source: av.stream.Stream, muxer: str, picture: bytes
) -> av.stream.Stream:
    """The output stream of a marked cover: an attachment holding the picture, written with the header
    (Matroska), else a stream like the source's whose one packet will be the picture (cover_packet)."""
    if COVER_WRITERS[muxer] == "attachment":
        tags = {k.lower(): v for k, v in source.metadata.items()}
        name = tags.get("filename") or f"cover-{source.index}"
        mime = tags.get("mimetype") or f"image/{image_format(picture[:SNIFF_BYTES])}"
        return out.add_attachment(name, mime, picture)
    return out.add_stream_from_template(source)


def cover_packet(source: av.Packet, stream: av.stream.Stream, picture: bytes) -> av.Packet:
    """The packet that carries the marked picture in place of source's."""
    packet = av.Packet(picture)
    packet.stream = stream
    packet.time_base = source.time_base
    packet.pts, packet.dts = source.pts, source.dts
    packet.is_keyframe = True
    return packet
