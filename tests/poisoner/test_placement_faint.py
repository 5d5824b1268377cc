"""Issue 25, round 7: a plain band below a plain-looking subject whose edge is faint, no masks given.

creator-fill's three touching views: the box's lower face is a photo of pavement above the real
pavement, plain at DETAIL_LEVEL, their edge too faint to count; the stacked mark, too tall for the
band of floor below the box, reached into the face by a few pixels. Its faint texture (FAINT_LEVEL)
makes such a plain place doubtful: each square then takes its own place in the band. A place with no
faint texture (a studio backdrop: lego, dtu_scan37) is placed exactly as before.

Real files (PNG) from synthetic arrays; no mocks."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from poisoner.formats import poison_file
from poisoner.ladder import default_spec
from poisoner.placement import FAINT_DOUBT, place_on_photo, reaches_a_corner, shown_squares
from poisoner.subject import display_details
from tests.poisoner.test_placement_photo import changed_shown, textured

SPEC = default_spec()
SIDE = 800
FACE_TOP, RIM = 560, 700  # the subject: busy above FACE_TOP, a plain-looking face down to RIM; floor below


def box_on_pavement(faint_amplitude: int = 8) -> np.ndarray:
    """A busy subject whose lower face (rows FACE_TOP..RIM) is a low-contrast texture (plain at
    DETAIL_LEVEL, faint at FAINT_LEVEL), above a flat floor; the edge between them a faint line."""
    pixels = textured(SIDE, SIDE, 7).astype(np.int16)
    yy, xx = np.mgrid[0:SIDE, 0:SIDE]
    face = 128 + faint_amplitude * (((yy // 6) + (xx // 10)) % 2)
    pixels[FACE_TOP:RIM] = face[FACE_TOP:RIM, :, None]
    pixels[RIM:] = 128
    pixels[RIM - 1 : RIM + 1] = 124
    return np.clip(pixels, 0, 255).astype(np.uint8)


def maps(pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, format="PNG")
    detail, faint, _ = display_details(buf.getvalue(), "v_3.png")
    return detail, faint


def test_the_face_is_plain_to_the_detail_map_and_faint_to_the_finer_one() -> None:
    detail, faint = maps(box_on_pavement())
    face = slice(FACE_TOP * 256 // SIDE + 2, RIM * 256 // SIDE - 1)
    assert not detail[face].any() and faint[face].mean() > 10 * FAINT_DOUBT
    assert not faint[RIM * 256 // SIDE + 2 :].any()  # the real floor: flat


def test_the_stacked_mark_touching_a_faint_face_splits_into_the_floor_band(tmp_path: Path) -> None:
    src = tmp_path / "v_3.png"
    Image.fromarray(box_on_pavement()).save(src)
    detail, faint = maps(box_on_pavement())
    # the rule before round 7 (no faint map): the stacked mark at the bottom edge, reaching the face
    before, _ = place_on_photo(SPEC, SIDE, SIDE, src.name, 1, detail)
    assert min(y0 for _, y0, _, _ in shown_squares(before, SIDE, SIDE)) < RIM
    report = poison_file(src, tmp_path / "out.png", SPEC)
    assert report.place is not None and report.place.free and report.place.source == "estimated-doubt-split"
    assert "faint texture" in report.place.line()  # what ppd poison -v and ppd preview say
    changed = changed_shown(src, tmp_path / "out.png")
    assert changed.any() and not changed[:RIM].any()  # nothing on the subject, its face included
    placed, _ = place_on_photo(SPEC, SIDE, SIDE, src.name, 1, detail, faint=faint)
    assert not reaches_a_corner(before, SIDE, SIDE, (SIDE, SIDE), SPEC.corner_region)
    assert not reaches_a_corner(placed, SIDE, SIDE, (SIDE, SIDE), SPEC.corner_region)


def test_a_plain_place_without_faint_texture_is_placed_as_before() -> None:
    """A studio backdrop: the face flat (no faint texture either), the band wide enough: the faint
    map changes nothing (what keeps lego's and dtu_scan37's files byte-identical)."""
    pixels = box_on_pavement(faint_amplitude=0)
    pixels[FACE_TOP:RIM] = 128
    detail, faint = maps(pixels)
    assert not faint[FACE_TOP * 256 // SIDE + 2 :].any()
    for name in ("v_1.png", "v_3.png", "v_8.png"):
        assert place_on_photo(SPEC, SIDE, SIDE, name, 1, detail) == place_on_photo(
            SPEC, SIDE, SIDE, name, 1, detail, faint=faint
        )
