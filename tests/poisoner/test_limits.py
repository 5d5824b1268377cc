"""Bounded memory (issue 20, row 6): sizes read from headers, hostile files refused before any
decode, measured in child processes."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image

from poisoner.formats import ImageFormatError, poison_file
from poisoner.limits import (
    DEFAULT_MAX_PIXELS,
    check_decode_budget,
    decoded_bytes_estimate,
    decoded_size,
)
from poisoner.spec import PatchSpec
from poisoner.video import VideoFormatError, VideoOptions, poison_video
from testkit import hostile_images

SPEC = PatchSpec(patch_size=16, block_size=4, position="top-left", offset=(4, 4))
LOW_MEMORY_MB = 300


def _save(path: Path, mode: str, size: tuple[int, int], fmt: str, **opts: object) -> Path:
    rng = np.random.default_rng(0)
    channels = len(mode)
    arr = rng.integers(0, 256, size=(size[1], size[0], channels)).astype(np.uint8)
    Image.fromarray(arr if channels > 1 else arr[..., 0], mode).save(path, fmt, **opts)
    return path


@pytest.mark.parametrize(
    ("name", "mode", "fmt", "opts", "channels", "bps"),
    [
        ("a.jpg", "RGB", "JPEG", {}, 3, 1),
        ("g.jpg", "L", "JPEG", {"progressive": True}, 1, 1),
        ("a.png", "RGBA", "PNG", {}, 4, 1),
        ("l.png", "L", "PNG", {}, 1, 1),
        ("lossy.webp", "RGB", "WEBP", {"quality": 80}, 3, 1),
        ("lossless.webp", "RGBA", "WEBP", {"lossless": True}, 4, 1),
        (
            "x.webp",
            "RGB",
            "WEBP",
            {"lossless": True, "exif": b"Exif\x00\x00II*\x00\x08\x00\x00\x00\x00\x00"},
            4,
            1,
        ),
        ("a.tif", "RGB", "TIFF", {"compression": "tiff_lzw"}, 3, 1),
        ("a.gif", "P", "GIF", {}, 4, 1),
    ],
)
def test_header_sizes_match_the_decoded_image(
    tmp_path: Path, name: str, mode: str, fmt: str, opts: dict[str, object], channels: int, bps: int
) -> None:
    path = _save(tmp_path / name, mode, (173, 91), fmt, **opts)
    size = decoded_size(path)
    assert (size.width, size.height, size.frames) == Image.open(path).size + (1,)
    assert (size.channels, size.bytes_per_sample) == (channels, bps)
    assert decoded_bytes_estimate(path) == 173 * 91 * channels * bps


def test_header_sizes_16bit_png_animated_webp_and_heic(tmp_path: Path) -> None:
    import pillow_heif

    pillow_heif.register_heif_opener()
    Image.fromarray(np.zeros((40, 30), np.uint16)).save(tmp_path / "a16.png")
    assert decoded_bytes_estimate(tmp_path / "a16.png") == 30 * 40 * 2
    frames = [Image.new("RGB", (50, 20), (i * 40, 0, 0)) for i in range(5)]
    frames[0].save(tmp_path / "anim.webp", save_all=True, append_images=frames[1:], lossless=True)
    assert decoded_size(tmp_path / "anim.webp").frames == Image.open(tmp_path / "anim.webp").n_frames == 5
    frames[0].save(tmp_path / "anim.gif", save_all=True, append_images=frames[1:])
    assert decoded_size(tmp_path / "anim.gif").frames == Image.open(tmp_path / "anim.gif").n_frames
    Image.new("RGB", (130, 70)).save(tmp_path / "a.heic", quality=50)
    size = decoded_size(tmp_path / "a.heic")
    assert (size.width, size.height) == (130, 70)


def test_refusal_message_is_one_line_naming_the_file(tmp_path: Path) -> None:
    hostile_images.tiff_huge(tmp_path / "big.tif")
    with pytest.raises(ImageFormatError) as err:
        check_decode_budget(tmp_path / "big.tif")
    assert str(err.value) == (
        f"big.tif: 100000x100000 (10000 MP) is over the {DEFAULT_MAX_PIXELS // 1_000_000} MP limit; "
        "raise [limits] max_megapixels to protect it"
    )
    hostile_images.apng_many_frames(tmp_path / "anim.png")
    with pytest.raises(ImageFormatError, match=r"2000x2000 x 1000 frames \(4000 MP\)"):
        check_decode_budget(tmp_path / "anim.png")


def test_poison_file_max_pixels(tmp_path: Path) -> None:
    src = _save(tmp_path / "a.png", "RGB", (200, 100), "PNG")
    with pytest.raises(ImageFormatError, match=r"200x100 \(0.0 MP\) is over the 0.0 MP limit"):
        poison_file(src, tmp_path / "out.png", SPEC, max_pixels=200 * 100 - 1)
    assert not (tmp_path / "out.png").exists()
    poison_file(src, tmp_path / "out.png", SPEC, max_pixels=200 * 100)  # at the limit: protected
    poison_file(src, tmp_path / "out2.png", SPEC)  # default
    assert DEFAULT_MAX_PIXELS >= 61_000_000  # the largest full-frame camera photos pass by default


def test_webp_gets_a_fifth_of_the_budget(tmp_path: Path) -> None:
    src = _save(tmp_path / "a.webp", "RGB", (200, 100), "WEBP", lossless=True)
    with pytest.raises(ImageFormatError, match=r"over the 0.0 MP limit for WebP \(a fifth of"):
        check_decode_budget(src, max_pixels=200 * 100 * 5 - 1)
    check_decode_budget(src, max_pixels=200 * 100 * 5)


def test_unreadable_header_is_left_to_the_decoder(tmp_path: Path) -> None:
    (tmp_path / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00")
    check_decode_budget(tmp_path / "x.png")  # no refusal here...
    with pytest.raises(ImageFormatError):
        poison_file(tmp_path / "x.png", tmp_path / "o.png", SPEC)  # ...the decoder's one line instead


CHILD = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from poisoner.formats import ImageFormatError, poison_file
    from poisoner.spec import PatchSpec

    def peak_mb():
        # VmHWM, not ru_maxrss: Linux keeps ru_maxrss across exec, so a child forked from a
        # large pytest process would report the parent's size
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) // 1024
        raise RuntimeError("no VmHWM")

    for name in sys.argv[2:]:
        try:
            poison_file(Path(sys.argv[1]) / name, Path(sys.argv[1]) / ("out-" + name), PatchSpec())
            outcome = "PROTECTED"
        except ImageFormatError as exc:
            outcome = str(exc)
        print(f"{peak_mb()}\\t{name}\\t{outcome}", flush=True)
    """
)


def test_hostile_corpus_refused_before_decoding_in_low_memory(tmp_path: Path) -> None:
    corpus = tmp_path / "corpus"
    hostile_images.write_corpus(corpus)
    names = sorted(hostile_images.CORPUS)
    run = subprocess.run(
        [sys.executable, "-c", CHILD, str(corpus), *names],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    rows = [line.split("\t") for line in run.stdout.splitlines()]
    assert [r[1] for r in rows] == names
    for rss, name, outcome in rows:
        assert int(rss) < LOW_MEMORY_MB, (name, rss)
        assert "\n" not in outcome and outcome.startswith(name)
        if name == "text-bomb.png":
            assert "PROTECTED" not in outcome  # Pillow's text limit refuses it; memory stays low
        else:
            assert f"is over the {DEFAULT_MAX_PIXELS // 1_000_000} MP limit" in outcome or (
                name.endswith(".webp") and "MP limit for WebP" in outcome
            ), outcome
    assert not list(corpus.glob("out-*"))


def test_solid_webp_trick_really_decodes_to_the_declared_size(tmp_path: Path) -> None:
    """The corpus's 38-byte WebP is genuine: patched to 1024 it decodes to 1024 x 1024 of one colour."""
    hostile_images.webp_solid_lossless(tmp_path / "w.webp", 1024)
    arr = np.asarray(Image.open(tmp_path / "w.webp"))
    assert arr.shape[:2] == (1024, 1024)
    assert len(np.unique(arr.reshape(-1, arr.shape[-1]), axis=0)) == 1


def test_video_over_the_frame_limit_is_refused(tmp_path: Path) -> None:
    src = tmp_path / "a.mp4"
    with av.open(str(src), "w") as out:
        vs = out.add_stream("libx264", rate=10)
        vs.width, vs.height, vs.pix_fmt = 128, 96, "yuv420p"
        for i in range(3):
            f = av.VideoFrame.from_ndarray(np.full((96, 128, 3), 60 * i, np.uint8), format="rgb24")
            f = f.reformat(format="yuv420p")
            f.pts = i
            for pkt in vs.encode(f):
                out.mux(pkt)
        for pkt in vs.encode(None):
            out.mux(pkt)
    opts = VideoOptions(verify_patch=False, preset="ultrafast")
    with pytest.raises(VideoFormatError, match=r"a.mp4: 128x96 frames .* over the .* video limit"):
        poison_video(src, tmp_path / "o.mp4", SPEC, options=opts, max_pixels=128 * 96 - 1)
    poison_video(src, tmp_path / "o.mp4", SPEC, options=opts)  # default limit: protected


def test_heif_gets_a_third_of_the_budget(tmp_path: Path) -> None:
    import pillow_heif

    pillow_heif.register_heif_opener()
    Image.new("RGB", (200, 100)).save(tmp_path / "a.heic", quality=50)
    with pytest.raises(ImageFormatError, match=r"limit for HEIF/AVIF \(a third of"):
        check_decode_budget(tmp_path / "a.heic", max_pixels=200 * 100 * 3 - 1)
    check_decode_budget(tmp_path / "a.heic", max_pixels=200 * 100 * 3)


# ---- issue 29: memory counted in bytes, headers found wherever they are --------------------------
def _png16(path: Path, w: int, h: int, channels: int = 4) -> Path:
    """A real 16-bit PNG of zeros (Pillow cannot write 16-bit colour)."""
    import struct
    import zlib

    def chunk(t: bytes, b: bytes) -> bytes:
        return struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b))

    raw = (b"\x00" + bytes(w * channels * 2)) * h
    ihdr = struct.pack(">IIBBBBB", w, h, 16, 6 if channels == 4 else 2, 0, 0, 0)
    body = chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + body)
    return path


def test_jpeg_frame_header_after_megabytes_of_segments_is_found(tmp_path: Path) -> None:
    """Before: a SOF after 1.1 MB of COM segments was not looked for (1 MiB read) and the file passed."""
    import io
    import struct

    out = io.BytesIO()
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(out, "JPEG")
    data = out.getvalue()
    comments = b"".join(b"\xff\xfe" + struct.pack(">H", 65535) + bytes(65533) for _ in range(18))  # 1.18 MB
    sof = data.index(b"\xff\xc0")
    big = bytearray(data[:2] + comments + data[2:])
    at = sof + len(comments)
    big[at + 5 : at + 9] = struct.pack(">HH", 30000, 30000)  # declares 30000x30000 (900 MP)
    path = tmp_path / "com.jpg"
    path.write_bytes(bytes(big))
    size = decoded_size(path)
    assert (size.width, size.height) == (30000, 30000)
    with pytest.raises(ImageFormatError, match="900 MP"):
        check_decode_budget(path)


def test_memory_limit_counts_bytes_per_sample_and_working_copies(tmp_path: Path) -> None:
    """Same pixels, 16-bit RGBA needs several times the memory of 8-bit RGB (FFmpeg's codec): a
    byte limit refuses the one and lets the other through; the pixel limit alone let both pass."""
    deep = _png16(tmp_path / "deep.png", 2000, 2000)
    flat = tmp_path / "flat.png"
    Image.new("RGB", (2000, 2000)).save(flat)
    assert decoded_size(deep).bytes == 2000 * 2000 * 4 * 2 and decoded_size(flat).bytes == 2000 * 2000 * 3
    assert decoded_size(deep).peak_bytes > 4 * decoded_size(deep).bytes
    limit = 150_000_000  # 16-bit RGBA: over 60 + 32 x 6.2 = 258 MB; 8-bit RGB: ~60 + 12 x 3.2 = 98 MB
    check_decode_budget(deep, max_bytes=None)  # the pixel limit alone: 4 MP passes
    said = r"deep\.png: 2000x2000 \(16-bit, 4 channel\(s\)\) needs about \d+ MB"
    with pytest.raises(ImageFormatError, match=said):
        check_decode_budget(deep, max_bytes=limit)
    check_decode_budget(flat, max_bytes=limit)


def test_byte_budget_admits_no_more_than_it_holds() -> None:
    import threading
    import time

    from daemon.protect.pool import ByteBudget

    budget = ByteBudget(1000)
    running: list[int] = []
    peak: list[int] = []
    lock = threading.Lock()

    def job(nbytes: int) -> None:
        held = budget.reserve(nbytes)
        with lock:
            running.append(nbytes)
            peak.append(sum(running))
        time.sleep(0.05)
        with lock:
            running.remove(nbytes)
        budget.release(held)

    threads = [threading.Thread(target=job, args=(n,)) for n in (600, 600, 300, 300, 2500, 100)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert not any(t.is_alive() for t in threads)
    assert max(peak) == 2500  # the oversized one ran, alone
    assert all(p <= 1000 for p in peak if p != 2500) and budget.used == 0


def test_a_png_that_deflates_poorly_is_counted_by_its_file_too(tmp_path: Path) -> None:
    """A photo's sensor noise barely deflates, and a PNG's file is held several times while it is
    protected (read, IDAT, written, sealed): issue 30 measured noise-like PNGs at up to 3x the old
    estimate, which counted the decoded pixels alone. Same pixels, a file 100x larger: more memory."""
    rng = np.random.default_rng(0)
    noisy, flat = tmp_path / "noisy.png", tmp_path / "flat.png"
    Image.fromarray(rng.integers(0, 256, (800, 1200, 3), dtype=np.uint8)).save(noisy, compress_level=1)
    Image.new("RGB", (1200, 800), (90, 120, 150)).save(flat)
    a, b = decoded_size(noisy), decoded_size(flat)
    assert a.bytes == b.bytes and a.file_bytes > 100 * b.file_bytes
    assert a.file_bytes == noisy.stat().st_size
    assert a.peak_bytes - b.peak_bytes >= 4 * (a.file_bytes - b.file_bytes)


def test_lossy_webp_is_told_from_lossless(tmp_path: Path) -> None:
    """libwebp's lossy encoder holds memory by the file's size, its lossless one by the picture's
    (docs/FORMATS.md "Memory"): the header says which, plain (VP8 ) or extended (VP8X + VP8)."""
    exif = b"Exif\x00\x00II*\x00\x08\x00\x00\x00\x00\x00"
    plain = _save(tmp_path / "plain.webp", "RGB", (64, 48), "WEBP", quality=80)
    extended = _save(tmp_path / "ext.webp", "RGB", (64, 48), "WEBP", quality=80, exif=exif)
    lossless = _save(tmp_path / "ll.webp", "RGB", (64, 48), "WEBP", lossless=True, exif=exif)
    assert plain.read_bytes()[12:16] == b"VP8 " and extended.read_bytes()[12:16] == b"VP8X"
    assert decoded_size(plain).lossy and decoded_size(extended).lossy
    assert not decoded_size(lossless).lossy
    ext = decoded_size(extended)
    assert (ext.width, ext.height, ext.frames) == (64, 48, 1)


PEAK_CHILD = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from poisoner.formats import poison_file
    from poisoner.ladder import default_spec
    from poisoner.limits import decoded_size

    src = Path(sys.argv[1])
    estimate = decoded_size(src).peak_bytes
    poison_file(src, src.with_name("out" + src.suffix), default_spec(), max_pixels=10**12)
    hwm = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM:"))
    print(hwm * 1024, estimate)
    """
)


@pytest.mark.parametrize(("fmt", "suffix", "mp"), [("WEBP", ".webp", 5.0), ("HEIF", ".heic", 3.0)])
def test_noise_like_photos_stay_within_the_estimate(tmp_path: Path, fmt: str, suffix: str, mp: float) -> None:
    """The estimate the daemon admits files by and `ppd poison` refuses by must cover what protecting
    a file takes: measured in a fresh child (VmHWM) on the worst case, pixels the codec cannot shrink
    (a photo's sensor noise), ppd's own mark. Lossy WebP took 1.12x and HEIF 1.2x their old estimates."""
    opts: dict[str, object] = {"quality": 90}
    if fmt == "HEIF":
        import pillow_heif

        pillow_heif.register_heif_opener()
    w = int((mp * 1e6 * 4 / 3) ** 0.5) // 16 * 16
    src = _save(tmp_path / f"noise{suffix}", "RGB", (w, int(mp * 1e6 / w) // 16 * 16), fmt, **opts)
    run = subprocess.run([sys.executable, "-c", PEAK_CHILD, str(src)], capture_output=True, text=True,
                         timeout=300, cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    peak, estimate = map(int, run.stdout.split())
    assert peak <= estimate, f"{fmt}: peak {peak / 1e6:.0f} MB over the estimate {estimate / 1e6:.0f} MB"


def test_a_ten_bit_heic_is_budgeted_at_two_bytes_a_sample(tmp_path: Path) -> None:
    """ppd decodes a 10-bit HEIC at 16 bits to keep its depth (tests/poisoner/test_format_review.py): the
    memory budget read it as 8-bit, half what protecting it takes (found in the formats review)."""
    pillow_heif = pytest.importorskip("pillow_heif")
    from poisoner.limits import decoded_size

    deep = np.random.default_rng(0).integers(0, 65535, (120, 160, 3)).astype(np.uint16)
    pillow_heif.from_bytes(mode="RGB;16", size=(160, 120), data=deep.tobytes()).save(tmp_path / "x10.heic")
    shallow = (deep >> 8).astype(np.uint8)
    pillow_heif.from_bytes(mode="RGB", size=(160, 120), data=shallow.tobytes()).save(tmp_path / "x8.heic")
    ten, eight = decoded_size(tmp_path / "x10.heic"), decoded_size(tmp_path / "x8.heic")
    assert (ten.format, ten.bytes_per_sample, eight.bytes_per_sample) == ("HEIF", 2, 1)
    assert ten.peak_bytes > eight.peak_bytes  # the per-pixel part twice (a fixed part beside it)
