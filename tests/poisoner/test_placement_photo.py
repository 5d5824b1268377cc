"""Issue 25: the mark goes where each photo is plain, as a viewer sees it, and never silently nowhere.

Real files (PNG, JPEG with EXIF orientation), the real CLI and store; no mocks."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageOps
from typer.testing import CliRunner

from daemon.cli import app
from poisoner.blend import patch_coverage
from poisoner.formats import poison_file
from poisoner.ladder import default_spec
from poisoner.orientation import orient_array, position_words, unorient_array
from poisoner.placement import choose_spot, place_on_photo, stored_box_shown
from poisoner.spec import PatchSpec

runner = CliRunner()
SPEC = default_spec()


def textured(h: int, w: int, seed: int) -> np.ndarray:
    """An RGB picture full of detail (every region busy)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (h // 4 + 1, w // 4 + 1, 3), dtype=np.uint8)
    return np.repeat(np.repeat(small, 4, axis=0), 4, axis=1)[:h, :w].copy()


def changed_shown(a: Path, b: Path) -> np.ndarray:
    """Pixels that differ between two files, as a viewer shows them (EXIF orientation applied)."""
    pa = np.asarray(ImageOps.exif_transpose(Image.open(a)).convert("RGB")).astype(int)
    pb = np.asarray(ImageOps.exif_transpose(Image.open(b)).convert("RGB")).astype(int)
    return np.abs(pa - pb).max(axis=2) > 0


@pytest.mark.parametrize("orientation", range(1, 9))
def test_orient_array_is_what_viewers_show(orientation: int) -> None:
    stored = np.arange(5 * 7 * 3, dtype=np.uint8).reshape(5, 7, 3)
    im = Image.fromarray(stored)
    exif = im.getexif()
    exif[0x0112] = orientation
    buf = io.BytesIO()
    im.save(buf, format="PNG", exif=exif)
    shown = np.asarray(ImageOps.exif_transpose(Image.open(io.BytesIO(buf.getvalue()))))
    assert np.array_equal(orient_array(stored, orientation), shown)
    assert np.array_equal(unorient_array(shown, orientation), stored)


def test_choose_spot_takes_the_plain_region_then_the_preferred_anchor() -> None:
    detail = np.ones((60, 80), dtype=bool)
    detail[45:, 50:] = False  # only the bottom-right is plain
    spot = choose_spot(detail, None, (800, 600), [(0, 0, 60, 60)], preferred=(370, 0))
    assert spot.free and spot.x >= 500 and spot.y >= 450
    again = choose_spot(detail, None, (800, 600), [(0, 0, 60, 60)], preferred=(370, 0))
    assert spot == again  # deterministic
    plain = np.zeros((60, 80), dtype=bool)
    best = choose_spot(plain, None, (800, 600), [(0, 0, 60, 60)], preferred=(370, 0))
    assert (best.x, best.y) == (370, 0)
    busy = choose_spot(np.ones((60, 80), dtype=bool), None, (800, 600), [(0, 0, 60, 60)], preferred=(370, 0))
    assert not busy.free  # nothing plain: said, not hidden


def test_choose_spot_never_touches_a_masked_subject_when_there_is_room() -> None:
    plain = np.zeros((60, 80), dtype=bool)
    subject = np.zeros((60, 80), dtype=bool)
    subject[:30, :] = True  # the subject fills the whole top half, the preferred place included
    spot = choose_spot(plain, subject, (800, 600), [(0, 0, 60, 60)], preferred=(370, 0))
    assert spot.free and spot.subject == 0.0 and spot.y >= 300


def test_position_words() -> None:
    assert position_words((350, 0, 450, 100), 800, 600) == "top-centre"
    assert position_words((0, 500, 100, 600), 800, 600) == "bottom-left"
    assert position_words((350, 250, 450, 350), 800, 600) == "centre"


def test_per_photo_mark_goes_to_each_photos_plain_region(tmp_path: Path) -> None:
    """Two photos with their plain region in different places: each mark lands in its own photo's
    plain region (every changed pixel there), and a re-run writes the same bytes."""
    outs = []
    for i, (rows, cols) in enumerate([(slice(0, 60), slice(0, 200)), (slice(140, 240), slice(120, 320))]):
        pixels = textured(240, 320, i)
        pixels[rows, cols] = 200
        src = tmp_path / f"v{i}.png"
        Image.fromarray(pixels).save(src)
        report = poison_file(src, tmp_path / f"out{i}.png", SPEC)
        assert report.place is not None and report.place.free
        changed = changed_shown(src, tmp_path / f"out{i}.png")
        plain = np.zeros((240, 320), dtype=bool)
        plain[rows, cols] = True
        assert changed.any() and not (changed & ~plain).any()
        poison_file(src, tmp_path / f"again{i}.png", SPEC)
        assert (tmp_path / f"again{i}.png").read_bytes() == (tmp_path / f"out{i}.png").read_bytes()
        outs.append(report.placement.box)
    assert outs[0] != outs[1]


def phone_jpeg(path: Path, orientation: int = 6) -> np.ndarray:
    """A phone-style JPEG: stored 320x240 (landscape) with EXIF orientation 6, shown 240x320
    (portrait); as shown, busy everywhere but a plain band at the bottom. Returns the shown pixels."""
    shown = textured(320, 240, 7)
    shown[250:, :] = 190  # plain floor at the bottom of what the viewer sees
    stored = unorient_array(shown, orientation)
    im = Image.fromarray(np.ascontiguousarray(stored))
    exif = im.getexif()
    exif[0x0112] = orientation
    im.save(path, format="JPEG", quality=95, exif=exif)
    return shown


def test_exif_6_phone_photo_gets_the_mark_where_it_shows_plain(tmp_path: Path) -> None:
    src, dst = tmp_path / "IMG_0001.jpg", tmp_path / "out.jpg"
    phone_jpeg(src)
    report = poison_file(src, dst, SPEC)
    place = report.place
    assert place is not None and place.orientation == 6 and place.frame == (240, 320)
    assert place.words.startswith("bottom")
    changed = changed_shown(src, dst)
    ys, xs = np.nonzero(changed)
    x0, y0, x1, y1 = place.box
    assert ys.size > 100 and ys.min() >= 250 - 8  # in the plain band (a JPEG MCU's reach)
    assert xs.min() >= x0 - 8 and xs.max() < x1 + 8 and ys.min() >= y0 - 8 and ys.max() < y1 + 8
    assert stored_box_shown(report.placement, report.width, report.height) == place.box



@pytest.mark.parametrize("fmt", ["TIFF", "WEBP", "PNG", "HEIF"])
def test_a_turned_photo_in_any_format_is_marked_where_it_shows_plain(fmt: str, tmp_path: Path) -> None:
    """Orientation 6 in every format that carries it: the place ppd reports, the pixels it changed
    and `ppd preview`'s line agree, as shown. Pillow turns a TIFF (and pillow-heif a HEIC) upright as
    it decodes it and drops the tag: read from the header first, the TIFF's thumbnail was turned
    twice and ppd said "top-left" of a mark it wrote at the bottom."""
    if fmt == "HEIF":
        pytest.importorskip("pillow_heif").register_heif_opener()
    shown = textured(320, 240, 7)
    shown[250:, :] = 190  # plain floor at the bottom of what the viewer sees
    im = Image.fromarray(np.ascontiguousarray(unorient_array(shown, 6)))
    exif = im.getexif()
    exif[0x0112] = 6
    suffix = {"TIFF": "tif", "WEBP": "webp", "PNG": "png", "HEIF": "heic"}[fmt]
    src, dst = tmp_path / f"IMG_0001.{suffix}", tmp_path / f"out.{suffix}"
    options = {"WEBP": {"lossless": True}, "HEIF": {"quality": 95}}.get(fmt, {})
    im.save(src, format=fmt, exif=exif.tobytes(), **options)
    report = poison_file(src, dst, SPEC)
    place = report.place
    assert place is not None and place.free and place.frame == (240, 320)
    assert place.words.startswith("bottom"), place.words
    a = np.asarray(ImageOps.exif_transpose(Image.open(src)).convert("RGB")).astype(int)
    b = np.asarray(ImageOps.exif_transpose(Image.open(dst)).convert("RGB")).astype(int)
    changed = np.abs(a - b).max(axis=2) > (40 if fmt == "HEIF" else 0)  # HEIC: its re-encode's noise
    ys, xs = np.nonzero(changed)
    x0, y0, x1, y1 = place.box
    assert ys.size > 100 and ys.min() >= 250
    assert xs.min() >= x0 and xs.max() < x1 and ys.min() >= y0 and ys.max() < y1
    out = runner.invoke(app, ["preview", str(src), "--no-visibility"])  # written to the cache folder
    assert out.exit_code == 0, out.output
    said = MARK_AT.search(out.output)
    assert said is not None and said.group(1) == place.words, out.output
    assert tuple(int(v) for v in said.groups()[1:]) == place.box

def test_lanes_are_pixel_identical_as_shown_whatever_the_orientation(tmp_path: Path) -> None:
    """The same photo stored upright and stored turned (orientation 6): as shown, the same mark at
    the same place, pixel for pixel (lossless PNG)."""
    shown = textured(320, 240, 3)
    shown[250:, :] = 190
    files = {}
    for o in (1, 6):
        im = Image.fromarray(np.ascontiguousarray(unorient_array(shown, o)))
        exif = im.getexif()
        exif[0x0112] = o
        im.save(tmp_path / f"p{o}_5.png", exif=exif)
        poison_file(tmp_path / f"p{o}_5.png", tmp_path / f"out{o}.png", SPEC)
        files[o] = np.asarray(ImageOps.exif_transpose(Image.open(tmp_path / f"out{o}.png")).convert("RGB"))
    assert np.array_equal(files[1], files[6])
    assert not np.array_equal(files[1], shown)


def test_place_on_photo_turns_the_pattern_with_the_frame() -> None:
    detail = np.zeros((64, 48), dtype=bool)
    upright, _ = place_on_photo(SPEC, 240, 320, "a_3.png", 1, detail)
    turned, place = place_on_photo(SPEC, 320, 240, "a_3.png", 6, detail)
    assert place.frame == (240, 320) and turned.turn == 6
    assert np.array_equal(orient_array(patch_coverage(turned), 6), patch_coverage(upright))


def test_explicit_corner_keeps_its_meaning() -> None:
    spec = SPEC.replace(position="bottom-right")
    assert not spec.per_photo and spec.corner_bound
    p = spec.resolve(800, 600, "a_0.png")
    assert p.box[2] == 800 and p.box[3] == 600


def test_auto_is_refused_for_a_tumbling_mark() -> None:
    with pytest.raises(ValueError, match="tumbling"):
        PatchSpec(pattern="random_blocks", motion="tumble", position="auto")


# ---- never silent: the CLI --------------------------------------------------------------------------
def test_no_file_is_reported_patched_without_a_changed_pixel(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    """Masks given: one photo's mask covers the whole frame (no free place, nothing may be written):
    that file fails with one line and is left as it was; every file reported patched has changed pixels."""
    images, masks = tmp_path / "shoot" / "image", tmp_path / "shoot" / "mask"
    masks.mkdir(parents=True)
    for i in range(3):
        pixels = textured(240, 320, i)
        pixels[:80] = 220
        images.mkdir(parents=True, exist_ok=True)
        Image.fromarray(pixels).save(images / f"{i:06d}.png")
        mask = np.zeros((240, 320), dtype=np.uint8)
        mask[120:] = 255
        if i == 2:
            mask[:] = 255  # the subject fills the frame
        Image.fromarray(mask).save(masks / f"{i:03d}.png")
    before = {p.name: p.read_bytes() for p in images.iterdir()}
    result = runner.invoke(app, ["-v", "poison", str(images), "--subject-masks", str(masks), "-j", "1"])
    assert result.exit_code == 1, result.output
    assert "patched 2, unchanged 0, skipped 0, failed 1" in result.output
    said = " ".join(result.output.split())
    assert "000002.png: the subject mask covers every pixel the mark would write (no free part of the " \
        "photo holds its squares), no pixel would change: not patched" in said, said
    assert (images / "000002.png").read_bytes() == before["000002.png"]
    for name in ("000000.png", "000001.png"):
        changed = changed_shown_bytes(before[name], images / name)
        assert changed.any() and not changed[120:].any()  # marked, and off the subject


def changed_shown_bytes(original: bytes, patched: Path) -> np.ndarray:
    a = np.asarray(Image.open(io.BytesIO(original)).convert("RGB")).astype(int)
    b = np.asarray(Image.open(patched).convert("RGB")).astype(int)
    return np.abs(a - b).max(axis=2) > 0


def test_no_plain_region_is_said_per_file_and_in_the_summary(
    ppd_env: dict[str, Path], tmp_path: Path
) -> None:
    folder = tmp_path / "busy"
    folder.mkdir()
    for i in range(2):
        Image.fromarray(textured(240, 320, 10 + i)).save(folder / f"v{i}.png")
    plain = textured(240, 320, 20)
    plain[:100] = 128
    Image.fromarray(plain).save(folder / "v2.png")
    result = runner.invoke(app, ["-v", "poison", str(folder), "-j", "1"])
    assert result.exit_code == 0, result.output
    assert "patched 3" in result.output
    assert "mark on the subject in 2 photos: no plain region" in result.output
    assert result.output.count("mark on the subject: no plain region") == 2  # -v: per file
    assert "busy: mark placed per photo, where each photo is plainest as shown" in result.output
    # `ppd status` says it too, from the store (the daemon's files print no summary), for the files
    # patched now: a restored one no longer counts
    status = runner.invoke(app, ["status", "busy"])
    words = " ".join(status.output.split())  # wrapped at the terminal's width (COLUMNS=40 in CI)
    assert status.exit_code == 0, status.output
    assert "mark on the subject in 2 photos: no plain region" in words, status.output
    assert runner.invoke(app, ["restore", str(folder / "v0.png")]).exit_code == 0
    status = runner.invoke(app, ["status", "busy", "--json"])
    assert status.exit_code == 0, status.output
    assert json.loads(status.output)["datasets"][0]["mark_notes"] == [
        "mark on the subject in 1 photo: no plain region"
    ], status.output
    from daemon.context import AppContext
    from daemon.verification.dataset_report import build_dataset_report

    ctx = AppContext.open()
    try:  # and the HTML report's notes, in the same words
        notes = build_dataset_report(ctx, "busy").notes
    finally:
        ctx.close()
    assert "Placement: mark on the subject in 1 photo: no plain region." in notes, notes


# ---- preview, report and pixels agree on a phone photo (EXIF orientation 6) --------------------------
MARK_AT = re.compile(r"mark at the (\S+), within pixels \((\d+),(\d+)\)-\((\d+),(\d+)\) as shown")


def test_exif_6_preview_report_and_pixels_agree(ppd_env: dict[str, Path], tmp_path: Path) -> None:
    from daemon.context import AppContext
    from daemon.verification.dataset_report import build_dataset_report

    folder = tmp_path / "phone"
    folder.mkdir()
    for i in (1, 2):
        phone_jpeg(folder / f"IMG_000{i}.jpg")
    src = folder / "IMG_0001.jpg"
    original = src.read_bytes()
    before = runner.invoke(app, ["preview", str(src), "--out", str(tmp_path / "p1.png"), "--no-visibility"])
    assert before.exit_code == 0, before.output
    planned = MARK_AT.search(before.output)
    assert planned is not None, before.output
    assert runner.invoke(app, ["poison", str(folder), "-j", "1"]).exit_code == 0
    after = runner.invoke(app, ["preview", str(src), "--out", str(tmp_path / "p2.png"), "--no-visibility"])
    assert after.exit_code == 0, after.output
    stored = MARK_AT.search(after.output)
    assert stored is not None and stored.groups() == planned.groups()  # before and after: one answer
    words, box = planned.group(1), tuple(int(v) for v in planned.groups()[1:])
    assert words.startswith("bottom")  # the plain floor as the viewer sees it
    changed = changed_shown_bytes_oriented(original, src)
    ys, xs = np.nonzero(changed)
    assert position_words((xs.min(), ys.min(), xs.max() + 1, ys.max() + 1), 240, 320) == words
    assert xs.min() >= box[0] - 8 and ys.min() >= box[1] - 8  # within a JPEG MCU's reach of the box
    assert xs.max() < box[2] + 8 and ys.max() < box[3] + 8
    ctx = AppContext.open()
    try:
        data = build_dataset_report(ctx, "phone")
    finally:
        ctx.close()
    captions = [f.caption for f in data.figures if f.caption.startswith("Patch preview")]
    found = [MARK_AT.search(c) for c in captions]
    assert found and all(m is not None for m in found), captions
    assert any(m.group(1) == words for m in found if m is not None)
    assert any(n.startswith("Placement: per photo") for n in data.notes)


def changed_shown_bytes_oriented(original: bytes, patched: Path) -> np.ndarray:
    a = np.asarray(ImageOps.exif_transpose(Image.open(io.BytesIO(original))).convert("RGB")).astype(int)
    b = np.asarray(ImageOps.exif_transpose(Image.open(patched)).convert("RGB")).astype(int)
    return np.abs(a - b).max(axis=2) > 0


def test_video_anchors_glide_between_keyframes() -> None:
    from poisoner.keyframes import anchor_at, smooth_anchors

    anchors = smooth_anchors([(0.0, (0, 0)), (1.0, (300, 0)), (2.0, (300, 0))], max_step=100.0)
    assert anchors[1][1] == (100.0, 0.0)  # a 300 px jump in 1 s is spread at 100 px/s
    xs = [anchor_at(anchors, t / 10)[0] for t in range(0, 31)]
    assert xs[0] == 0 and xs[20] == 200 and xs[-1] == 200  # as far as the speed allows, then held
    assert max(b - a for a, b in zip(xs, xs[1:], strict=False)) <= 10  # 100 px/s at 0.1 s steps


def test_lanes_move_by_different_amounts_between_photos_whatever_their_anchors() -> None:
    """Between two photos the two lanes never move by one and the same vector (COLMAP's watermark test
    removes a pure translation): the slide per image index stays, the per-photo anchor is added to it."""
    top_plain = np.ones((192, 256), dtype=bool)
    top_plain[:40] = False
    bottom_plain = np.ones((192, 256), dtype=bool)
    bottom_plain[150:] = False
    for a, b in ((top_plain, top_plain), (top_plain, bottom_plain)):
        p1, _ = place_on_photo(SPEC, 800, 600, "v_3.png", 1, a)
        p2, _ = place_on_photo(SPEC, 800, 600, "v_4.png", 1, b)
        lanes1 = [(p1.x + dx, p1.y + dy) for dx, dy, _ in p1.parts]
        lanes2 = [(p2.x + dx, p2.y + dy) for dx, dy, _ in p2.parts]
        moves = {(x2 - x1, y2 - y1) for (x1, y1), (x2, y2) in zip(lanes1, lanes2, strict=True)}
        assert len(moves) == 2, moves


# ---- round 2: plain places are equal, off the corners, along the slide's line; split lanes ------------
def test_a_plain_place_off_the_corners_beats_a_nearer_plain_corner() -> None:
    """Busy everywhere but the top-left corner region and a patch in the middle of the left edge: the
    mark takes the middle-left patch (the masked attacker removes the four 20% corners), not the corner."""
    detail = np.ones((60, 80), dtype=bool)
    detail[:12, :16] = False  # the top-left corner region (20% x 20%) is plain
    detail[24:36, :10] = False  # so is a patch of the left edge, outside every corner region
    spot = choose_spot(detail, None, (800, 600), [(0, 0, 60, 60)], preferred=(0, 0))
    assert spot.plain and spot.y >= 120 and spot.y + 60 <= 480  # off the corners, though farther
    corner_only = np.ones((60, 80), dtype=bool)
    corner_only[:12, :16] = False
    spot = choose_spot(corner_only, None, (800, 600), [(0, 0, 60, 60)], preferred=(370, 0))
    assert spot.plain and spot.x + 60 <= 160 and spot.y + 60 <= 120  # a plain corner beats busy pixels


def test_anchors_move_along_the_slide_line_before_anywhere_else() -> None:
    """The preferred place busy, the rest plain: the anchor moves along the line of the mark's own slide
    direction (8, 1) through the preferred anchor, so that the lanes of this photo and of a photo at the
    preferred anchor still move exactly in parallel."""
    spec = default_spec()
    pref = spec.auto_anchor(800, 600)
    assert pref[1] > 0  # below the top edge: the line can go either way
    detail = np.zeros((192, 256), dtype=bool)
    x0, y0 = (pref[0] * 256) // 800, (pref[1] * 192) // 600
    detail[y0 : y0 + 20, x0 : x0 + 12] = True  # something detailed at the preferred place
    _, place = place_on_photo(spec, 800, 600, "v_3.png", 1, detail)
    ax, ay = place.anchor
    assert (ax, ay) != pref and place.free
    dx, dy = spec.slide_direction
    assert (ax - pref[0]) * dy == (ay - pref[1]) * dx  # on the line


def test_a_little_detail_at_the_edge_of_the_margin_does_not_move_the_mark() -> None:
    """All plain places are equal: a few detailed cells in the margin around the preferred place (1%)
    leave every photo of a plain-background set at the same anchor."""
    spec = default_spec()
    pref = spec.auto_anchor(800, 600)
    detail = np.zeros((192, 256), dtype=bool)
    ew, eh = spec.path_extent(800, 600)
    detail[(pref[1] + eh) * 192 // 600 + 2, (pref[0] * 256) // 800] = True  # one cell below the mark
    _, place = place_on_photo(spec, 800, 600, "v_3.png", 1, detail)
    assert place.anchor == pref


def two_pockets(path: Path) -> tuple[np.ndarray, list[tuple[slice, slice]]]:
    """A busy 800x600 picture with two plain pockets, each room for one square of the mark but not
    for the two stacked (a subject filling the frame, backdrop showing in two places). Off the left
    edge: a pocket there holds the stacked mark, its path starting before the frame."""
    pixels = textured(600, 800, 3)
    pockets = [(slice(0, 110), slice(300, 420)), (slice(420, 600), slice(150, 270))]
    for rows, cols in pockets:
        pixels[rows, cols] = 230
    Image.fromarray(pixels).save(path)
    return pixels, pockets


def test_lanes_split_into_two_plain_pockets_when_no_place_holds_both(tmp_path: Path) -> None:
    src = tmp_path / "v_5.png"
    _, pockets = two_pockets(src)
    report = poison_file(src, tmp_path / "out.png", SPEC)
    place = report.place
    assert place is not None and place.free and place.source == "estimated-split"
    changed = changed_shown(src, tmp_path / "out.png")
    inside = np.zeros(changed.shape, dtype=bool)
    for rows, cols in pockets:
        inside[rows, cols] = True
        assert changed[rows, cols].any()  # one square in each pocket
    assert changed.any() and not (changed & ~inside).any()  # nothing on the busy "subject"
    assert changed.mean() <= 0.01
    # the line names each square where it is, not the middle of their box (a black-box review: "mark
    # at the middle-right" for squares at the top-right and the bottom-centre)
    assert len(place.squares) == 2
    for (x0, y0, x1, y1), (rows, cols) in zip(place.squares, pockets, strict=True):  # top first
        assert changed[y0:y1, x0:x1].any() and rows.start <= y0 and cols.start <= x0
    assert place.words == "top-centre and bottom-left", place.words
    assert place.line().startswith("mark in 2 squares, at the top-centre, pixels ("), place.line()
    poison_file(src, tmp_path / "again.png", SPEC)
    assert (tmp_path / "again.png").read_bytes() == (tmp_path / "out.png").read_bytes()


def test_split_lanes_keep_their_textures_and_move_in_parallel_by_different_amounts() -> None:
    """Split lanes are the same squares (each lane's texture) at their own anchors; between two photos
    at the same anchors both move along the slide direction, by different amounts."""
    spec = default_spec()
    at = ((300, 10), (40, 440))
    p1 = spec.resolve(800, 600, "v_3.png", lanes_at=at)
    p2 = spec.resolve(800, 600, "v_4.png", lanes_at=at)
    stacked = spec.resolve(800, 600, "v_3.png")
    assert [seed for *_, seed in p1.parts] == [seed for *_, seed in stacked.parts]
    assert p1.lane_size == stacked.lane_size and p1.x + p1.size <= 800 and p1.y + p1.size <= 600
    lanes1 = [(p1.x + dx, p1.y + dy) for dx, dy, _ in p1.parts]
    lanes2 = [(p2.x + dx, p2.y + dy) for dx, dy, _ in p2.parts]
    moves = [(x2 - x1, y2 - y1) for (x1, y1), (x2, y2) in zip(lanes1, lanes2, strict=True)]
    assert moves[0] != moves[1]
    dx, dy = spec.slide_direction
    assert all(mx * dy == my * dx for mx, my in moves)  # both parallel to the slide
    assert lanes1[0][0] >= 300 and lanes1[1][1] >= 440  # each at its own anchor


def test_a_video_keyframe_keeps_its_lanes_stacked(tmp_path: Path) -> None:
    """split=False (videos: one anchor glides between keyframes for both lanes): the two pockets that
    split a photo's lanes give one stacked mark there, said not free."""
    from poisoner.subject import display_detail

    src = tmp_path / "v_5.png"
    two_pockets(src)
    detail, _ = display_detail(src.read_bytes())
    split, place = place_on_photo(SPEC, 800, 600, "v_5.png", 1, detail)
    stacked, kept = place_on_photo(SPEC, 800, 600, "v_5.png", 1, detail, split=False)
    assert place.source == "estimated-split" and kept.source == "no-plain" and not kept.free
    assert stacked == SPEC.resolve(800, 600, "v_5.png", anchor=kept.anchor)  # the stacked layout
    assert split.parts != stacked.parts
