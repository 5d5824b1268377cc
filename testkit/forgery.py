"""What an attacker makes of a sealed file: its seal copied onto a never-patched photo or video
(`forged`), or the patched file cropped or its picture data changed with the seal kept (`edited`)."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import PIL.Image
import PIL.PngImagePlugin

from poisoner.provenance import MAGIC, MP4_UUID
from testkit.reliability import make_media


def token_of(data: bytes) -> str:
    """The seal's text in a patched file (as an attacker copies it)."""
    at = data.index(MAGIC)
    n = int(data[at + len(MAGIC) : at + len(MAGIC) + 2], 16)
    return data[at : at + len(MAGIC) + 2 + 2 * n + 64].decode()


def xmp_with(token: str) -> bytes:
    return (
        b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        b'<rdf:Description rdf:about="" xmlns:sl="urn:uuid:5e1f0c3a-92d4-4b7e-8a61-3c0f9d2b7e14" sl:k="'
        + token.encode()
        + b'"/></rdf:RDF></x:xmpmeta>'
    )


def forged(kind: str, patched: bytes, seed: int) -> bytes:
    """A never-patched photo (or video) carrying the patched file's seal, copied as it is."""
    token = token_of(patched)
    if kind == "mp4":
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            clean = make_media(Path(tmp) / "c.mp4", seed=seed).read_bytes()
        body = MP4_UUID + token.encode()
        return clean + struct.pack(">I", 8 + len(body)) + b"uuid" + body
    im = PIL.Image.new("RGB", (192, 192), (seed * 40 % 256, 90, 120))
    out = io.BytesIO()
    if kind == "png":
        info = PIL.PngImagePlugin.PngInfo()
        info.add_itxt("sl", token)
        im.save(out, "PNG", pnginfo=info)
    else:
        im.save(out, "JPEG", quality=90, xmp=xmp_with(token))
    return out.getvalue()


def edited(kind: str, patched: bytes) -> bytes:
    """The patched file cropped by 25% (images, metadata kept) or with one byte of its picture
    data changed (video): the seal's text is still in it."""
    if kind == "mp4":
        data = bytearray(patched)
        mdat = data.index(b"mdat")
        data[mdat + 200] ^= 0xFF
        return bytes(data)
    im = PIL.Image.open(io.BytesIO(patched))
    crop = im.crop((0, 0, im.width * 3 // 4, im.height))
    out = io.BytesIO()
    if kind == "png":
        info = PIL.PngImagePlugin.PngInfo()
        info.add_itxt("sl", token_of(patched))
        crop.save(out, "PNG", pnginfo=info)
    else:
        crop.save(out, "JPEG", quality=90, xmp=xmp_with(token_of(patched)))
    return out.getvalue()
