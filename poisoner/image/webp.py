"""WebP: lossless stays lossless (exact, RGB under transparent pixels kept); lossy is re-encoded
at the quality estimated from the source's VP8 quantiser (read with a minimal VP8 header
decoder). EXIF, ICC and XMP are kept, location removed unless kept."""

from __future__ import annotations

import io
import struct

import numpy as np
from PIL import Image

from poisoner.image.metadata import metadata_options
from poisoner.image.write import paste_patch, save_explicit
from poisoner.provenance import Marker
from poisoner.spec import PatchPlacement


def _riff_chunks(data: bytes) -> dict[bytes, bytes]:
    chunks: dict[bytes, bytes] = {}
    pos = 12
    while pos + 8 <= len(data):
        ctype = data[pos : pos + 4]
        (size,) = struct.unpack("<I", data[pos + 4 : pos + 8])
        chunks.setdefault(ctype, data[pos + 8 : pos + 8 + size])
        pos += 8 + size + (size & 1)
    return chunks


class _BoolDecoder:
    """VP8's boolean entropy decoder (RFC 6386, section 7), just enough to read the frame header."""

    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 2
        self.value = (data[0] << 8) | data[1]
        self.range, self.bit_count = 255, 0

    def bool(self, prob: int = 128) -> int:
        split = 1 + (((self.range - 1) * prob) >> 8)
        big_split = split << 8
        if self.value >= big_split:
            bit, self.range, self.value = 1, self.range - split, self.value - big_split
        else:
            bit, self.range = 0, split
        while self.range < 128:
            self.value <<= 1
            self.range <<= 1
            self.bit_count += 1
            if self.bit_count == 8:
                self.bit_count = 0
                if self.pos < len(self.data):
                    self.value |= self.data[self.pos]
                    self.pos += 1
        return bit

    def literal(self, bits: int) -> int:
        v = 0
        for _ in range(bits):
            v = (v << 1) | self.bool()
        return v

    def signed(self, bits: int) -> int:
        v = self.literal(bits)
        return -v if self.bool() else v


def vp8_quantizers(vp8: bytes) -> list[int]:
    """The luma AC quantiser index (0..127) of each segment of a VP8 key frame."""
    if len(vp8) < 12 or vp8[3:6] != b"\x9d\x01\x2a" or vp8[0] & 1:
        raise ValueError("not a VP8 key frame")
    d = _BoolDecoder(vp8[10:])
    d.literal(2)  # colour space, clamping
    segment_quant: list[int] | None = None
    absolute = False
    if d.bool():  # segmentation enabled
        update_map = d.bool()
        if d.bool():  # update segment feature data
            absolute = bool(d.bool())
            segment_quant = [d.signed(7) if d.bool() else 0 for _ in range(4)]
            for _ in range(4):
                if d.bool():
                    d.signed(6)
        if update_map:
            for _ in range(3):
                if d.bool():
                    d.literal(8)
    d.literal(1 + 6 + 3)  # filter type, level, sharpness
    if d.bool() and d.bool():  # loop-filter deltas enabled and updated
        for _ in range(8):
            if d.bool():
                d.signed(6)
    d.literal(2)  # partitions
    base = d.literal(7)
    if segment_quant is None:
        return [base]
    return [q if absolute else max(0, min(127, base + q)) for q in segment_quant]


# libwebp spreads its segments' quantisers around the quality's with spatial noise shaping
# (src/enc/quant_enc.c, VP8SetSegmentParams): segment i's compression is c ** (1 - amp * alpha_i), amp =
# 0.9 * sns_strength / 100 / 128 (sns_strength 50 by default: cwebp, Pillow, browsers), alpha_i in
# [-127, 127], and the segment farthest from the weighted mean is clipped to the end of that range. On
# photos that is the coarsest segment (alpha -127): its quantiser gives the quality back exactly.
SNS_COARSEST_EXPONENT = 1.0 + 0.9 * 50 / 100 / 128 * 127


def webp_quality_from_quantizer(q: float, exponent: float = 1.0) -> int:
    """Invert libwebp's quality -> quantiser mapping (src/enc/quant_enc.c, QualityToCompression) for a
    segment whose compression is the quality's to this power."""
    c = (1.0 - q / 127.0) ** (1.0 / exponent)
    linear = c**3
    quality = linear * 1.5 if linear < 0.5 else (linear + 1.0) / 2.0
    return int(round(max(0.0, min(1.0, quality)) * 100))


def webp_quality_from_segments(quantizers: list[int]) -> int:
    """The quality a libwebp-coded picture was asked at, from its segments' quantisers: the coarsest
    segment's at the default noise shaping (exact on natural photos; above the quality asked, never
    below, where the finest segment is the clipped one: noise); one quantiser for all: itself. The
    finest segment read as the quality's own gave 77 for 50 on a photo (a black-box review)."""
    if len(set(quantizers)) == 1:
        return webp_quality_from_quantizer(float(quantizers[0]))
    return webp_quality_from_quantizer(float(max(quantizers)), SNS_COARSEST_EXPONENT)


def poison_webp(
    im: Image.Image,
    data: bytes,
    placement: PatchPlacement,
    keep_location: bool,
    marker: Marker | None,
    keep_out: np.ndarray | None = None,
) -> tuple[bytes, list[str], list[str], bool, list[str]]:
    chunks = _riff_chunks(data)
    lossless = b"VP8L" in chunks
    notes: list[str] = []
    opts: dict[str, object] = {"exact": True, "method": 4}
    if lossless:
        opts["lossless"] = True
    else:
        try:
            quant = vp8_quantizers(chunks[b"VP8 "])
            quality = webp_quality_from_segments(quant)
            notes.append(f"lossy WebP re-encoded at quality {quality} (from VP8 quantisers {quant})")
        except (KeyError, ValueError, IndexError) as exc:
            quality = 90
            notes.append(f"lossy WebP re-encoded at quality 90 (source quality unknown: {exc})")
        opts["quality"] = quality
        if b"ALPH" in chunks:
            opts["alpha_quality"] = 100
    mode = im.mode if im.mode in ("RGB", "RGBA") else "RGBA" if "A" in im.mode else "RGB"
    out = paste_patch(im if im.mode == mode else im.convert(mode), placement, keep_out)
    preserved, removed, shown = metadata_options(im.info, keep_location, "WebP", marker, opts, lambda: out)
    notes += shown
    buf = io.BytesIO()
    save_explicit(out, buf, "WEBP", **opts)
    return buf.getvalue(), preserved, notes, lossless, removed
