"""Issue 25, round 4: a subject filling the frame, no masks given. Where no place holds the stacked
mark plain, each square looks for its own place on a finer grid (SPLIT_GRID) and, without masks, only
near the frame's edge, as the stacked mark does (a plain patch inside the frame may be the subject's
smooth face); the masks, when given, still allow any place off the subject. A photo whose stacked
mark has a plain place is placed as before (bench/bench_identical.py: lego, dtu_scan37 byte for byte).

Round 5: where no place is free even cropped (no masks), the crop whose squares hold the least detail.

Real files (PNG); no mocks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.formats import poison_file
from poisoner.ladder import default_spec
from poisoner.placement import _parts
from poisoner.shrink import place_fitting
from tests.poisoner.test_placement_photo import changed_shown, textured

SPEC = default_spec()
EDGE = [(slice(0, 110), slice(560, 680)), (slice(470, 600), slice(680, 800))]  # two backdrop pockets
FACE = (slice(200, 340), slice(280, 420))  # a smooth face in the middle of the busy subject


def busy_with_pockets(path: Path, pockets: list[tuple[slice, slice]]) -> None:
    pixels = textured(600, 800, 5)
    for rows, cols in pockets:
        pixels[rows, cols] = 230
    Image.fromarray(pixels).save(path)


def region(shape: tuple[int, int], where: list[tuple[slice, slice]]) -> np.ndarray:
    inside = np.zeros(shape, dtype=bool)
    for rows, cols in where:
        inside[rows, cols] = True
    return inside


def test_without_masks_split_squares_keep_to_the_edges_not_a_smooth_face(tmp_path: Path) -> None:
    src = tmp_path / "v_5.png"
    busy_with_pockets(src, [*EDGE, FACE])
    report = poison_file(src, tmp_path / "out.png", SPEC)
    assert report.place is not None and report.place.free and report.place.source == "estimated-split"
    diff = changed_shown(src, tmp_path / "out.png")
    assert not diff[FACE].any()  # round 3 put a square on the smooth face, nearer the preferred anchor
    for rows, cols in EDGE:
        assert diff[rows, cols].any()  # one square in each backdrop pocket
    assert not (diff & ~region(diff.shape, EDGE)).any()


def test_with_masks_a_smooth_face_off_the_subject_is_free(tmp_path: Path) -> None:
    """The same picture, the masks saying the middle pocket is backdrop: a square may go there (the
    edge rule is for the estimate without masks only)."""
    src = tmp_path / "v_5.png"
    busy_with_pockets(src, [*EDGE, FACE])
    subject = ~region((600, 800), [*EDGE, FACE])
    report = poison_file(src, tmp_path / "out.png", SPEC, keep_out=subject)
    assert report.place is not None and report.place.free
    diff = changed_shown(src, tmp_path / "out.png")
    assert diff[FACE].any() and not (diff & subject).any()


def test_a_square_finds_a_pocket_between_the_coarse_grid_anchors(tmp_path: Path) -> None:
    """Two edge pockets just large enough for one whole square with its margin, at offsets the
    stacked mark's grid (a 25 px stride on 600 px) steps over: found, whole (round 3 cropped the
    squares to fit the grid's anchors), off the busy subject."""
    pockets = [(slice(0, 82), slice(437, 537)), (slice(518, 600), slice(213, 313))]
    src = tmp_path / "v_6.png"
    busy_with_pockets(src, pockets)
    report = poison_file(src, tmp_path / "out.png", SPEC)
    assert report.place is not None and report.place.free and report.place.shrunk is None
    diff = changed_shown(src, tmp_path / "out.png")
    assert diff.sum() == 2 * 48 * 48 and not (diff & ~region(diff.shape, pockets)).any()


# ---- round 5: nowhere free, the least-bad place of the cropped squares too ------------------------------
def test_nowhere_free_the_squares_go_cropped_into_pockets_the_whole_mark_cannot_fit() -> None:
    """A busy frame with two plain pockets at the top edge, each room for a cropped square but not with
    ppd's margin (so no place is called free, even cropped): the least-bad place is the crop whose
    squares hold no detail, not the whole mark over busy pixels (round 4: 81% of its footprint); it is
    still said 'no plain region', and marked as shrunk."""
    detail = np.ones((150, 200), dtype=bool)  # 4 px cells of an 800 x 600 frame
    detail[0:8, 75:83] = False  # x 300-332, y 0-32
    detail[0:8, 90:98] = False  # x 360-392
    placement, where = place_fitting(SPEC, 800, 600, "v_1.png", 1, detail)
    assert not where.free and where.source == "no-plain"
    assert where.shrunk is not None and where.shrunk[0] < placement.lane_size
    assert where.detail == 0.0
    for x0, y0, x1, y1 in _parts(placement):
        cells = detail[y0 // 4 : -(-y1 // 4), x0 // 4 : -(-x1 // 4)]
        assert not cells.any(), (x0, y0, x1, y1)  # each written square inside a pocket



def test_nowhere_free_the_cropped_squares_never_go_into_a_corner_region() -> None:
    """Round 6: the same two pockets moved into the top-left corner region (the masked attacker's):
    the crop is not taken there, the whole mark keeps its least-bad place (dtu_scan37's 55% crops: four
    such crops let `masked` recover 93% of the cameras); at the top edge's middle it is."""
    from poisoner.placement import CORNER_REGION, reaches_a_corner

    detail = np.ones((150, 200), dtype=bool)
    detail[0:8, 5:13] = False  # x 20-52, y 0-32: inside the top-left 20% (160 x 120 px)
    detail[0:8, 20:28] = False  # x 80-112
    placement, where = place_fitting(SPEC, 800, 600, "v_1.png", 1, detail)
    assert not where.free and where.shrunk is None and placement.lane_crop == 0
    moved = np.ones((150, 200), dtype=bool)
    moved[0:8, 75:83] = moved[0:8, 90:98] = False  # the same pockets, top edge's middle
    cropped, there = place_fitting(SPEC, 800, 600, "v_1.png", 1, moved)
    assert there.shrunk is not None and not reaches_a_corner(cropped, 800, 600, there.frame, CORNER_REGION)


@pytest.mark.parametrize("orientation", [1, 6])
def test_reaches_a_corner_sees_each_square_as_shown(orientation: int) -> None:
    """Squares placed apart, one at the top edge's middle and one at the left edge's middle: their
    union box reaches the top-left corner region, neither square does; moved into it, one does."""
    from poisoner.orientation import display_size
    from poisoner.placement import place_on_photo, reaches_a_corner, shown_squares

    width, height = (800, 600) if orientation == 1 else (600, 800)  # stored; shown 800 x 600 either way
    assert display_size(width, height, orientation) == (800, 600)
    for pockets, corner in (([(0, 88), (62, 0)], False), ([(0, 2), (62, 0)], True)):
        detail = np.ones((150, 200), dtype=bool)
        for r, c in pockets:  # thumbnail cells (4 px): room for a whole square and its margin
            detail[r : r + 26, c : c + 26] = False
        placement, where = place_on_photo(SPEC, width, height, "v_1.png", orientation, detail)
        assert where.free and where.source == "estimated-split", where
        first, second = shown_squares(placement, width, height)
        assert max(abs(first[0] - second[0]), abs(first[1] - second[1])) > 200  # apart
        assert reaches_a_corner(placement, width, height, where.frame, 0.2) is corner


def test_nowhere_plain_at_all_the_whole_mark_stays_whole() -> None:
    """Busy everywhere: a crop is a shade less busy somewhere, but no better place and a weaker mark;
    the whole mark goes to the least-bad place, uncropped."""
    detail = np.ones((150, 200), dtype=bool)
    detail[::7, ::5] = False  # a few scattered plain cells, no pocket a square fits
    placement, where = place_fitting(SPEC, 800, 600, "v_1.png", 1, detail)
    assert not where.free and where.shrunk is None and where.detail > 0.5


def test_skipping_crops_no_square_could_be_plain_changes_no_answer(monkeypatch: pytest.MonkeyPatch) -> None:
    """place_fitting skips a crop side when no square of it holds <= PLAIN_SHARE detail anywhere (a
    necessary condition of a free place and of the plain-crop fallback): on busy maps with pockets of
    every size, the answer is the one the unskipped loop gives."""
    import poisoner.shrink as shrink

    rng = np.random.default_rng(5)
    cases = []
    for k in range(12):
        detail = rng.random((150, 200)) < 0.6
        for _ in range(k % 4):  # 0-3 plain pockets of 4-12 cells (16-48 px), anywhere
            y, x, s = rng.integers(0, 140), rng.integers(0, 190), rng.integers(4, 13)
            detail[y : y + s, x : x + s] = False
            if k % 2:  # a speck of detail: plain, not empty (a share between 0 and PLAIN_SHARE)
                detail[y + s // 2, x + s // 2] = True
        cases.append(detail)
    skipped = [place_fitting(SPEC, 800, 600, f"v_{i}.png", 1, d) for i, d in enumerate(cases)]
    monkeypatch.setattr(shrink, "_some_square_plain", lambda *a: True)
    every = [place_fitting(SPEC, 800, 600, f"v_{i}.png", 1, d) for i, d in enumerate(cases)]
    assert skipped == every
    assert any(p.shrunk for _, p in every)  # the cases reach the crops


def test_some_square_plain_sees_a_pocket_of_the_side_and_nothing_smaller() -> None:
    from poisoner.placement import integral_image
    from poisoner.shrink import _some_square_plain

    detail = np.ones((150, 200), dtype=bool)
    assert not _some_square_plain(integral_image(detail), (800, 600), 24)
    detail[10:17, 50:57] = False  # 7 x 7 cells = 28 px: room for a 24 px square (6-7 cells)
    assert _some_square_plain(integral_image(detail), (800, 600), 24)
    assert not _some_square_plain(integral_image(detail), (800, 600), 40)  # 10-11 cells: more than the pocket


def test_some_square_plain_answers_the_same_with_box_sizes_remembered_across_sides() -> None:
    """place_fitting remembers each box size's answer across the crop sides it tries (neighbouring
    sides share most): every side gets the answer a fresh call gives, yes and no both occurring."""
    from poisoner.placement import integral_image
    from poisoner.shrink import _some_square_plain

    rng = np.random.default_rng(11)
    answers = []
    for k in range(6):
        detail = rng.random((171, 256)) < 0.7
        y, x, s = rng.integers(0, 150), rng.integers(0, 230), 6 + 3 * k  # one pocket, a size per map
        detail[y : y + s, x : x + s] = False
        sums, known = integral_image(detail), {}
        for side in range(400, 100, -10):  # sides as crop_sides gives them at 4240 px: 10 px blocks
            shared = _some_square_plain(sums, (4240, 2832), side, known)
            assert shared == _some_square_plain(sums, (4240, 2832), side)
            answers.append(shared)
        assert known  # the sizes were remembered
    assert any(answers) and not all(answers)
