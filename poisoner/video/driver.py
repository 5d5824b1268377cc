"""poison_video: the video stages in order. Check the source, probe it, place the patch per
frame, encode (again at a lower CRF while the patch's contrast did not survive), check the
output is complete, and report."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import av
import av.error
import numpy as np

from poisoner.provenance import Marker
from poisoner.spec import PatchPlacement, PatchSpec, SpecError
from poisoner.video import model
from poisoner.video.contrast import intended_contrast, measure_video_patch
from poisoner.video.cover import plan_covers
from poisoner.video.demux import main_video_stream, open_input, stream_bit_rate
from poisoner.video.encoder import CRF_STEP_ON_RETRY, choose_encoder, encoder_pix_fmt, quality_text
from poisoner.video.errors import VideoFormatError, one_line
from poisoner.video.metadata import append_marker_box, preserved_list, tags_left_out
from poisoner.video.source import probe, timecode_of
from poisoner.video.transcode import EncodeResult, encode_once

log = logging.getLogger("poisoner.video")


def poison_video(
    src: Path,
    dst: Path,
    spec: PatchSpec,
    progress: model.ProgressCallback | None = None,
    *,
    options: model.VideoOptions | None = None,
    marker: Marker | None = None,
    keep_location: bool = False,
    max_pixels: int | None = None,
) -> model.VideoReport:
    """Write src's video to dst with spec's patch in every selected frame; src is only read.

    Location tags (MP4 ©xyz/'location', Apple ISO6709, Matroska *LOCATION*) and GPS telemetry
    streams (GoPro gpmd, CAMM, Apple mebx) are left out unless keep_location. With a marker, dst
    carries it (poisoner.provenance: a uuid box in MP4/MOV, a PPD_PROVENANCE tag in Matroska).
    A frame size over max_pixels (default poisoner.limits.DEFAULT_MAX_VIDEO_PIXELS) is refused
    before any frame is decoded.

    dst receives the complete file (normally the temporary path of poisoner.atomic.atomic_output);
    on any error dst may hold a partial file that the caller discards. Raises VideoFormatError
    (one line) for input that cannot be poisoned faithfully.
    """
    src, dst = Path(src), Path(dst)
    options = options or model.VideoOptions()
    state_before = _check_source(src)
    info = probe(src, max_pixels=max_pixels)
    # frames too small for squares of texture: refused as a photo is (a review: flat squares, "patched")
    if (why := spec.too_small(info.width, info.height)) is not None:
        raise VideoFormatError(f"{src.name}: {why}")
    try:
        placement_at = frame_placements(spec, info, options, src)
        placement = placement_at(0)
    except SpecError as exc:
        raise VideoFormatError(f"{src.name}: {exc}") from exc
    report = _new_report(info, spec, placement, options)
    covers = plan_covers(src, spec, info.muxer, keep_location)  # marked once, written by every attempt

    def encode(choice: model.EncoderChoice) -> EncodeResult:
        return encode_once(
            src, dst, spec, placement_at, info, choice, options, progress, report, marker, keep_location,
            covers,
        )  # fmt: skip

    def contrast_ok(result: EncodeResult) -> bool:
        return _contrast_ok(report, dst, spec, placement_at, intended_contrast(placement), options, result)

    choice, result = _encode_until_visible(src, info, options, report, encode, contrast_ok)
    if _file_state(src) != state_before:
        raise VideoFormatError(f"{src.name}: changed while being read (still being written?)")
    report.location_removed += covers.location_removed
    _finish_report(report, info, choice, result, stream_bit_rate(dst))
    report.notes += covers.notes()
    _note_timecode(report, info, dst)
    _note_tags_left_out(report, src, dst)
    append_marker_box(dst, info.muxer, marker)
    _note_size(report, state_before[0], dst.stat().st_size)
    return report


def _note_tags_left_out(report: model.VideoReport, src: Path, dst: Path) -> None:
    """Said where a container tag of src did not reach dst (the muxer writes only the keys it knows):
    only the location's removal was said, which read as "every other tag kept" (black-box review 9)."""
    with open_input(src) as source, open_input(dst) as written:
        lost = tags_left_out(dict(source.metadata), dict(written.metadata), report.location_removed)
    if lost:
        muxer = f"FFmpeg's {report.format} muxer does not write them"
        report.notes.append(f"tags left out ({len(lost)}; {muxer}): " + ", ".join(lost))


def _note_timecode(report: model.VideoReport, info: model.SourceInfo, dst: Path) -> None:
    """Said where the source's timecode track is not in dst: the muxer writes it from the video's
    timecode tag (poisoner.video.transcode) and leaves it out where the start does not fit the rate."""
    if not info.timecode:
        return
    with open_input(dst) as written:
        kept = timecode_of(written)
    if not kept:
        report.notes.append(
            f"timecode track (start {info.timecode}) left out: FFmpeg's {info.muxer} muxer did not write it"
        )
    elif kept != info.timecode:
        report.notes.append(f"timecode track's start {info.timecode} written as {kept}")


def _note_size(report: model.VideoReport, source_bytes: int, output_bytes: int) -> None:
    """The files' sizes, said per file (`ppd -v poison`; the summary says a growth once): a re-encoded
    video with the mark can be larger than a creator's upload limit allows (a black-box review)."""
    report.source_bytes, report.output_bytes = source_bytes, output_bytes
    ratio = output_bytes / source_bytes if source_bytes else 1.0
    report.notes.append(
        f"size {model.size_text(source_bytes)} -> {model.size_text(output_bytes)} ({ratio:.2f}x"
        + ("; the mark costs bits)" if ratio >= model.NOTICEABLE_GROWTH else ")")
    )


def frame_placements(
    spec: PatchSpec, info: model.SourceInfo, options: model.VideoOptions, src: Path | None = None
) -> model.PlacementAt:
    """Where frame i's patch goes: one placement for a static spec, a point on the path per frame
    for a moving one (poisoner.video's docstring). Raises SpecError when a placement does not fit."""
    if spec.per_photo and src is not None:
        return _per_photo_placements(spec, info, options, src)
    first = spec.resolve(info.width, info.height, index=0.0)
    if not spec.moves or options.motion_steps_per_second <= 0:
        return lambda _i: first
    per_frame = options.motion_steps_per_second / model.frame_rate(info)
    return lambda i: spec.resolve(info.width, info.height, index=i * per_frame)


def _per_photo_placements(
    spec: PatchSpec, info: model.SourceInfo, options: model.VideoOptions, src: Path
) -> model.PlacementAt:
    """A per-photo mark in a video (issue 25): each keyframe (decoded alone, cheap) judged as a photo
    is (poisoner.placement.place_on_photo on its own detail), the anchor moving between keyframes
    along a straight line at most MAX_ANCHOR_SPEED of the frame per second, so the mark glides to
    the next plain place instead of jumping; the lanes' own slide goes on on top of it."""
    from poisoner.keyframes import MAX_ANCHOR_SPEED, anchor_at, smooth_anchors
    from poisoner.placement import place_on_photo
    from poisoner.subject import frame_detail

    rate = model.frame_rate(info)
    per_frame = options.motion_steps_per_second / rate if spec.moves else 0.0
    keys: list[tuple[float, tuple[int, int]]] = []
    start: float | None = None
    try:
        with av.open(str(src)) as container:
            stream = main_video_stream(container, src.name)  # not a cover picture listed first
            stream.codec_context.skip_frame = "NONKEY"
            for frame in container.decode(stream):
                start = float(frame.time or 0.0) if start is None else start
                i = round((float(frame.time or 0.0) - start) * rate)  # frame number, the first is 0
                rgb = frame.to_ndarray(format="rgb24")
                _, place = place_on_photo(spec, info.width, info.height, None, 1, frame_detail(rgb),
                                          index=i * per_frame, split=False)  # fmt: skip
                keys.append((i / rate, place.anchor))
                if len(keys) >= MAX_KEYFRAMES:
                    break
    except av.error.FFmpegError as exc:
        log.info("keyframes unreadable: the mark keeps its preferred place", extra={"reason": one_line(exc)})
    if not keys:
        return lambda i: spec.resolve(info.width, info.height, index=i * per_frame)
    anchors = smooth_anchors(keys, MAX_ANCHOR_SPEED * min(info.width, info.height))
    # between keyframes the slide goes on: keep room for the mark's box anywhere on its path
    side = max(spec.path_extent(info.width, info.height))
    hi = (max(0, info.width - side), max(0, info.height - side))

    def at(i: int) -> PatchPlacement:
        x, y = anchor_at(anchors, i / rate)
        anchor = (min(max(x, 0), hi[0]), min(max(y, 0), hi[1]))
        return spec.resolve(info.width, info.height, index=i * per_frame, anchor=anchor)

    return at


MAX_KEYFRAMES = 600  # keyframes judged per video (a long video's later ones keep the last place)


def _check_source(src: Path) -> tuple[int, int]:
    """Refuse what is not a non-empty file; its (size, mtime) to notice a change while reading."""
    if not src.is_file():
        raise VideoFormatError(f"{src.name}: not a file")
    if src.stat().st_size == 0:
        raise VideoFormatError(f"{src.name}: empty file (still being written?)")
    return _file_state(src)


def _file_state(path: Path) -> tuple[int, int]:
    st = path.stat()
    return st.st_size, st.st_mtime_ns


def _new_report(
    info: model.SourceInfo, spec: PatchSpec, placement: PatchPlacement, options: model.VideoOptions
) -> model.VideoReport:
    report = model.VideoReport(
        format=info.muxer,
        width=info.width,
        height=info.height,
        placement=placement,
        codec=info.codec,
        pix_fmt=info.pix_fmt,
        source_bit_rate=info.bit_rate,
    )
    if spec.moves and options.motion_steps_per_second > 0:
        report.notes.append(
            f"moving spec: the patch travels its path at {options.motion_steps_per_second:g} "
            "photo-steps per second; `placement` is frame 0's"
        )
    elif spec.moves:
        report.notes.append(
            "moving spec with motion_steps_per_second = 0: the patch stays at its first position in "
            "every frame (COLMAP's stationary-match filter can remove it from extracted frames)"
        )
    return report


def _encode_until_visible(
    src: Path,
    info: model.SourceInfo,
    options: model.VideoOptions,
    report: model.VideoReport,
    encode: Callable[[model.EncoderChoice], EncodeResult],
    contrast_ok: Callable[[EncodeResult], bool],
) -> tuple[model.EncoderChoice, EncodeResult]:
    """Encode, check the output is complete, and encode again CRF_STEP_ON_RETRY lower while the
    patch contrast stays below options.min_patch_contrast (at most options.max_retries more)."""
    attempts = 0
    shift = 0
    while True:
        attempts += 1
        choice = choose_encoder(info, options, crf_shift=shift)
        log.info(
            "video encode",
            extra={"src": str(src), "encoder": choice.encoder, "crf": choice.crf, "attempt": attempts},
        )
        try:
            result = encode(choice)
        except av.error.FFmpegError as exc:
            raise VideoFormatError(
                f"{src.name}: cannot encode with {choice.encoder} ({one_line(exc)})"
            ) from exc
        _check_complete(src, info, result)
        if contrast_ok(result):
            break
        # nothing to raise: CRF 0, or an encoder whose quality is its profile (ProRes)
        at_best = choice.crf == 0 or (choice.crf is None and choice.bit_rate is None)
        if attempts > options.max_retries or at_best:
            report.notes.append(
                f"patch contrast after encoding is {report.patch_contrast_min:.2f} of intended "
                f"(below {options.min_patch_contrast}) after {attempts} attempts"
            )
            break
        shift += CRF_STEP_ON_RETRY
    report.attempts = attempts
    return choice, result


def _contrast_ok(
    report: model.VideoReport,
    dst: Path,
    spec: PatchSpec,
    placement_at: model.PlacementAt,
    target: float,
    options: model.VideoOptions,
    result: EncodeResult,
) -> bool:
    """Whether dst's patch kept enough contrast (or is not to be checked); records the measured
    min and mean (relative to target) of the selected frames in report."""
    if not options.verify_patch or result.frames_patched == 0 or target <= 0:
        return True
    measured = [v / target for v in measure_video_patch(dst, placement_at)]
    selected = [m for i, m in enumerate(measured) if spec.selects(f"frame:{i}")]
    report.patch_contrast_min = min(selected) if selected else None
    report.patch_contrast_mean = float(np.mean(selected)) if selected else None
    return report.patch_contrast_min is None or report.patch_contrast_min >= options.min_patch_contrast


def _check_complete(src: Path, info: model.SourceInfo, result: EncodeResult) -> None:
    if result.frames == 0:
        raise VideoFormatError(f"{src.name}: no frames decoded")
    if info.frames_declared and result.frames < info.frames_declared:
        raise VideoFormatError(
            f"{src.name}: truncated: {result.frames} of {info.frames_declared} declared frames decode"
        )
    if info.duration_s and result.end_s is not None and result.end_s < 0.9 * info.duration_s - 0.1:
        raise VideoFormatError(
            f"{src.name}: truncated: frames end at {result.end_s:.2f} s of a declared {info.duration_s:.2f} s"
        )


def _finish_report(
    report: model.VideoReport,
    info: model.SourceInfo,
    choice: model.EncoderChoice,
    result: EncodeResult,
    output_bit_rate: int | None,
) -> None:
    report.encoder = choice.encoder
    report.crf = choice.crf
    report.frames = result.frames
    report.frames_patched = result.frames_patched
    report.duration_s = info.duration_s
    report.output_bit_rate = output_bit_rate
    report.preserved = preserved_list(info, choice)
    # every frame is re-encoded (lossy): said, with the quality chosen (the summary counts it)
    quality = quality_text(choice)
    made_at = f"; the source was made at CRF {info.encoded_crf:g}" if info.encoded_crf is not None else ""
    report.notes.append(f"video re-encoded at quality {quality} with {choice.encoder} (lossy){made_at}")
    if report.location_removed:
        report.notes.append(
            f"location removed ({len(report.location_removed)}): " + ", ".join(report.location_removed)
        )
    if not choice.same_codec:
        report.notes.append(f"no {info.codec} encoder in this build; re-encoded as {choice.encoder}")
    if (written := encoder_pix_fmt(choice.encoder, info.pix_fmt)) != info.pix_fmt:
        report.notes.append(
            f"written as {written}: {choice.encoder} takes no {info.pix_fmt} (the decoder reads it back "
            f"as {info.pix_fmt}, with 2 bits less of precision)"
        )
    if info.alpha_mode and not model.has_alpha(info.pix_fmt):
        report.notes.append(
            f"transparency (alpha) left out: this build has no libvpx decoder for {info.codec}'s alpha; "
            "the output is opaque"
        )
    if info.hdr_side_data and choice.encoder != "libx265":
        report.notes.append(
            "HDR mastering/light-level metadata not carried ("
            f"{choice.encoder} takes it only through x265-params here)"
        )
