"""poisoner.media.media_class, what a diff review found in the sniffing of photos by their first bytes:
a preallocated download named after its photo was patched while its tool still wrote it, a FIFO with
no suffix hung `ppd status`, and raw files with a TIFF-like header were named nowhere."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from poisoner.media import IMAGE, UNPROTECTED, VIDEO, content_under_any_name, media_class, unpatched_name

JPEG_HEAD = b"\xff\xd8\xff\xe0\x00\x10JFIF\x00" + bytes(53)


@pytest.mark.parametrize("name", ["photo.jpg.!sync", "photo.jpg.bc!", "photo.jpg.td", "a.png.xyz", "x.!bt"])
def test_a_download_named_after_its_photo_is_not_sniffed(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_bytes(JPEG_HEAD)  # its first bytes already read as a JPEG; its middle may not be there
    assert media_class(path) is None


@pytest.mark.parametrize("name", ["IMG_0001", "IMG_0001.jpg_original", "shot.THM"])
def test_a_photo_under_a_name_of_no_format_is_sniffed(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_bytes(JPEG_HEAD)
    assert media_class(path) == IMAGE


@pytest.mark.parametrize("head", [b"IIU\x00", b"IIRO", b"IIRS", b"MMOR", b"FUJIFILMCCD-RAW "])
def test_raw_files_with_a_tiff_like_header_are_named_unprotected(tmp_path: Path, head: bytes) -> None:
    path = tmp_path / "RAW_0001.unknown"
    path.write_bytes(head + bytes(60))
    assert media_class(path) == UNPROTECTED
    assert media_class(tmp_path / "P1000001.RW2") == UNPROTECTED  # by suffix, unread
    (tmp_path / "P1000002.raw").write_bytes(bytes(64))
    assert media_class(tmp_path / "P1000002.raw") == UNPROTECTED


def test_a_fifo_is_not_read(tmp_path: Path) -> None:
    """Opened to be read, a FIFO blocks until a writer comes: `ppd status` hung on one."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    answer: list[str | None] = []
    judge = threading.Thread(target=lambda: answer.append(media_class(fifo)), daemon=True)
    judge.start()
    judge.join(timeout=10)
    assert not judge.is_alive() and answer == [None]


MP4_HEAD = b"\x00\x00\x00\x18ftypmp42" + bytes(52)


@pytest.mark.parametrize(
    "name, head, kind",
    [
        ("IMG_0024.part", JPEG_HEAD, IMAGE),
        (".IMG_0017.jpg", JPEG_HEAD, IMAGE),
        ("clip.mp4.part", MP4_HEAD, VIDEO),
        (".clip.mov", MP4_HEAD, VIDEO),
        ("memo.part", MP4_HEAD, None),  # an MP4 may be sound alone: a video only by its name
        ("._IMG_0017.jpg", b"\x00\x05\x16\x07" + bytes(60), None),  # macOS's resource fork of a copy
        ("notes.txt.bak", b"my notes" + bytes(56), None),
    ],
)
def test_a_file_under_a_name_ppd_does_not_patch_is_told_by_its_first_bytes(
    name: str, head: bytes, kind: str | None
) -> None:
    """A black-box review (F4): `ppd status` never counted the JPEGs under names ppd does not patch."""
    assert unpatched_name(name) is not None
    assert content_under_any_name(name, head) == kind


def test_a_photo_named_with_a_hash_is_a_photo_emacs_autosave_is_not(tmp_path: Path) -> None:
    assert unpatched_name("#IMG_0022.jpg") is None and unpatched_name("#IMG_0022.jpg#") == "editor lock file"
    path = tmp_path / "#IMG_0022.jpg#"
    path.write_bytes(JPEG_HEAD)
    assert media_class(path) is None  # before: a JPEG by its bytes, which `ppd poison` patched
