"""A photo is judged by what COLMAP reads, its content, not only by its suffix (a black-box review,
F5): JPEGs named .jfif/.pjpeg/.pjp (what browsers and Windows save), Canon's .HIF and a file with no
suffix were 'skipped' like sidecars, unsaid, not counted by `ppd status` and never seen by the daemon,
yet COLMAP reconstructs from every one of them."""

from __future__ import annotations

import hashlib
from pathlib import Path

from PIL import Image
from typer.testing import CliRunner

from daemon.cli import app
from daemon.protect.one_file import AppContext
from daemon.states import FileState
from testkit.daemon_proc import start_daemon, stop_daemon, wait_for
from testkit.photos import gps_exif, make_image
from testkit.reliability import DAEMON_ARGS

runner = CliRunner()

# a JPEG under each of these names is patched; the GIF with no suffix is named as not protected
JPEG_NAMES = ("a.jfif", "b.pjpeg", "c.pjp", "IMG_0004")


def _photo(path: Path, seed: int, fmt: str = "JPEG") -> Path:
    """A photo in fmt whatever path's suffix says, with a camera's make and a GPS position."""
    src = make_image(path.with_name(f"src{seed}.png"), seed, size=(200, 150))
    Image.open(src).save(path, fmt, quality=90, exif=gps_exif())
    src.unlink()
    return path


def _jpeg(path: Path, seed: int) -> Path:
    return _photo(path, seed)


def _heif(path: Path, seed: int) -> Path:
    import pillow_heif

    pillow_heif.register_heif_opener()
    return _photo(path, seed, "HEIF")


def _shoot(folder: Path) -> dict[Path, bytes]:
    """Photos under other suffixes, sidecars beside them; the originals' bytes of those to patch."""
    for i, name in enumerate(JPEG_NAMES):
        _jpeg(folder / name, i)
    _heif(folder / "IMG_0005.HIF", 5)
    Image.new("P", (64, 48)).save(folder / "loop", "GIF")  # COLMAP reads a GIF; ppd writes none
    (folder / "a.xmp").write_text("<x:xmpmeta/>")
    (folder / "notes").write_text("shot list: front, back")  # no suffix, no photo
    (folder / "blob.bin").write_bytes(bytes(range(200)))
    return {p: p.read_bytes() for p in (*(folder / n for n in JPEG_NAMES), folder / "IMG_0005.HIF")}


def _said(result) -> str:  # type: ignore[no-untyped-def]
    return " ".join(result.output.split())


def test_photos_under_other_suffixes_are_patched_counted_and_restored(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    shoot = tmp_path / "shoot"
    shoot.mkdir()
    originals = _shoot(shoot)
    sidecars = {p: p.read_bytes() for p in (shoot / "a.xmp", shoot / "notes", shoot / "blob.bin")}
    result = runner.invoke(app, ["-v", "poison", str(shoot)])
    text = _said(result)
    assert "patched 5, unchanged 0, skipped 4, failed 0" in text, text
    assert "not protected: 1 photo(s) or video(s) ppd cannot read (loop)" in text, text
    assert result.exit_code == 1, text  # the GIF is left unprotected beside them
    for path, before in originals.items():
        assert path.read_bytes() != before, path.name  # each carries the mark, under its own name
    assert all(p.read_bytes() == b for p, b in sidecars.items())  # sidecars left alone
    jfif = Image.open(shoot / "a.jfif")
    assert jfif.format == "JPEG" and jfif.getexif().get(0x010F) == "ppd-cam"  # its metadata kept
    assert 0x8825 not in jfif.getexif()  # the location removed, as from any .jpg
    assert Image.open(shoot / "IMG_0005.HIF").format == "HEIF"
    status = _said(runner.invoke(app, ["status", "shoot"]))
    assert "files 5: patched 5; not counted: in a format ppd cannot protect 1" in status, status
    restored = runner.invoke(app, ["restore", str(shoot)])
    assert restored.exit_code == 0 and "restored 5," in _said(restored), restored.output
    assert all(path.read_bytes() == before for path, before in originals.items())


def test_status_names_an_unpatched_jfif_in_the_outbox(ppd_env: dict[str, Path]) -> None:
    """`ppd status` named y.jpg as not protected in the outbox and said nothing of x.jfif beside it."""
    _jpeg(ppd_env["outbox"] / "shoot" / "x.jfif", 1)
    _jpeg(ppd_env["outbox"] / "shoot" / "IMG_2", 2)
    (ppd_env["outbox"] / "shoot" / "x.xmp").write_text("<x:xmpmeta/>")
    said = _said(runner.invoke(app, ["status"]))
    assert "outbox: 2 photo(s)" in said and "shoot/x.jfif" in said and "shoot/IMG_2" in said, said
    assert "x.xmp" not in said


def _patched(dataset: str) -> set[str]:
    ctx = AppContext.open()
    try:
        rows = ctx.store.files(dataset) if ctx.store.dataset(dataset) else []
    finally:
        ctx.close()
    return {Path(r["path"]).name for r in rows if r["state"] == FileState.PATCHED}


def test_the_daemon_patches_a_jfif_and_a_file_without_suffix_and_leaves_sidecars(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd watch` patched y.jpg and never logged x.jfif, left byte-identical in the outbox."""
    daemon = start_daemon(tmp_path, *DAEMON_ARGS)  # the folders ppd_env made, under tmp_path
    folder = ppd_env["outbox"] / "shoot"
    try:
        folder.mkdir()
        (folder / "x.xmp").write_text("<x:xmpmeta/>")
        (folder / "notes").write_text("shot list")
        for name, seed in (("x.jfif", 1), ("y.jpg", 2), ("IMG_3", 3)):  # complete files, renamed in
            _jpeg(tmp_path / name, seed).rename(folder / name)
        digests = {n: hashlib.sha256((folder / n).read_bytes()).hexdigest() for n in ("x.jfif", "IMG_3")}
        wanted = {"x.jfif", "IMG_3", "y.jpg"}
        wait_for(lambda: _patched("shoot") >= wanted, 60, "x.jfif, IMG_3 and y.jpg patched")
    finally:
        stop_daemon(daemon)
    assert _patched("shoot") == wanted  # no row for a sidecar
    assert all(hashlib.sha256((folder / n).read_bytes()).hexdigest() != d for n, d in digests.items())
    log = daemon.log.read_text()
    assert "x.xmp" not in log and "notes" not in log, log  # sidecars: not even a 'skipped' line


def test_preview_takes_a_photo_ppd_poison_patches_whatever_its_suffix(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """`ppd preview IMG_1` said 'not a photo or video ppd protects (ppd poison skips it)' of a JPEG with no
    suffix, which ppd poison patches; a GIF with no suffix is still refused."""
    shoot = tmp_path / "shoot"
    _jpeg(shoot / "IMG_1", 1)
    Image.new("P", (64, 48)).save(shoot / "loop", "GIF")
    for given in (shoot / "IMG_1", shoot):  # the file, and its folder's first photo
        result = runner.invoke(app, ["preview", str(given), "--out", str(tmp_path / "p.png")])
        assert result.exit_code == 0 and (tmp_path / "p.png").is_file(), result.output
        (tmp_path / "p.png").unlink()
    refused = runner.invoke(app, ["preview", str(shoot / "loop"), "--out", str(tmp_path / "p.png")])
    assert refused.exit_code == 2 and "ppd poison skips it" in _said(refused), refused.output


def test_the_mask_lines_count_a_photo_with_no_suffix(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    """A diff review: with masks for a1.jpg only, a2.jpg and a no-suffix JPEG patched without them, the
    summary said "for 1 of 2 photos" and "no subject mask ... for 1 photo (a2.jpg)": the mask lines
    went by suffix alone."""
    from testkit.photos import masked_shoot

    masked_shoot(tmp_path / "made", tmp_path / "made-masks", n=3)
    shoot, masks = tmp_path / "shoot", tmp_path / "masks"
    shoot.mkdir()
    masks.mkdir()
    for i, name in enumerate(("a1.jpg", "a2.jpg", "a3")):
        Image.open(tmp_path / "made" / f"{i:06d}.png").convert("RGB").save(shoot / name, "JPEG", quality=92)
    (tmp_path / "made-masks" / "000.png").rename(masks / "a1.png")
    result = runner.invoke(app, ["poison", str(shoot), "--subject-masks", str(masks)])
    said = " ".join(result.output.split())
    assert result.exit_code == 0 and "patched 3" in said, said
    assert "no subject mask in" in said and "for 2 photos" in said, said
