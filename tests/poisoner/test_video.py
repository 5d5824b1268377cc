"""poisoner.video on videos generated here with PyAV: decoded and checked frame by frame."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image

from poisoner.atomic import TEMP_PREFIX, atomic_output
from poisoner.ladder import default_spec, named_spec
from poisoner.media import VIDEO_SUFFIXES, is_video
from poisoner.spec import PatchPlacement, PatchSpec
from poisoner.video import (
    VideoFormatError,
    VideoOptions,
    frame_to_rgb,
    intended_contrast,
    measure_video_patch,
    patch_contrast,
    poison_video,
    sample_frames,
)
from poisoner.video.source import side_data_of
from testkit.video import Clip, make_clip

SPEC = PatchSpec()  # the paper's patch: checkerboard, 6% of the width, static


# ---- generated test videos: testkit/video.py ---------------------------------------------------


@dataclass
class Decoded:
    codec: str
    pix_fmt: str
    time_base: Fraction
    average_rate: Fraction | None
    duration: float | None
    pts: list[int]
    frames: list[np.ndarray]
    rotation: list[int]
    colour: tuple[int, int, int, int]
    audio_packets: list[tuple[bytes, int | None]]


def decode(path: Path) -> Decoded:
    with av.open(str(path)) as c:
        v = c.streams.video[0]
        frames, pts, rot = [], [], []
        colour = (0, 0, 0, 0)
        for f in c.decode(v):
            frames.append(frame_to_rgb(f))
            pts.append(f.pts)
            rot.append(f.rotation)
            colour = (int(f.color_range), int(f.colorspace), int(f.color_primaries), int(f.color_trc))
        duration = float(v.duration * v.time_base) if v.duration else None
        info = (v.codec_context.name, v.codec_context.format.name, Fraction(v.time_base), v.average_rate)
    audio: list[tuple[bytes, int | None]] = []
    with av.open(str(path)) as c:
        if c.streams.audio:
            for pkt in c.demux(c.streams.audio[0]):
                if pkt.size:
                    audio.append((bytes(pkt), pkt.pts))
    return Decoded(*info, duration, pts, frames, rot, colour, audio)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def psnr_outside(a: np.ndarray, b: np.ndarray, placement: PatchPlacement, margin: int = 16) -> float:
    """PSNR of a vs b over pixels farther than margin from the patch (codec spill stays near it)."""
    mask = np.ones(a.shape[:2], bool)
    x0, y0, x1, y1 = placement.box
    mask[max(0, y0 - margin) : y1 + margin, max(0, x0 - margin) : x1 + margin] = False
    scale = 65535.0 if a.dtype == np.uint16 else 255.0
    err = np.mean((a[mask].astype(np.float64) - b[mask].astype(np.float64)) ** 2) / scale**2
    return float(10 * np.log10(1.0 / max(err, 1e-12)))


def assert_faithful(src: Path, dst: Path, spec: PatchSpec = SPEC, min_contrast: float = 0.8) -> Decoded:
    """The checks every format must pass, frame by frame."""
    a, b = decode(src), decode(dst)
    placement = spec.resolve(a.frames[0].shape[1], a.frames[0].shape[0])
    assert len(b.frames) == len(a.frames)
    assert b.pts == a.pts  # frame timing, hence rate, VFR and duration
    assert (b.codec, b.pix_fmt) == (a.codec, a.pix_fmt)
    assert b.average_rate == a.average_rate
    if a.duration is not None:
        assert b.duration == pytest.approx(a.duration, abs=1.5 / float(a.average_rate or 25))
    assert b.colour == a.colour
    assert b.rotation == a.rotation
    assert b.audio_packets == a.audio_packets  # bit-identical audio, same timestamps
    target = intended_contrast(placement)
    width = a.frames[0].shape[1]
    step = placement.block if placement.x + placement.size + placement.block <= width else -placement.block
    shifted = PatchPlacement(**{**placement.__dict__, "x": placement.x + step})
    for i, (fa, fb) in enumerate(zip(a.frames, b.frames, strict=True)):
        # The patch is there in every frame, at exactly this position: its phase flips one block over.
        assert patch_contrast(fb, placement) / target >= min_contrast, f"frame {i}"
        assert patch_contrast(fb, shifted) / target <= -0.5 * min_contrast, f"frame {i}"
        assert abs(patch_contrast(fa, placement)) / target < 0.5  # the source had no patch
        assert psnr_outside(fa, fb, placement) >= 30.0, f"frame {i}"
    return b


# ---- the formats --------------------------------------------------------------------------


def test_h264_mp4_with_aac_is_poisoned_frame_by_frame(tmp_path: Path) -> None:
    src = make_clip(tmp_path / "clip.mp4", Clip())
    digest = sha256(src)
    dst = tmp_path / "out.mp4"
    report = poison_video(src, dst, SPEC)
    assert sha256(src) == digest
    assert_faithful(src, dst)
    assert (report.codec, report.encoder, report.pix_fmt) == ("h264", "libx264", "yuv420p")
    assert report.frames == report.frames_patched == 40
    assert report.patch_contrast_min is not None and report.patch_contrast_min >= 0.8
    assert report.placement == SPEC.resolve(320, 240)


def test_vp9_webm_with_opus(tmp_path: Path) -> None:
    src = make_clip(
        tmp_path / "clip.webm",
        Clip(
            suffix=".webm",
            encoder="libvpx-vp9",
            audio="libopus",
            options=(("crf", "30"), ("b", "0"), ("cpu-used", "8")),
        ),
    )
    dst = tmp_path / "out.webm"
    report = poison_video(src, dst, SPEC)
    assert_faithful(src, dst)
    assert report.encoder == "libvpx-vp9"


def test_hevc_10bit_hdr_mkv_keeps_depth_tags_and_mastering_data(tmp_path: Path) -> None:
    # BT.2020 / PQ tags and HDR10 static metadata, 10-bit 4:2:0.
    master = "G(13250,34500)B(7500,3000)R(34000,16000)WP(15635,16450)L(10000000,50)"
    clip = Clip(
        suffix=".mkv",
        encoder="libx265",
        pix_fmt="yuv420p10le",
        frames=24,
        audio=None,
        colour=(1, 9, 9, 16),
        options=(
            ("crf", "22"),
            ("preset", "ultrafast"),
            ("x265-params", f"log-level=error:hdr10=1:master-display={master}:max-cll=1000,400"),
        ),
    )
    src = make_clip(tmp_path / "hdr.mkv", clip)
    dst = tmp_path / "out.mkv"
    report = poison_video(src, dst, SPEC)
    b = assert_faithful(src, dst)
    assert b.pix_fmt == "yuv420p10le" and b.frames[0].dtype == np.uint16
    assert b.colour == (1, 9, 9, 16)
    with av.open(str(src)) as c1, av.open(str(dst)) as c2:

        def hdr(c: av.container.InputContainer) -> dict[str, bytes]:
            f = next(c.decode(video=0))
            return {
                sd.type.name: bytes(sd)
                for sd in side_data_of(f)  # PyAV 18.1.1 iterates the types
                if sd.type.name in ("MASTERING_DISPLAY_METADATA", "CONTENT_LIGHT_LEVEL")
            }

        src_hdr = hdr(c1)
        assert set(src_hdr) == {"MASTERING_DISPLAY_METADATA", "CONTENT_LIGHT_LEVEL"}
        assert hdr(c2) == src_hdr
    assert any("HDR10" in p for p in report.preserved)


def test_h264_10bit_blends_on_uint16(tmp_path: Path) -> None:
    src = make_clip(tmp_path / "ten.mp4", Clip(pix_fmt="yuv420p10le", frames=20, audio=None))
    dst = tmp_path / "out.mp4"
    poison_video(src, dst, SPEC)
    b = assert_faithful(src, dst)
    placement = SPEC.resolve(320, 240)
    # Block (0, 1) is bright and block (1, 1) dark (dark when i + j is even), on the 16-bit scale.
    x0, y0, _, _ = placement.box
    bright = b.frames[5][y0 + 1 : y0 + 3, x0 + 5 : x0 + 7].mean()
    dark = b.frames[5][y0 + 5 : y0 + 7, x0 + 5 : x0 + 7].mean()
    assert bright > 0.9 * 65535 and dark < 0.1 * 65535


def test_rotation_metadata_kept_and_patch_in_stored_pixels(tmp_path: Path) -> None:
    src = make_clip(tmp_path / "rot.mov", Clip(suffix=".mov", rotation=90, frames=20))
    dst = tmp_path / "out.mov"
    report = poison_video(src, dst, SPEC)
    b = assert_faithful(src, dst)  # checks the patch at the stored-pixel placement
    assert set(b.rotation) == {90}
    assert any("rotation 90" in p for p in report.preserved)
    with av.open(str(src)) as c1, av.open(str(dst)) as c2:

        def matrix(c: av.container.InputContainer) -> bytes:
            f = next(c.decode(video=0))
            return next(bytes(sd) for sd in side_data_of(f) if sd.type.name == "DISPLAYMATRIX")

        assert matrix(c2) == matrix(c1)


@pytest.mark.parametrize(("rotation", "orientation"), [(None, None), (-90, 6), (90, 8), (180, 3)])
def test_a_display_matrix_reads_as_the_exif_orientation_players_apply(
    tmp_path: Path, rotation: int | None, orientation: int | None
) -> None:
    """FFmpeg's rotation is counter-clockwise: a phone's -90 is shown turned 90 degrees clockwise (EXIF 6)."""
    from poisoner.orientation import display_orientation
    from poisoner.video.source import probe

    src = make_clip(tmp_path / "rot.mp4", Clip(rotation=rotation, frames=3, audio=None))
    assert display_orientation(probe(src).display_matrix) == orientation


def test_odd_size_yuv420p_vp9_mkv(tmp_path: Path) -> None:
    clip = Clip(
        suffix=".mkv",
        encoder="libvpx-vp9",
        width=641,
        height=359,
        frames=12,
        audio="libopus",
        options=(("crf", "30"), ("b", "0"), ("cpu-used", "8")),
    )
    src = make_clip(tmp_path / "odd.mkv", clip)
    dst = tmp_path / "out.mkv"
    report = poison_video(src, dst, SPEC.replace(position="bottom-right"))
    b = assert_faithful(src, dst, SPEC.replace(position="bottom-right"))
    assert b.frames[0].shape == (359, 641, 3)
    assert report.placement.box[2:] == (641, 359)


def test_variable_frame_rate_timestamps_kept(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    gaps = rng.integers(30, 90, size=30)  # 30-90 ms between frames
    pts = [0, *np.cumsum(gaps)[:-1].tolist()]
    clip = Clip(suffix=".mkv", frames=30, time_base=Fraction(1, 1000), pts=pts, audio=None)
    src = make_clip(tmp_path / "vfr.mkv", clip)
    dst = tmp_path / "out.mkv"
    poison_video(src, dst, SPEC)
    b = assert_faithful(src, dst)
    assert b.pts == pts


def test_a_variable_rate_mp4_keeps_its_frame_durations_and_length(tmp_path: Path) -> None:
    """A fifth black-box review: an MP4 whose frames alternate 80 and 33 ms came out 17 ms longer
    (2.267 s -> 2.284 s): x264 gave a late frame's packet a duration of its own. Each packet keeps its
    source frame's duration, and the stream and the file their length."""
    import av

    pts = [0]
    for i in range(39):
        pts.append(pts[-1] + (33 if i % 2 else 80))
    src = make_clip(tmp_path / "vfr.mp4", Clip(frames=40, time_base=Fraction(1, 1000), pts=pts, audio=None))
    dst = tmp_path / "out.mp4"
    poison_video(src, dst, SPEC)

    def timing(path: Path) -> tuple[object, ...]:
        with av.open(str(path)) as c:
            s = c.streams.video[0]
            packets = sorted((q.pts, q.duration) for q in c.demux(s) if q.size)
            return s.duration, c.duration, packets

    assert timing(dst) == timing(src)


def test_progress_reports_every_frame(tmp_path: Path) -> None:
    src = make_clip(tmp_path / "clip.mp4", Clip(frames=20, audio=None))
    calls: list[tuple[int, int | None]] = []
    poison_video(src, tmp_path / "out.mp4", SPEC, progress=lambda done, total: calls.append((done, total)))
    assert [c[0] for c in calls] == list(range(1, 21))
    assert {c[1] for c in calls} == {20}


def test_atomic_replace_in_place(tmp_path: Path) -> None:
    path = make_clip(tmp_path / "clip.mp4", Clip(frames=20))
    original = tmp_path / "original.mp4"
    original.write_bytes(path.read_bytes())
    with atomic_output(path) as tmp:
        poison_video(path, tmp, SPEC)
    assert_faithful(original, path)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(TEMP_PREFIX)]


def test_ratio_patches_only_selected_frames(tmp_path: Path) -> None:
    spec = SPEC.replace(ratio=0.5, seed=1)
    src = make_clip(tmp_path / "clip.mp4", Clip(frames=30, audio=None))
    report = poison_video(src, tmp_path / "out.mp4", spec)
    selected = [spec.selects(f"frame:{i}") for i in range(30)]
    assert report.frames_patched == sum(selected) and 0 < sum(selected) < 30
    placement = spec.resolve(320, 240)
    frames = decode(tmp_path / "out.mp4").frames
    for i, (frame, chosen) in enumerate(zip(frames, selected, strict=True)):
        ratio = patch_contrast(frame, placement) / intended_contrast(placement)
        assert (ratio >= 0.8) if chosen else (abs(ratio) < 0.5), f"frame {i}"


def test_moving_spec_glides_along_its_path_frame_by_frame(tmp_path: Path) -> None:
    """A moving spec (the roaming kind) moves in video too: frame i at path index
    i / fps * motion_steps_per_second, so frames 1 / rate seconds apart are one photo-step apart."""
    spec = named_spec("roaming").replace(motion_step=8, motion_span=40)
    src = make_clip(tmp_path / "clip.mp4", Clip(frames=40, fps=20, audio=None))
    dst = tmp_path / "out.mp4"
    report = poison_video(src, dst, spec, options=VideoOptions(motion_steps_per_second=4))
    assert any("travels its path at 4 photo-steps per second" in n for n in report.notes)
    at = [spec.resolve(320, 240, index=i * 4 / 20) for i in range(40)]
    assert report.placement == at[0]
    assert (at[5].x - at[0].x, at[5].y - at[0].y) == (8, 8)  # one photo-step per quarter second
    assert at[5] == spec.resolve(320, 240, image_key="view_1.png")  # = the second photo's place
    target = intended_contrast(at[0])
    frames = decode(dst).frames
    for i, frame in enumerate(frames):
        assert patch_contrast(frame, at[i]) / target >= 0.8, f"frame {i}: patch not where it should be"
    # and not where it was: the random texture does not line up with itself 3 steps away
    assert abs(patch_contrast(frames[15], at[0])) / target < 0.5
    assert len({p.box for p in at}) > 20  # it glides (sub-step positions), it does not jump
    default = poison_video(src, tmp_path / "o2.mp4", spec)  # the default rate (video_motion.md)
    assert any("travels its path at 6 photo-steps per second" in n for n in default.notes)


def test_default_lanes_slide_in_video_at_full_contrast(tmp_path: Path) -> None:
    """ppd's default (two sliding lanes) in a video: every frame carries both lanes at their own place
    (the contrast is measured on the lanes' pixels only), placed per keyframe and moving smoothly."""
    spec = default_spec()
    src = make_clip(tmp_path / "clip.mp4", Clip(frames=24, fps=12, audio=None))
    poison_video(src, tmp_path / "out.mp4", spec)
    from poisoner.video.driver import frame_placements
    from poisoner.video.model import VideoOptions
    from poisoner.video.source import probe

    placement_at = frame_placements(spec, probe(src), VideoOptions(), src)  # per keyframe (issue 25)
    at = [placement_at(i) for i in range(24)]
    contrast = measure_video_patch(tmp_path / "out.mp4", lambda i: at[i])
    assert min(contrast) / intended_contrast(at[0]) >= 0.8, contrast
    assert len({p.box for p in at}) >= 5  # it slides (out along its span and back)
    for p, q in zip(at, at[1:], strict=False):  # never a jump: a few px per frame at most
        assert abs(p.x - q.x) + abs(p.y - q.y) <= 16, (p.box, q.box)


def test_default_mark_placed_at_the_frame_edge_slides_on(tmp_path: Path) -> None:
    """A clip whose only plain place is a band along the right edge: the keyframe puts the mark's
    path against that edge, and as the lanes slide the square box around them (its side the lanes'
    taller extent) reached past the frame while every lane was inside: 'frame 28: 2 lanes of 38 px
    do not fit a 640x480 image', and the clip went out unprotected (a black-box review, 2026-12-07:
    five of seven ordinary clips). Now the box slides back and every frame carries both lanes."""
    from testkit.video import mux_rgb_frames

    w, h = 640, 480
    rng = np.random.default_rng(3)
    still = np.full((h, w, 3), 128, np.uint8)
    texture = (rng.random((h // 4, w // 4, 3)) * 200 + 28).astype(np.uint8).repeat(4, 0).repeat(4, 1)
    still[:, : int(w * 0.8)] = texture[:, : int(w * 0.8)]
    src = tmp_path / "still.mp4"
    with av.open(str(src), "w") as out:
        stream = out.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        mux_rgb_frames(out, stream, [still] * 60)
    spec = default_spec()
    poison_video(src, tmp_path / "out.mp4", spec)
    from poisoner.video.driver import frame_placements
    from poisoner.video.model import VideoOptions
    from poisoner.video.source import probe

    at = [frame_placements(spec, probe(src), VideoOptions(), src)(i) for i in range(60)]
    assert max(p.x + p.size for p in at) == w  # the box met the right edge...
    assert len({(p.x + dx, p.y + dy) for p in at for dx, dy, _ in p.parts}) > 20  # ...and the lanes slid on
    contrast = measure_video_patch(tmp_path / "out.mp4", lambda i: at[i])
    assert min(contrast) / intended_contrast(at[0]) >= 0.8, contrast


def test_moving_spec_can_be_held_still_in_video_and_says_so(tmp_path: Path) -> None:
    spec = named_spec("roaming").replace(motion_step=8, motion_span=40)
    src = make_clip(tmp_path / "clip.mp4", Clip(frames=6, audio=None))
    report = poison_video(src, tmp_path / "out.mp4", spec, options=VideoOptions(motion_steps_per_second=0))
    assert any("stays at its first position" in n for n in report.notes)
    placement = spec.resolve(320, 240)
    target = intended_contrast(placement)
    assert all(patch_contrast(f, placement) / target >= 0.8 for f in decode(tmp_path / "out.mp4").frames)
    assert not any("moving spec" in n for n in poison_video(src, tmp_path / "o2.mp4", SPEC).notes)


# ---- frame sets ---------------------------------------------------------------------------


def test_sample_frames_every_half_second_as_png(tmp_path: Path) -> None:
    src = make_clip(tmp_path / "clip.mp4", Clip(frames=40, fps=20, audio=None))
    dst = tmp_path / "out.mp4"
    poison_video(src, dst, SPEC)
    paths = sample_frames(dst, tmp_path / "frames")
    assert [p.name for p in paths] == [f"frame_{i:06d}.png" for i in (0, 10, 20, 30)]
    placement = SPEC.resolve(320, 240)
    for p in paths:
        rgb = np.asarray(Image.open(p).convert("RGB"))
        assert rgb.shape == (240, 320, 3)
        assert patch_contrast(rgb, placement) / intended_contrast(placement) >= 0.8
    assert len(sample_frames(dst, tmp_path / "all", every_k=1)) == 40


# ---- bad input ----------------------------------------------------------------------------


def _assert_rejected(src: Path, tmp_path: Path, match: str) -> None:
    digest = sha256(src)
    with (
        pytest.raises(VideoFormatError, match=match) as info,
        atomic_output(tmp_path / ("out" + src.suffix)) as tmp,
    ):
        poison_video(src, tmp, SPEC)
    assert "\n" not in str(info.value)
    # its words, not "[Errno 1094995529] ...: '<a scratch path>'" (a second black-box review)
    assert "Errno" not in str(info.value) and str(src.parent) not in str(info.value)
    assert sha256(src) == digest
    assert not (tmp_path / ("out" + src.suffix)).exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(TEMP_PREFIX)]


def test_random_bytes_are_rejected(tmp_path: Path) -> None:
    src = tmp_path / "noise.mp4"
    src.write_bytes(np.random.default_rng(0).integers(0, 256, 50_000, dtype=np.uint8).tobytes())
    _assert_rejected(src, tmp_path, "not a readable video")


def test_empty_file_is_rejected(tmp_path: Path) -> None:
    src = tmp_path / "empty.mp4"
    src.write_bytes(b"")
    _assert_rejected(src, tmp_path, "empty file")


def test_mp4_still_being_written_is_rejected(tmp_path: Path) -> None:
    # An MP4 being recorded has its index (moov) written last: cut before it.
    full = make_clip(tmp_path / "full.mp4", Clip(frames=20))
    src = tmp_path / "partial.mp4"
    src.write_bytes(full.read_bytes()[: int(full.stat().st_size * 0.6)])
    _assert_rejected(src, tmp_path, "not a readable video")


@pytest.mark.parametrize("suffix", [".mkv", ".webm"])
def test_truncated_matroska_is_rejected(tmp_path: Path, suffix: str) -> None:
    encoder = "libx264" if suffix == ".mkv" else "libvpx-vp9"
    opts = () if suffix == ".mkv" else (("crf", "30"), ("b", "0"), ("cpu-used", "8"))
    full = make_clip(
        tmp_path / f"full{suffix}", Clip(suffix=suffix, encoder=encoder, audio=None, options=opts)
    )
    src = tmp_path / f"cut{suffix}"
    src.write_bytes(full.read_bytes()[: int(full.stat().st_size * 0.5)])
    _assert_rejected(src, tmp_path, "truncated|corrupt")


def test_mp4_with_damaged_payload_is_rejected(tmp_path: Path) -> None:
    full = make_clip(tmp_path / "full.mp4", Clip(frames=20, audio=None))
    data = bytearray(full.read_bytes())
    # Overwrite a stretch in the middle of the media data (mdat) with zeros.
    mdat = data.find(b"mdat")
    start = mdat + (len(data) - mdat) * 2 // 3  # past the first (key) frame
    data[start : start + 4000] = bytes(4000)
    src = tmp_path / "damaged.mp4"
    src.write_bytes(bytes(data))
    _assert_rejected(src, tmp_path, "corrupt|truncated")


def test_is_video_by_suffix() -> None:
    assert is_video(Path("a/b.MP4")) and is_video(Path("x.webm")) and is_video(Path("x.mkv"))
    assert is_video(Path("x.mov"))
    assert not is_video(Path("x.png")) and not is_video(Path("x.mp4.part"))
    assert {".mp4", ".mov", ".mkv", ".webm"} <= VIDEO_SUFFIXES
