"""JPEG, faithfully: put the patch in while changing as little of the file as possible.

Four ways, best first:

-1. The bit-level splice (poisoner/jpeg_scan.py, its C module poisoner/_jpeg_entropy.c): one
   Huffman decode of the picture indexes every MCU; the patched MCUs are coded with the source's
   own tables and every other MCU's bits are copied as they are. The same coefficients and, for a
   source with libjpeg's standard tables, the same entropy-coded bytes as 0.; the source's header
   bytes are kept as they are. Baseline files without restart markers only; the rest take 0.

0. The same splice in one in-process pass (`patch_in_one_pass`, poisoner/jpeg_turbo.py): one
   libturbojpeg `tjTransform` call reads every coefficient once, writes the lossless crop of the
   box + ring that Pillow decodes, and writes the whole picture once with the box's blocks (the
   patched box encoded as in 1.) swapped in by a coefficient callback. Same bytes as 1., about a
   third of its CPU (no child processes, one entropy decode instead of two). libjpeg-turbo's
   TurboJPEG API catches libjpeg errors itself (setjmp), and any warning on corrupt or truncated
   data refuses the file, as jpegtran's do. Sources it cannot write as their source is written
   (restart markers, optimised baseline Huffman tables, arithmetic coding: `turbo_refusal`) and
   machines without libturbojpeg take 1.

1. DCT-coefficient splice (`splice_patch`). Only the MCUs (minimum coded units, 8x8 to 16x16
   pixels) that the patch touches are re-encoded; every other quantised DCT coefficient is
   copied verbatim, so outside the patch's MCU-aligned box the file holds the very same
   coefficients as the original. The patched MCU box is encoded on its own with the source's
   quantisation tables and chroma subsampling, then dropped into the source by libjpeg-turbo's
   `jpegtran -drop +X+Y` (lossless transform; `-copy all` keeps every marker: EXIF, ICC, XMP,
   IPTC, comments).

   Only the patch's MCUs are decoded to pixels (`decode_box`): `jpegtran -crop` cuts the MCU box
   grown by one MCU out of the file losslessly and Pillow decodes that small crop; the ring makes
   the box's pixels equal to a whole-picture decode's, so the output is byte-identical to the
   whole-decode path. Per 12 MP file that is two entropy passes in jpegtran (crop: read every
   coefficient; drop: read and write them) instead of a full pixel decode plus the drop. A source
   coded with libjpeg's standard Huffman tables keeps them (no `-optimize` pass); other sources
   are re-optimised. bench/results/batch.md has the measurements.

   Why jpegtran: it is libjpeg-turbo's own, long-maintained lossless-transform tool (Debian's
   `libjpeg-turbo-progs`), it does exactly this operation, it handles baseline, progressive,
   arithmetic and restart-marker files, and it runs in a child process, so a malformed file
   cannot crash the daemon. The alternatives were weaker: a PyPI DCT library (`jpeglib`) would
   be a second, bundled libjpeg with its own marker handling to audit; a ctypes binding of
   libjpeg's structs is ABI-fragile (struct layouts differ between libjpeg 6b/8/9/turbo).

2. Same-tables re-encode (`encode_like`), when neither splice can be done: the
   whole picture is re-encoded with the source's quantisation tables and subsampling (never a
   blanket quality), progressive and restart settings, and its metadata segments. One such
   re-encode is a second generation of JPEG loss over the whole picture (measured in
   docs/FORMATS.md); the caller records a note.

Pixels the patch must not touch (a subject mask, `keep_mcus`): their MCUs inside the box keep the
source's coefficients on ways 0 and 1 (1. puts them back into the drop file in-process, with
libturbojpeg; without it they are re-encoded from their own, unpatched pixels).

A decoder detail worth knowing: libjpeg's "fancy" chroma upsampling interpolates between
neighbouring chroma samples, so a decoded pixel in the MCU row/column right next to the box
can still move by a level or two even though its coefficients are identical.
"""

from __future__ import annotations

import io
import logging
import os
import shutil
import struct
import subprocess
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, JpegImagePlugin

from poisoner.jpeg_parts import box_block_shapes, crop_box, mcu_box, parts_cover, rows_taking_blocks

log = logging.getLogger(__name__)

JPEGTRAN_ENV = "PPD_JPEGTRAN"  # override the jpegtran binary (or "" to disable the splice, in-process too)
JPEGTRAN_TIMEOUT_S = 120
# A source coded with the standard Huffman tables keeps them (no -optimize pass; keeps_standard_huffman).
STANDARD_HUFFMAN_AS_SOURCE = True

_SOF_MARKERS = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_PROGRESSIVE_SOF = {0xC2, 0xC6, 0xCA, 0xCE}
_ARITHMETIC_SOF = {0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_LOSSLESS_SOF = {0xC3, 0xC7, 0xCB, 0xCF}


class SpliceUnavailable(Exception):
    """The coefficient splice cannot be done for this file (the caller falls back)."""


@dataclass(frozen=True)
class Segment:
    marker: int  # 0xE0..0xEF for APPn, 0xFE for COM
    payload: bytes

    def raw(self) -> bytes:
        return bytes((0xFF, self.marker)) + struct.pack(">H", len(self.payload) + 2) + self.payload


@dataclass(frozen=True)
class JpegLayout:
    """What the file header says about how the picture is coded."""

    width: int
    height: int
    sof: int
    components: int
    sampling: tuple[tuple[int, int], ...]  # (h, v) per component
    restart_interval: int  # in MCUs, 0 = none
    segments: tuple[Segment, ...] = field(default=())
    huffman: tuple[bytes, ...] = field(default=())  # each DHT table: class/id byte, 16 counts, values

    @property
    def progressive(self) -> bool:
        return self.sof in _PROGRESSIVE_SOF

    @property
    def arithmetic(self) -> bool:
        return self.sof in _ARITHMETIC_SOF

    @property
    def lossless(self) -> bool:
        return self.sof in _LOSSLESS_SOF

    @property
    def mcu_size(self) -> tuple[int, int]:
        """(width, height) of one MCU in pixels: 8 x the largest sampling factors."""
        if self.components == 1:
            return (8, 8)  # a single-component scan is not interleaved: 8x8 blocks
        return (8 * max(h for h, _ in self.sampling), 8 * max(v for _, v in self.sampling))


def read_layout(data: bytes) -> JpegLayout:
    """Scan the markers up to the first SOS. Raises ValueError on a malformed header."""
    if data[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG (no SOI marker)")
    pos = 2
    segments: list[Segment] = []
    sof: int | None = None
    width = height = components = 0
    sampling: tuple[tuple[int, int], ...] = ()
    restart = 0
    huffman: list[bytes] = []
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            raise ValueError(f"JPEG marker expected at byte {pos}")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker == 0xDA or marker == 0xD9:  # SOS / EOI: header done
            break
        (length,) = struct.unpack(">H", data[pos + 2 : pos + 4])
        payload = data[pos + 4 : pos + 2 + length]
        if len(payload) != length - 2:
            raise ValueError("JPEG header truncated")
        if 0xE0 <= marker <= 0xEF or marker == 0xFE:
            segments.append(Segment(marker, payload))
        elif marker in _SOF_MARKERS:
            sof = marker
            # a damaged file: one line, not an IndexError
            if len(payload) < 6 or len(payload) < 6 + 3 * payload[5]:
                raise ValueError("JPEG frame header (SOF) truncated")
            height, width = struct.unpack(">HH", payload[1:5])
            components = payload[5]
            sampling = tuple(
                (payload[6 + 3 * i + 1] >> 4, payload[6 + 3 * i + 1] & 0x0F) for i in range(components)
            )
        elif marker == 0xDD:
            if len(payload) < 2:
                raise ValueError("JPEG restart interval (DRI) truncated")
            (restart,) = struct.unpack(">H", payload[:2])
        elif marker == 0xC4:
            huffman += _dht_tables(payload)
        pos += 2 + length
    if sof is None:
        raise ValueError("JPEG has no frame header (SOF)")
    return JpegLayout(width, height, sof, components, sampling, restart, tuple(segments), tuple(huffman))


def _dht_tables(payload: bytes) -> list[bytes]:
    """The Huffman tables of one DHT segment (it may define several)."""
    tables = []
    i = 0
    while i + 17 <= len(payload):
        end = i + 17 + sum(payload[i + 1 : i + 17])
        if end > len(payload):
            raise ValueError("DHT segment truncated")
        tables.append(payload[i:end])
        i = end
    return tables


_standard_tables: frozenset[bytes] | None = None


def standard_huffman_tables() -> frozenset[bytes]:
    """libjpeg's standard Huffman tables (JPEG Annex K.3), as its encoder writes them when not
    optimising: taken from a tiny Pillow-encoded file, so they are the very bytes libjpeg uses."""
    global _standard_tables
    if _standard_tables is None:
        buf = io.BytesIO()
        Image.new("RGB", (8, 8)).save(buf, "JPEG")
        _standard_tables = frozenset(read_layout(buf.getvalue()).huffman)
    return _standard_tables


def keeps_standard_huffman(layout: JpegLayout) -> bool:
    """True when the file is coded with libjpeg's standard Huffman tables only (most cameras and
    every unoptimised libjpeg/Pillow save): jpegtran then writes the output with those same
    tables, one pass over the coefficients, and `-optimize` (a second, statistics pass: 37 ms of
    104 on a 12 MP file, measured) is left out, so the output is coded like its source. Optimised
    or custom tables, progressive and arithmetic files are re-optimised as before."""
    if layout.progressive or layout.arithmetic or not layout.huffman:
        return False
    return set(layout.huffman) <= standard_huffman_tables()


# ---- same-tables encoding ------------------------------------------------------------------
# Segments Pillow writes itself from explicit arguments (or regenerates): everything else is
# passed through verbatim as `extra` (FlashPix FPXR too: previews.jpeg_previews drops it from every path's).
def _is_pillow_managed(seg: Segment) -> bool:
    p = seg.payload
    if seg.marker == 0xE0:  # JFIF / JFXX: Pillow writes its own JFIF with the dpi
        return True
    if seg.marker == 0xE1 and (
        p.startswith(b"Exif\x00\x00") or p.startswith(b"http://ns.adobe.com/xap/1.0/\x00")
    ):
        return True
    if seg.marker == 0xE2 and (p.startswith(b"ICC_PROFILE\x00") or p.startswith(b"MPF\x00")):
        return True  # ICC: via icc_profile; MPF: its offsets point at images we do not write
    return seg.marker in (0xEE, 0xFE)  # Adobe (libjpeg writes it when needed); COM: via comment


def table_options(src: Image.Image) -> dict[str, object]:
    """Encoder options that reproduce the source's quantisation and chroma subsampling."""
    if not isinstance(src, JpegImagePlugin.JpegImageFile):
        raise TypeError("table_options needs a JPEG image")
    opts: dict[str, object] = {"qtables": src.quantization}
    sampling = JpegImagePlugin.get_sampling(src)
    if sampling != -1:
        opts["subsampling"] = sampling
    return opts


def encode_like(pixels: np.ndarray, src: Image.Image, layout: JpegLayout, *, metadata: bool = True) -> bytes:
    """Encode pixels (H x W x 3 or H x W, uint8) like the source JPEG: same tables, same
    subsampling, progressive/restart settings and (with metadata=True) every metadata
    segment of the source."""
    mode = "L" if pixels.ndim == 2 else "RGB"
    out = Image.fromarray(pixels, mode)
    opts: dict[str, object] = table_options(src)
    if metadata:
        info = src.info
        opts.update(
            progressive=layout.progressive,
            optimize=True,  # Huffman tables only: lossless, smaller
            exif=info.get("exif", b""),
            icc_profile=info.get("icc_profile"),
            comment=info.get("comment"),
            extra=b"".join(s.raw() for s in layout.segments if not _is_pillow_managed(s)),
        )
        if info.get("xmp"):
            opts["xmp"] = info["xmp"]
        if "dpi" in info:
            opts["dpi"] = info["dpi"]
        if layout.restart_interval:
            opts["restart_marker_blocks"] = layout.restart_interval
    buf = io.BytesIO()
    out.save(buf, "JPEG", **opts)
    return buf.getvalue()


# ---- coefficient splice --------------------------------------------------------------------
def jpegtran_binary() -> str | None:
    override = os.environ.get(JPEGTRAN_ENV)
    if override is not None:
        return override or None
    return shutil.which("jpegtran")


def _check_splice_layout(src: Image.Image, layout: JpegLayout) -> str:
    binary = jpegtran_binary()
    if binary is None:
        raise SpliceUnavailable("jpegtran not found (install libjpeg-turbo-progs)")
    if layout.lossless:
        raise SpliceUnavailable("lossless JPEG")
    if src.mode not in ("RGB", "L") or layout.components not in (1, 3):
        raise SpliceUnavailable(f"{src.mode} JPEG with {layout.components} components")
    if (why := sampling_refusal(src, layout)) is not None:
        raise SpliceUnavailable(why)
    return binary


def sampling_refusal(src: Image.Image, layout: JpegLayout) -> str | None:
    """Why the patched blocks cannot be coded with the source's chroma sampling, or None. They are
    encoded by Pillow (encode_like), which writes 4:4:4, 4:2:2 and 4:2:0 only: a 4:1:1 source's
    patched MCUs came out 4:2:0 and were laid into 4:1:1 block rows, wrong colours in the mark's box
    (found testing an installed wheel, issue 30 round 10). Such a file is re-encoded whole."""
    if layout.components != 3:
        return None
    if any(s != (1, 1) for s in layout.sampling[1:]) or JpegImagePlugin.get_sampling(src) == -1:
        return f"chroma sampling {layout.sampling} that Pillow cannot write"
    return None


def _jpegtran(cmd: list[str], src_path: Path, op: str, stdin: bytes | None = None) -> bytes:
    """Run jpegtran writing to stdout; any warning (exit 2: corrupt or truncated data) or error
    raises SpliceUnavailable, so the caller's full decode gives the verdict."""
    try:
        run = subprocess.run(cmd, input=stdin, capture_output=True, timeout=JPEGTRAN_TIMEOUT_S, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SpliceUnavailable(f"jpegtran failed to run: {exc}") from exc
    if run.returncode != 0 or not run.stdout:
        msg = run.stderr.decode(errors="replace").strip().splitlines()
        raise SpliceUnavailable(f"jpegtran {op} refused: {msg[-1] if msg else run.returncode}")
    if run.stderr:
        log.info("jpegtran warning", extra={"path": str(src_path), "stderr": run.stderr[-200:]})
    return run.stdout


def decode_box(
    src_path: Path, src: Image.Image, layout: JpegLayout, box: tuple[int, int, int, int]
) -> np.ndarray:
    """The decoded pixels of the MCU-aligned `box`, without decoding the rest of the picture:
    `jpegtran -crop` losslessly cuts crop_box(box) out (its coefficients copied, entropy
    decoding only), Pillow decodes that small file. Equal to np.asarray(full decode)[box]
    (tests/poisoner/test_jpeg_region.py). Raises SpliceUnavailable (the caller decodes everything)."""
    binary = _check_splice_layout(src, layout)
    if box != mcu_box(box, layout):
        raise ValueError(f"box {box} is not MCU-aligned")
    cx0, cy0, cx1, cy1 = crop_box(box, layout)
    cmd = [binary, "-copy", "none", "-crop", f"{cx1 - cx0}x{cy1 - cy0}+{cx0}+{cy0}", str(src_path)]
    cropped = Image.open(io.BytesIO(_jpegtran(cmd, src_path, "-crop")))
    if cropped.size != (cx1 - cx0, cy1 - cy0) or cropped.mode != src.mode:
        raise SpliceUnavailable(f"jpegtran crop gave {cropped.mode} {cropped.size}")
    x0, y0, x1, y1 = box
    try:
        return np.asarray(cropped.crop((x0 - cx0, y0 - cy0, x1 - cx0, y1 - cy0)))
    except OSError as exc:  # a crop jpegtran wrote but Pillow cannot read: decode everything
        raise SpliceUnavailable(f"cropped box unreadable: {exc}") from exc


def splice_patch(
    src_path: Path,
    src: Image.Image,
    layout: JpegLayout,
    patched_box: np.ndarray,
    box: tuple[int, int, int, int],
    keep_mcus: np.ndarray | None = None,
) -> bytes:
    """Return the source JPEG with only the MCUs in `box` (MCU-aligned, see mcu_box) replaced
    by `patched_box` (its pixels, already patched). keep_mcus (the box's MCU rows x columns, True =
    keep): those MCUs keep the source's coefficients where libturbojpeg is there
    (`keep_source_mcus`), else they are re-encoded from their own pixels. Raises SpliceUnavailable
    when it cannot be done for this file."""
    binary = _check_splice_layout(src, layout)
    if box != mcu_box(box, layout):
        raise ValueError(f"box {box} is not MCU-aligned")
    x0, y0 = box[0], box[1]
    drop_bytes = encode_like(np.ascontiguousarray(patched_box), src, layout, metadata=False)
    if keep_mcus is not None and turbo_available() is None:
        drop_bytes = keep_source_mcus(drop_bytes, src_path.read_bytes(), layout, box, keep_mcus)
    cmd = [binary, "-copy", "all"]
    if not (STANDARD_HUFFMAN_AS_SOURCE and keeps_standard_huffman(layout)):
        cmd.append("-optimize")
    if layout.progressive:
        cmd.append("-progressive")
    if layout.restart_interval:
        cmd += ["-restart", f"{layout.restart_interval}B"]
    if layout.arithmetic:
        cmd.append("-arithmetic")
    # The drop file comes through a pipe and the result through stdout: no temporary files.
    cmd += ["-drop", f"+{x0}+{y0}", "/dev/stdin", str(src_path)]
    data = _jpegtran(cmd, src_path, "-drop", stdin=drop_bytes)
    check = read_layout(data)
    if (check.width, check.height, check.components) != (layout.width, layout.height, layout.components):
        raise SpliceUnavailable("jpegtran output has a different frame")
    return data


# ---- one in-process coefficient pass (libturbojpeg) ----------------------------------------
def turbo_refusal(src: Image.Image, layout: JpegLayout) -> str | None:
    """Why the in-process pass cannot write this file like the jpegtran path would, or None.
    tjTransform (TurboJPEG 2.x) writes standard Huffman tables for a baseline file (progressive
    output is always optimised) and offers no restart interval and no arithmetic coding."""
    if layout.lossless or layout.arithmetic:
        return "lossless or arithmetic-coded JPEG"
    if src.mode not in ("RGB", "L") or layout.components not in (1, 3):
        return f"{src.mode} JPEG with {layout.components} components"
    if (why := sampling_refusal(src, layout)) is not None:
        return why
    if layout.restart_interval:
        return "restart markers (tjTransform cannot write them)"
    if not layout.progressive and not (STANDARD_HUFFMAN_AS_SOURCE and keeps_standard_huffman(layout)):
        return "optimised Huffman tables (tjTransform cannot re-optimise a baseline file)"
    return None


def _component_offsets(layout: JpegLayout, box: tuple[int, int, int, int]) -> list[tuple[int, int]]:
    """(block column, block row) of the box's top-left block in each component."""
    if layout.components == 1:
        return [(box[0] // 8, box[1] // 8)]
    mw, mh = layout.mcu_size
    return [(box[0] // mw * h, box[1] // mh * v) for h, v in layout.sampling]


def _component_rows(layout: JpegLayout, box: tuple[int, int, int, int]) -> list[int]:
    """How many block rows the box spans in each component (a partial block at the bottom edge
    counts)."""
    if layout.components == 1:
        return [-(-(box[3] - box[1]) // 8)]
    mh = layout.mcu_size[1]
    return [-(-(box[3] - box[1]) * v // mh) for _, v in layout.sampling]


def _patched_blocks(
    crops: list[bytes],
    src: Image.Image,
    layout: JpegLayout,
    box: tuple[int, int, int, int],
    parts: Sequence[tuple[int, int, int, int]],
    patch: Callable[[np.ndarray, tuple[int, int, int, int]], np.ndarray],
) -> list[np.ndarray]:
    """The DCT blocks of the patched MCU box, coded as the jpegtran path codes its drop file: each
    part's crop (part + one MCU ring) decoded by Pillow, the part cut out and patched, encoded with
    the source's tables and sampling, its coefficients read back and put at the part's place in the
    box. A block's coefficients depend on its own MCU's pixels only (colour conversion per pixel,
    downsampling inside the MCU from its even column, DCT and quantisation per block), and every part
    starts on an MCU edge and ends on one or on the box's, so a part encoded alone gives the very
    blocks the whole box encoded gives there; blocks in no part are left zero (the caller keeps the
    source's there: parts_cover)."""
    from poisoner import jpeg_turbo

    whole = None
    if len(parts) > 1 or parts[0] != box:
        whole = [np.zeros((*shape, 64), dtype=np.int16) for shape in box_block_shapes(layout, box)]
    mw, mh = layout.mcu_size
    factors = [(1, 1)] if layout.components == 1 else list(layout.sampling)
    for crop_jpeg, part in zip(crops, parts, strict=True):
        cropped = Image.open(io.BytesIO(crop_jpeg))
        cx0, cy0, cx1, cy1 = crop_box(part, layout)
        if cropped.size != (cx1 - cx0, cy1 - cy0) or cropped.mode != src.mode:
            raise SpliceUnavailable(f"in-process crop gave {cropped.mode} {cropped.size}")
        x0, y0, x1, y1 = part
        pixels = np.asarray(cropped.crop((x0 - cx0, y0 - cy0, x1 - cx0, y1 - cy0)))
        drop = encode_like(np.ascontiguousarray(patch(pixels, part)), src, layout, metadata=False)
        blocks = jpeg_turbo.read_blocks(drop)
        if whole is None:
            return blocks
        for target, got, (f, v) in zip(whole, blocks, factors, strict=True):
            r0, c0 = (y0 - box[1]) // mh * v, (x0 - box[0]) // mw * f
            rows, cols = min(got.shape[0], target.shape[0] - r0), min(got.shape[1], target.shape[1] - c0)
            target[r0 : r0 + rows, c0 : c0 + cols] = got[:rows, :cols]
    assert whole is not None
    return whole


def patch_in_one_pass(
    data: bytes,
    src: Image.Image,
    layout: JpegLayout,
    box: tuple[int, int, int, int],
    patch: Callable[..., np.ndarray],
    keep_mcus: np.ndarray | None = None,
    parts: Sequence[tuple[int, int, int, int]] | None = None,
) -> bytes:
    """The source JPEG (its bytes: data) with only the MCUs of the MCU-aligned `box` replaced by
    patch(box pixels), in one libturbojpeg call: the coefficients are entropy-decoded once, a
    lossless crop of the box + one MCU ring is written (small) and decoded by Pillow, and the
    whole picture is written once with the box's blocks swapped in; every other block, every
    marker segment and the quantisation tables are copied. Same bytes as the jpegtran path
    (tests/poisoner/test_jpeg_turbo.py). keep_mcus (the box's MCU rows x MCU columns, True = keep): those
    MCUs keep the source's blocks too (pixels the patch must not touch, e.g. a subject mask; the
    jpegtran path gets them back with keep_source_mcus). parts (MCU-aligned boxes inside box that
    hold every MCU not in keep_mcus, e.g. one per square of a mark placed apart): each part is
    decoded, patched (patch(pixels, part)) and encoded alone, the same blocks as the whole box's at
    a fraction of its pixels; without parts patch(box pixels). Raises SpliceUnavailable when it
    cannot be done here."""
    from poisoner import jpeg_turbo

    reason = turbo_available() or turbo_refusal(src, layout)
    if reason is not None:
        raise SpliceUnavailable(reason)
    if box != mcu_box(box, layout):
        raise ValueError(f"box {box} is not MCU-aligned")
    patch_part = patch
    if parts is None:
        parts, patch_part = [box], lambda pixels, _part: patch(pixels)
    elif not parts_cover(layout, box, parts, keep_mcus):  # some MCU would be left unpatched: whole box
        parts = [box]
    outputs = jpeg_turbo.Outputs(len(parts) + 1)
    offsets = _component_offsets(layout, box)
    new_blocks: list[np.ndarray] = []

    wanted = [range(r0, r0 + n) for (_, r0), n in zip(offsets, _component_rows(layout, box), strict=True)]
    take: list[np.ndarray] = []

    def swap_in(row: int, blocks: np.ndarray, component: int, _index: int) -> None:
        if not new_blocks:  # first box row of the whole-picture transform: the crop is written by now
            crops = [outputs.finished(i) for i in range(len(parts))]
            new_blocks.extend(_patched_blocks(crops, src, layout, box, parts, patch_part))
            take.extend(_blocks_to_take(layout, keep_mcus, [b.shape[:2] for b in new_blocks]))
        col0, row0 = offsets[component]
        replacement = new_blocks[component]
        # The drop file's last MCU row may hold padding block rows (read_blocks keeps them): unused.
        if replacement.shape[0] < len(wanted[component]):
            raise SpliceUnavailable(
                f"patched box has {replacement.shape[0]} block rows in component {component}"
            )
        row_take = take[component][row - row0]
        blocks[col0 : col0 + replacement.shape[1]][row_take] = replacement[row - row0][row_take]

    specs: list[tuple[jpeg_turbo.TjTransform, object]] = [
        (jpeg_turbo.crop_spec(crop_box(part, layout)), None) for part in parts
    ]
    # Rows whose blocks all stay the source's (between two squares placed apart) are not even handed
    # to Python: the callback returns at once there.
    needed = wanted if keep_mcus is None else rows_taking_blocks(layout, keep_mcus, wanted)
    specs.append(jpeg_turbo.filter_spec(swap_in, wanted=lambda c: needed[c], progressive=layout.progressive))
    try:
        out = jpeg_turbo.transform(data, specs, outputs)[-1]
    except jpeg_turbo.TurboUnavailable as exc:
        raise SpliceUnavailable(str(exc)) from exc
    check = read_layout(out)
    if (check.width, check.height, check.components) != (layout.width, layout.height, layout.components):
        raise SpliceUnavailable("libturbojpeg output has a different frame")
    return out


def _blocks_to_take(
    layout: JpegLayout, keep_mcus: np.ndarray | None, shapes: list[tuple[int, ...]]
) -> list[np.ndarray]:
    """Per component, which of the patched box's blocks (rows x columns, `shapes`) replace the
    source's: all, except the blocks of MCUs in keep_mcus."""
    if keep_mcus is None:
        return [np.ones(shape[:2], dtype=bool) for shape in shapes]
    factors = [(1, 1)] if layout.components == 1 else list(layout.sampling)
    out = []
    for (h, v), shape in zip(factors, shapes, strict=True):
        per_block = np.repeat(np.repeat(~keep_mcus, v, axis=0), h, axis=1)
        take = np.ones(shape[:2], dtype=bool)  # padding blocks beyond the box: as before
        rows, cols = min(shape[0], per_block.shape[0]), min(shape[1], per_block.shape[1])
        take[:rows, :cols] = per_block[:rows, :cols]
        out.append(take)
    return out


def keep_source_mcus(
    drop: bytes, data: bytes, layout: JpegLayout, box: tuple[int, int, int, int], keep_mcus: np.ndarray
) -> bytes:
    """The drop file (the patched box, encoded with the source's tables) with the MCUs in keep_mcus
    holding the source's own coefficients (a lossless crop of the box, read in-process), so
    jpegtran's drop leaves them exactly as they were. Raises SpliceUnavailable."""
    from poisoner import jpeg_turbo

    try:
        source = jpeg_turbo.read_blocks(jpeg_turbo.transform(data, [(jpeg_turbo.crop_spec(box), None)])[0])
        patched = [b.shape[:2] for b in jpeg_turbo.read_blocks(drop)]
        if patched != [b.shape[:2] for b in source]:
            raise SpliceUnavailable(f"source crop has blocks {[b.shape[:2] for b in source]}, drop {patched}")
        take = _blocks_to_take(layout, keep_mcus, patched)

        def restore(row: int, blocks: np.ndarray, component: int, _index: int) -> None:
            keep = ~take[component][row]
            blocks[keep] = source[component][row][keep]

        return jpeg_turbo.transform(drop, [jpeg_turbo.filter_spec(restore, copy_markers=False)])[0]
    except jpeg_turbo.TurboUnavailable as exc:
        raise SpliceUnavailable(f"cannot keep the source's blocks: {exc}") from exc


def turbo_available() -> str | None:
    """None when the in-process pass can run here, else why not (logged by the caller).
    PPD_JPEGTRAN="" turns the coefficient splice off whichever way it is done; PPD_TURBOJPEG=""
    only the in-process pass (jpegtran then does it)."""
    from poisoner import jpeg_turbo

    if os.environ.get(JPEGTRAN_ENV) == "":
        return f"{JPEGTRAN_ENV} is empty: coefficient splice off"

    try:
        jpeg_turbo.library()
    except jpeg_turbo.TurboUnavailable as exc:
        return str(exc)
    return None


def splice_available() -> bool:
    """Whether a JPEG can be patched without decoding the whole picture: the bit-level path
    (poisoner/jpeg_scan.py), the in-process pass or jpegtran is there."""
    from poisoner import jpeg_scan

    return jpeg_scan.available() is None or turbo_available() is None or jpegtran_binary() is not None
