"""A writer that appends to a file ppd patched (a fragmented MP4 whose writer closes it between
fragments): ppd's output followed by the recording's raw next fragment was quarantined and the
recording could not be restored (black-box review 9, F1, HIGH). The original comes back with the
appended bytes and is patched whole."""

from __future__ import annotations

import hashlib
import struct
from pathlib import Path

import av
from typer.testing import CliRunner

from daemon.cli import app
from testkit.video import scene

runner = CliRunner()


def _fragmented_mp4(path: Path, frames: int = 72, gop: int = 24) -> list[int]:
    """An MP4 written as OBS's "fragmented MP4" is (moov first, then a moof+mdat per keyframe
    interval); the byte offsets where its fragments start."""
    with av.open(str(path), "w", options={"movflags": "frag_keyframe+empty_moov"}) as out:
        vs = out.add_stream("libx264", rate=24, options={"g": str(gop), "keyint_min": str(gop)})
        vs.width, vs.height, vs.pix_fmt = 160, 120, "yuv420p"
        for i in range(frames):
            frame = av.VideoFrame.from_ndarray(scene(160, 120, i), format="rgb24").reformat(format="yuv420p")
            frame.pts = i
            for pkt in vs.encode(frame):
                out.mux(pkt)
        for pkt in vs.encode(None):
            out.mux(pkt)
    data, offsets, at = path.read_bytes(), [], 0
    while at + 8 <= len(data):
        size, kind = struct.unpack(">I4s", data[at : at + 8])
        if kind == b"moof":
            offsets.append(at)
        at += size
    return offsets


def _frames(path: Path) -> int:
    with av.open(str(path)) as container:
        return sum(1 for _ in container.decode(video=0))


def test_bytes_appended_to_a_patched_video_put_back_with_its_original(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    full = tmp_path / "recording.mp4"
    moofs = _fragmented_mp4(full)
    assert len(moofs) >= 3, moofs
    data = full.read_bytes()
    shoot = tmp_path / "rec"
    shoot.mkdir()
    take = shoot / "take1.mp4"
    take.write_bytes(data[: moofs[1]])  # the first fragment: a complete, playable file
    first = runner.invoke(app, ["poison", str(shoot)])
    assert first.exit_code == 0 and "patched 1" in first.output, first.output
    with open(take, "ab") as fh:  # the writer's next fragment, appended onto ppd's output
        fh.write(data[moofs[1] : moofs[2]])
    again = runner.invoke(app, ["poison", str(shoot)])
    text = " ".join(again.output.split())
    assert again.exit_code == 0 and "patched 1" in text, text
    assert _frames(take) == _frames_of(data[: moofs[2]], tmp_path)  # both fragments, patched whole
    assert hashlib.sha256(take.read_bytes()).hexdigest() != hashlib.sha256(data[: moofs[2]]).hexdigest()
    restored = runner.invoke(app, ["restore", str(take)])
    assert restored.exit_code == 0, restored.output
    assert "saved over" not in " ".join(restored.output.split()), restored.output  # not an edit over the mark
    assert take.read_bytes() == data[: moofs[2]]  # the recording as its writer wrote it


def _frames_of(data: bytes, tmp_path: Path) -> int:
    path = tmp_path / "expected.mp4"
    path.write_bytes(data)
    return _frames(path)
