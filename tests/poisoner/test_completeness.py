"""Complete files only (issue 20, row 4): truncated files of every format are detected from
their structure; complete files pass."""

from __future__ import annotations

import io
import subprocess
import sys
import textwrap
from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image

from poisoner.completeness import incomplete_reason
from testkit.video import mux_rgb_frames


def pixels(h: int = 90, w: int = 120) -> np.ndarray:
    return np.random.default_rng(5).integers(0, 256, size=(h, w, 3)).astype(np.uint8)


def image(fmt: str, **opts: object):  # a writer for the table below
    def write(path: Path) -> None:
        if fmt in ("HEIF", "AVIF"):
            import pillow_heif

            pillow_heif.register_heif_opener()
        Image.fromarray(pixels()).save(path, fmt, **opts)

    return write


def gif(path: Path) -> None:
    frames = [Image.fromarray(pixels()).convert("P") for _ in range(3)]
    frames[0].save(path, "GIF", save_all=True, append_images=frames[1:])


def video(muxer: str, encoder: str = "libx264", options: dict[str, str] | None = None):
    def write(path: Path) -> None:
        with av.open(str(path), "w", format=muxer, options=options or {}) as out:
            vs = out.add_stream(encoder, rate=10)
            vs.width, vs.height, vs.pix_fmt = 96, 64, "yuv420p"
            if encoder == "libx264":
                vs.codec_context.gop_size = 4
            rng = np.random.default_rng(1)
            mux_rgb_frames(out, vs, (rng.integers(0, 256, (64, 96, 3), dtype=np.uint8) for _ in range(12)))

    return write


WRITERS = {
    "a.jpg": image("JPEG", quality=90),
    "p.jpg": image("JPEG", quality=90, progressive=True),
    "r.jpg": image("JPEG", quality=90, restart_marker_blocks=2),
    "a.png": image("PNG"),
    "lossy.webp": image("WEBP", quality=80),
    "lossless.webp": image("WEBP", lossless=True),
    "a.gif": gif,
    "raw.tif": image("TIFF"),
    "lzw.tif": image("TIFF", compression="tiff_lzw"),
    "a.heic": image("HEIF", quality=60),
    "a.avif": image("AVIF", quality=60),
    "a.mp4": video("mp4"),
    "fast.mp4": video("mp4", options={"movflags": "+faststart"}),
    "frag.mp4": video("mp4", options={"movflags": "frag_keyframe+empty_moov"}),
    "a.mov": video("mov"),
    "a.mkv": video("matroska"),
    "a.webm": video("webm", encoder="libvpx-vp9"),
}


def cut_points(size: int) -> list[int]:
    points = {1, 8, 17, size // 3, size // 2, (2 * size) // 3, size - 64, size - 3, size - 1}
    return sorted(p for p in points if 0 < p < size)


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_complete_passes_truncated_is_caught(tmp_path: Path, name: str) -> None:
    src = tmp_path / name
    WRITERS[name](src)
    assert incomplete_reason(src) is None, incomplete_reason(src)
    data = src.read_bytes()
    cut = tmp_path / f"cut{src.suffix}"
    for n in cut_points(len(data)):
        cut.write_bytes(data[:n])
        reason = incomplete_reason(cut)
        assert reason is not None, f"{name} cut to {n} of {len(data)} bytes was taken as complete"
        assert "\n" not in reason


def test_fragmented_mp4_cut_inside_a_fragment(tmp_path: Path) -> None:
    """A fragmented MP4 is playable at every fragment boundary; a cut inside a fragment is not."""
    src = tmp_path / "frag.mp4"
    WRITERS["frag.mp4"](src)
    data = src.read_bytes()
    last_moof = data.rfind(b"moof") - 4
    (tmp_path / "moof-only.mp4").write_bytes(data[: data.find(b"mdat", last_moof) - 4])
    assert "moof" in (incomplete_reason(tmp_path / "moof-only.mp4") or "")
    (tmp_path / "boundary.mp4").write_bytes(data[:last_moof])
    assert incomplete_reason(tmp_path / "boundary.mp4") is None  # a real, shorter fragmented file


def test_jpeg_trailing_bytes_after_eoi_are_allowed(tmp_path: Path) -> None:
    """Motion Photos and MPF keep data after the first EOI: complete by policy."""
    buf = io.BytesIO()
    Image.fromarray(pixels()).save(buf, "JPEG")
    (tmp_path / "t.jpg").write_bytes(buf.getvalue() + b"\x00\x00\x00\x18ftypmp42" + b"x" * 500)
    assert incomplete_reason(tmp_path / "t.jpg") is None


def test_png_bad_crc_and_missing_ihdr(tmp_path: Path) -> None:
    buf = io.BytesIO()
    Image.fromarray(pixels()).save(buf, "PNG")
    data = bytearray(buf.getvalue())
    data[40] ^= 0xFF  # inside the first IDAT
    (tmp_path / "crc.png").write_bytes(bytes(data))
    assert "CRC" in (incomplete_reason(tmp_path / "crc.png") or "")


def test_empty_tiny_and_unknown(tmp_path: Path) -> None:
    (tmp_path / "e.jpg").write_bytes(b"")
    assert incomplete_reason(tmp_path / "e.jpg") == "empty file (0 bytes)"
    (tmp_path / "t.bin").write_bytes(b"\xff")
    assert incomplete_reason(tmp_path / "t.bin") is not None
    (tmp_path / "notes.txt").write_text("plain text, long enough to not be a fragment of anything\n")
    assert incomplete_reason(tmp_path / "notes.txt") is None  # not a format judged here
    assert (
        incomplete_reason(
            tmp_path / "missing.jpg",
        )
        is not None
    )


def test_live_matroska_of_unknown_size_is_incomplete(tmp_path: Path) -> None:
    """How a recorder writes Matroska until it stops (segment and cluster sizes unknown, no Cues):
    produced here by muxing to a pipe, which FFmpeg cannot seek back into."""
    script = textwrap.dedent(
        """
        import sys, av, numpy as np
        with av.open(sys.stdout.buffer, "w", format="matroska") as out:
            vs = out.add_stream("libx264", rate=10)
            vs.width, vs.height, vs.pix_fmt = 96, 64, "yuv420p"
            for i in range(10):
                f = av.VideoFrame.from_ndarray(np.full((64, 96, 3), i * 20, np.uint8), format="rgb24")
                f = f.reformat(format="yuv420p"); f.pts = i
                for p in vs.encode(f):
                    out.mux(p)
            for p in vs.encode(None):
                out.mux(p)
        """
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, check=False)  # a pipe
    assert run.returncode == 0, run.stderr[-500:]
    (tmp_path / "live.mkv").write_bytes(run.stdout)
    with av.open(str(tmp_path / "live.mkv")) as c:  # a playable file all the same
        assert sum(1 for _ in c.decode(video=0)) == 10
    reason = incomplete_reason(tmp_path / "live.mkv")
    assert reason is not None and "still being recorded" in reason
