"""A writer that appends to a file ppd patched (a fragmented MP4 whose writer closes it between
fragments): ppd's output followed by the recording's raw next fragment was quarantined and the
recording could not be restored (black-box review 9, F1, HIGH). The original comes back with the
appended bytes and is patched whole."""

from __future__ import annotations

import os
import struct
import time
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


def test_a_recording_appended_to_after_ppd_patched_it_is_patched_whole(
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
    patched_first = take.read_bytes()
    with open(take, "ab") as fh:  # the writer's next fragment, appended onto ppd's output
        fh.write(data[moofs[1] : moofs[2]])
    busy = runner.invoke(app, ["poison", str(shoot)])  # just written: its writer may be at work
    text = " ".join(busy.output.split())
    assert "grew after ppd patched it" in text and "patched 0" in text, text
    assert take.read_bytes() == patched_first + data[moofs[1] : moofs[2]]  # left as it is
    quiet = time.time() - 60
    os.utime(take, (quiet, quiet))
    again = runner.invoke(app, ["poison", str(shoot)])
    text = " ".join(again.output.split())
    assert again.exit_code == 0 and "patched 1" in text, text
    assert _frames(take) == _frames_of(data[: moofs[2]], tmp_path)  # both fragments, patched whole
    assert data[moofs[1] : moofs[2]] not in take.read_bytes()  # no raw fragment left
    assert runner.invoke(app, ["poison", str(shoot)]).output.count("unchanged 1") == 1  # settled
    restored = runner.invoke(app, ["restore", str(take)])
    assert restored.exit_code == 0, restored.output
    assert "saved over" not in " ".join(restored.output.split()), restored.output
    assert take.read_bytes() == data[: moofs[2]]  # the recording as its writer wrote it


def test_bytes_appended_that_do_not_continue_the_recording_are_judged_as_before(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """A writer that resumes at the size on disk (rsync --append), which ppd's output changed, adds
    bytes after it that do not make the recording whole: never put together as if they did."""
    full = tmp_path / "recording.mp4"
    moofs = _fragmented_mp4(full)
    data = full.read_bytes()
    shoot = tmp_path / "rec"
    shoot.mkdir()
    take = shoot / "take1.mp4"
    take.write_bytes(data[: moofs[1]])
    assert runner.invoke(app, ["poison", str(shoot)]).exit_code == 0
    patched = take.read_bytes()
    with open(take, "ab") as fh:
        fh.write(data[len(patched) : len(patched) + 5000])  # from the size on disk: mid-fragment bytes
    quiet = time.time() - 60
    os.utime(take, (quiet, quiet))
    result = runner.invoke(app, ["poison", str(shoot)])
    text = " ".join(result.output.split())
    assert "patched 1" not in text and "grew after ppd patched it" not in text, text
    assert take.read_bytes().startswith(patched)  # nothing of the original put at the path


def _frames_of(data: bytes, tmp_path: Path) -> int:
    path = tmp_path / "expected.mp4"
    path.write_bytes(data)
    return _frames(path)
