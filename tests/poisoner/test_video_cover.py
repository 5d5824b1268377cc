"""A video's cover picture (an `attached_pic` stream: MP4 `covr`, a Matroska image attachment) was copied
as it was: an unmarked picture of the subject published beside the marked frames, as a photo's EXIF
thumbnail was (docs/FORMATS.md "Thumbnails"). Now each is marked as a photo of its own size is, or left
out where it cannot be, and the report says it once."""

from __future__ import annotations

import io
from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image

from poisoner.blend import apply_patch
from poisoner.spec import PatchSpec
from poisoner.video import VideoOptions, poison_video
from poisoner.video.demux import audio_only, main_video_stream
from testkit.video import Clip, add_cover, make_clip, mux_sine, quicktime_branded

SPEC = PatchSpec(patch_size=16, block_size=4, position="top-left", offset=(4, 4))
FAST = VideoOptions(verify_patch=False, preset="ultrafast", threads=1)
COVER = (32, 24)


def cover_picture(fmt: str, exif: bytes = b"") -> tuple[np.ndarray, bytes]:
    """A 32x24 picture (a smooth gradient, so the mark stands out) and its file bytes."""
    x, y = np.meshgrid(np.arange(COVER[0]), np.arange(COVER[1]))
    rgb = np.stack([x * 6 + 20, y * 8 + 20, np.full_like(x, 128)], axis=-1).astype(np.uint8)
    out = io.BytesIO()
    Image.fromarray(rgb).save(out, fmt, **({"quality": 90} if fmt == "JPEG" else {}), exif=exif)
    return rgb, out.getvalue()


def clip(path: Path, picture: bytes | None) -> Path:
    return make_clip(path, Clip(suffix=path.suffix, width=64, height=48, frames=4, audio=None, cover=picture))


def covers_of(path: Path) -> list[tuple[str, dict[str, str], bytes]]:
    """Each cover stream's codec, tags and picture bytes, as FFmpeg reads them."""
    with av.open(str(path)) as c:
        streams = {s.index: (s.codec_context.name, dict(s.metadata)) for s in c.streams.video
                   if s.disposition & av.stream.Disposition.attached_pic}  # fmt: skip
        pictures = {p.stream.index: bytes(p) for p in c.demux() if p.stream.index in streams and p.size}
    return [(*streams[i], pictures[i]) for i in sorted(streams)]


def coded_runs(picture: bytes) -> list[bytes]:
    """32-byte runs of a picture's coded data (a JPEG's scan, a PNG's IDAT): none may be published."""
    if picture.startswith(b"\xff\xd8"):
        data = picture[picture.index(b"\xff\xda") + 14 : -2]
    else:
        data = picture[picture.index(b"IDAT") + 4 : picture.index(b"IEND") - 8]
    return [data[i : i + 32] for i in range(0, len(data) - 32, 8)]


@pytest.mark.parametrize(
    ("suffix", "fmt", "codec"),
    [(".mp4", "JPEG", "mjpeg"), (".mp4", "PNG", "png"), (".mkv", "JPEG", "mjpeg"), (".mkv", "PNG", "png")],
)
def test_a_cover_picture_is_marked_at_its_own_size(tmp_path: Path, suffix: str, fmt: str, codec: str) -> None:
    rgb, picture = cover_picture(fmt)
    src = clip(tmp_path / f"a{suffix}", picture)
    assert [(c, p) for c, _, p in covers_of(src)] == [(codec, picture)]  # the source has it, as written
    reports = [poison_video(src, tmp_path / f"o{i}{suffix}", SPEC, options=FAST) for i in (1, 2)]
    out = tmp_path / f"o1{suffix}"
    [(out_codec, tags, marked)] = covers_of(out)
    assert out_codec == codec and marked != picture
    if suffix == ".mkv":  # still an attachment of its name and type
        assert (tags["filename"], tags["mimetype"]) == (f"cover.{'jpg' if fmt == 'JPEG' else 'png'}",
                                                         f"image/{fmt.lower()}")  # fmt: skip
    published = out.read_bytes()
    assert picture not in published and not [r for r in coded_runs(picture) if r in published]
    with Image.open(io.BytesIO(marked)) as im:
        assert (im.format, im.size) == (fmt, COVER)
        now = np.asarray(im.convert("RGB")).astype(int)
    expected = apply_patch(rgb, SPEC.resolve(*COVER)).astype(int)  # the spec on a picture of its size
    x0, y0, x1, y1 = SPEC.resolve(*COVER).box
    mark = (slice(y0, y1), slice(x0, x1))
    assert np.abs(now[mark] - rgb[mark]).mean() > 40  # the mark is there
    if fmt == "PNG":
        assert np.array_equal(now, expected)  # lossless: exactly the image path's pixels
    else:
        assert np.abs(now[mark] - expected[mark]).mean() < 12
    assert [n for n in reports[0].notes if "cover" in n] == [f"cover picture marked (32x24 {fmt})"]
    # the same input gives the same bytes (the daemon re-poisons to check crash recovery)
    assert published == (tmp_path / f"o2{suffix}").read_bytes()
    with av.open(str(out)) as c:  # the video itself is whole
        assert sum(1 for _ in c.decode(video=0)) == 4


@pytest.mark.parametrize("suffix", [".mov", ".webm"])
def test_a_cover_in_a_container_ffmpeg_writes_none_into_is_removed_and_said(
    tmp_path: Path, suffix: str
) -> None:
    """FFmpeg's mov and webm muxers write no cover: a MOV's was dropped unsaid, a WebM with one failed.
    Now it is left out with a note."""
    _, picture = cover_picture("JPEG")
    if suffix == ".mov":
        src = quicktime_branded(clip(tmp_path / "a.mp4", picture), tmp_path / "a.mov")
    else:  # a Matroska file with an attachment, under .webm: FFmpeg reads it as it reads a WebM
        vp9 = Clip(
            suffix=".mkv", encoder="libvpx-vp9", width=64, height=48, frames=4, audio=None, cover=picture
        )
        src = make_clip(tmp_path / "a.mkv", vp9).rename(tmp_path / "a.webm")
    assert [p for _, _, p in covers_of(src)] == [picture]
    report = poison_video(src, tmp_path / f"o{suffix}", SPEC, options=FAST)
    assert covers_of(tmp_path / f"o{suffix}") == [] and picture not in (tmp_path / f"o{suffix}").read_bytes()
    assert [n for n in report.notes if "cover" in n] == [
        f"cover picture removed (FFmpeg writes no cover picture into {'MOV' if suffix == '.mov' else 'WebM'})"
    ]


def _gif() -> bytes:
    out = io.BytesIO()
    Image.new("RGB", COVER, (200, 30, 30)).save(out, "GIF")
    return out.getvalue()


@pytest.mark.parametrize(
    ("name", "why"),
    [
        ("too-small", "32x24 cannot hold the mark"),
        ("truncated", "cannot decode"),
        ("gif", "not a JPEG, PNG, WebP or HEIF picture, which ppd writes"),
        ("bad-crc", "not a recognised image file"),
    ],
)
def test_a_cover_that_cannot_be_marked_is_removed_never_copied(tmp_path: Path, name: str, why: str) -> None:
    """One too small for the mark, one that does not decode, a picture ppd does not write (a Matroska
    GIF attachment), a PNG whose header's CRC is wrong (Pillow's error named an object's address,
    different on every run): each left out of the output with its reason, as the image path words it,
    never published unmarked."""
    _, picture = cover_picture("JPEG")
    spec, suffix = SPEC, ".mp4"
    if name == "too-small":
        spec = PatchSpec(patch_size=28, block_size=4, position="top-left", offset=(0, 0))
    elif name == "truncated":
        picture = picture[: picture.index(b"\xff\xda") + 40]  # the header whole, the scan cut
    elif name == "bad-crc":  # a Matroska image/png attachment: FFmpeg reads it as an attached_pic
        _, png = cover_picture("PNG")
        picture, suffix = png[:29] + bytes([png[29] ^ 0xFF]) + png[30:], ".mkv"  # IHDR's CRC
    else:
        picture, suffix = _gif(), ".mkv"
    src = tmp_path / f"a{suffix}"
    if name == "gif":  # testkit's add_cover writes JPEG or PNG; Matroska takes any image attachment
        with av.open(str(src), "w") as out:
            vs = out.add_stream("libx264", rate=10)
            vs.width, vs.height, vs.pix_fmt = 64, 48, "yuv420p"
            out.add_attachment("cover.gif", "image/gif", picture)
            make_frames(out, vs)
    else:
        clip(src, picture)
    assert [p for _, _, p in covers_of(src)] == [picture]
    report = poison_video(src, tmp_path / f"o{suffix}", spec, options=FAST)
    assert covers_of(tmp_path / f"o{suffix}") == [] and picture not in (tmp_path / f"o{suffix}").read_bytes()
    [note] = [n for n in report.notes if "cover" in n]
    assert note.startswith("cover picture removed (") and why in note, note
    if name == "bad-crc":
        assert note == f"cover picture removed ({why})"


def attachments_of(path: Path) -> dict[str, tuple[str, bytes]]:
    """Each plain attachment stream's (type, bytes) by file name, as FFmpeg reads them."""
    with av.open(str(path)) as c:
        return {s.name: (s.mimetype, s.data) for s in c.streams if isinstance(s, av.stream.AttachmentStream)}


@pytest.mark.parametrize(
    ("mime", "fmt", "marked"),
    [
        ("image/webp", "WEBP", True),
        ("image/jpg", "JPEG", True),  # a common misspelling of image/jpeg
        ("application/octet-stream", "PNG", True),
        ("image/bmp", "BMP", False),
    ],
)
def test_a_matroska_picture_attachment_ffmpeg_reads_as_a_plain_attachment_is_a_cover(
    tmp_path: Path, mime: str, fmt: str, marked: bool
) -> None:
    """FFmpeg makes an attached_pic only of a JPEG, PNG, GIF or TIFF type: a picture attachment of
    another type stayed a plain attachment and was copied unmarked, unsaid. Its bytes now say it is a
    picture: marked (an attachment of its name and type) or removed with the reason. A font and a
    subtitle file are attachments too, and are copied as they were."""
    import matplotlib

    rgb, picture = cover_picture(fmt)
    font = Path(matplotlib.get_data_path(), "fonts", "ttf", "cmex10.ttf").read_bytes()
    subtitles = b"[Script Info]\nScriptType: v4.00+\n"
    name = f"cover.{fmt.lower()}"
    src = tmp_path / "a.mkv"
    with av.open(str(src), "w") as out:
        vs = out.add_stream("libx264", rate=10)
        vs.width, vs.height, vs.pix_fmt = 64, 48, "yuv420p"
        out.add_attachment(name, mime, picture)
        out.add_attachment("font.ttf", "application/x-truetype-font", font)
        out.add_attachment("subs.ass", "text/x-ssa", subtitles)
        make_frames(out, vs)
    kept = {"font.ttf": ("application/x-truetype-font", font), "subs.ass": ("text/x-ssa", subtitles)}
    assert attachments_of(src) == {name: (mime, picture), **kept} and covers_of(src) == []
    report = poison_video(src, tmp_path / "o.mkv", SPEC, options=FAST)
    got = attachments_of(tmp_path / "o.mkv")
    assert picture not in (tmp_path / "o.mkv").read_bytes()
    [note] = [n for n in report.notes if "cover" in n]
    if not marked:
        assert got == kept
        assert note == "cover picture removed (not a JPEG, PNG, WebP or HEIF picture, which ppd writes)"
        return
    assert got.keys() == {name, *kept} and {k: got[k] for k in kept} == kept
    out_mime, out_picture = got[name]
    assert out_mime == mime and note == f"cover picture marked (32x24 {fmt})"
    with Image.open(io.BytesIO(out_picture)) as im:
        assert (im.format, im.size) == (fmt, COVER)
        now = np.asarray(im.convert("RGB")).astype(int)
    x0, y0, x1, y1 = SPEC.resolve(*COVER).box
    assert np.abs(now[y0:y1, x0:x1] - rgb[y0:y1, x0:x1]).mean() > 40  # the mark is there


def make_frames(out: av.container.OutputContainer, vs: av.video.stream.VideoStream) -> None:
    from testkit.video import mux_rgb_frames, scene

    mux_rgb_frames(out, vs, (scene(64, 48, i) for i in range(4)))


def test_location_in_a_covers_own_exif_is_removed(tmp_path: Path) -> None:
    """A phone's cover JPEG can carry its EXIF GPS: the image path takes it out, as from a photo."""
    exif = Image.Exif()
    exif.get_ifd(0x8825)[2] = (48.0, 51.0, 24.0)  # GPSLatitude
    _, picture = cover_picture("JPEG", exif.tobytes())
    src = clip(tmp_path / "a.mp4", picture)
    report = poison_video(src, tmp_path / "o.mp4", SPEC, options=FAST)
    [(_, _, marked)] = covers_of(tmp_path / "o.mp4")
    with Image.open(io.BytesIO(marked)) as im:
        assert 0x8825 not in im.getexif()
    removed = report.location_removed
    assert any(r.startswith("cover picture EXIF GPS") for r in removed), removed


def test_cover_art_is_neither_the_video_stream_nor_a_picture_of_a_sound_file(tmp_path: Path) -> None:
    """demux: a cover is never taken for the video's frames, and sound with a cover is still sound only."""
    _, picture = cover_picture("JPEG")
    video = clip(tmp_path / "v.mp4", picture)
    with av.open(str(video)) as c:
        assert main_video_stream(c, "v.mp4").codec_context.name == "h264"
    assert not audio_only(video)
    memo = tmp_path / "memo.mp4"
    with av.open(str(memo), "w") as out:
        sound = out.add_stream("aac", rate=48000)
        sound.layout = "mono"
        add_cover(out, picture)
        mux_sine(out, sound, 24000, hz=440, amplitude=0.3, fmt="flt", layout="mono", fallback_step=960)
    assert [p for _, _, p in covers_of(memo)] == [picture] and audio_only(memo)


def test_ppd_poison_marks_or_removes_covers_says_it_once_and_restore_gives_the_originals_back(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Through `ppd poison` (the dataset's own spec): an MP4's cover (a frame, as phones set it) is
    published marked, a MOV's left out; the summary says each once; `ppd restore` gives both back byte
    for byte from the vault."""
    from typer.testing import CliRunner

    from daemon.cli import app
    from testkit.video import scene

    runner = CliRunner()
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    frame = io.BytesIO()
    Image.fromarray(scene(320, 240, 0)).resize((160, 120)).save(frame, "JPEG", quality=90)
    picture = frame.getvalue()
    make_clip(shoot / "a.mp4", Clip(frames=8, audio=None, cover=picture))
    other = make_clip(tmp_path / "b.mp4", Clip(frames=8, audio=None, cover=picture))
    quicktime_branded(other, shoot / "b.mov")
    before = {p.name: p.read_bytes() for p in shoot.iterdir()}
    result = runner.invoke(app, ["poison", str(shoot)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    beside = "copied as it was, it showed an unmarked picture beside the marked frames"
    for words, name in [
        (f"marked ({beside})", "a.mp4"),
        (f"removed (ppd could not mark it; {beside})", "b.mov"),
    ]:
        line = f"video cover picture {words}: 1 file(s) ({name}); `ppd -v poison` says how"
        assert text.count(line) == 1, text
    [(_, _, marked)] = covers_of(shoot / "a.mp4")
    assert marked != picture and marked.startswith(b"\xff\xd8")
    assert covers_of(shoot / "b.mov") == []
    assert not [p for p in shoot.iterdir() if picture in p.read_bytes()]
    assert runner.invoke(app, ["restore", str(shoot)]).exit_code == 0
    assert {p.name: p.read_bytes() for p in shoot.iterdir()} == before
