"""testkit/free_room.py (the room off a subject a touch is judged against) and testkit/fill_set.py
(issue 25 round 4's subject-filling capture with exact masks)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from testkit.free_room import fits, largest_free_square, two_fit, two_fit_within


def test_the_largest_free_square_is_the_biggest_hole_in_the_mask() -> None:
    subject = np.ones((60, 80), dtype=bool)
    subject[5:25, 50:70] = False  # a 20 x 20 hole
    subject[40:52, 2:30] = False  # a 12 x 28 hole: 12 at most
    assert largest_free_square(subject) == 20
    assert largest_free_square(np.ones((10, 10), dtype=bool)) == 0
    assert largest_free_square(np.zeros((10, 14), dtype=bool)) == 10


def test_fits_marks_every_top_left_corner_of_a_free_square() -> None:
    subject = np.ones((30, 30), dtype=bool)
    subject[10:20, 5:17] = False  # 10 x 12
    ok = fits(subject, 10)
    assert ok.shape == (21, 21)
    assert sorted(zip(*np.nonzero(ok), strict=True)) == [(10, 5), (10, 6), (10, 7)]
    assert not fits(subject, 11).any()
    assert fits(subject, 31).size == 0


def test_two_squares_need_two_places_that_do_not_overlap() -> None:
    subject = np.ones((40, 100), dtype=bool)
    subject[0:10, 0:19] = False  # room for one 10 px square and a bit: not two side by side
    assert largest_free_square(subject) == 10 and not two_fit(subject, 10)
    subject[0:10, 19:20] = False  # 20 px wide now: two 10 px squares side by side
    assert two_fit(subject, 10)
    subject[:] = True
    subject[0:10, 0:10] = subject[30:40, 90:100] = False  # two pockets in opposite corners
    assert two_fit(subject, 10) and not two_fit(subject, 11)


def test_a_fill_view_has_its_subject_about_two_thirds_of_the_frame(shared_dir: Path) -> None:
    from testkit.fill_set import OPTIONS, render, scene
    from verifier.synthetic import camera_poses

    rot, trans = camera_poses(OPTIONS)[12]
    planes = scene()
    rgb, mask = render(rot, trans, planes, 12)
    assert rgb.shape == (800, 800, 3) and mask.shape == (800, 800)
    assert 0.55 < mask.mean() < 0.8  # the box fills about 2/3 of the frame
    around = rgb[~mask].astype(float)
    assert around.std() > 15  # a real textured surrounding, not a plain backdrop
    again, _ = render(rot, trans, planes, 12)
    assert np.array_equal(rgb, again)  # deterministic: the same bytes every run


def test_two_squares_count_as_room_only_within_one_box_of_the_shorter_side() -> None:
    """Two pockets at opposite ends of a wide frame hold a square each, but ppd keeps its two squares
    inside one square of the frame's shorter side: room for two squares, not for the mark."""
    subject = np.ones((60, 200), dtype=bool)
    subject[:10, :10] = False  # a pocket top-left
    subject[50:, 190:] = False  # and one bottom-right, 180 px away
    assert two_fit(subject, 10)
    assert not two_fit_within(subject, 10, 60)
    subject[50:, 40:50] = False  # a third pocket 40 px from the first: both inside a 60 px square
    assert two_fit_within(subject, 10, 60) and not two_fit_within(subject, 10, 49)
    one = np.ones((60, 60), dtype=bool)
    one[:15, :15] = False  # room for one 10 px square only: its fitting corners overlap each other
    assert not two_fit_within(one, 10, 60)


def test_two_squares_that_fit_only_touching_do_not_fit_with_the_gap_ppd_keeps() -> None:
    """ppd keeps split squares a sixth of a side apart (choose_split): a pocket that holds two squares
    only edge to edge (dtu crop55's view 24) is no room for the mark."""
    subject = np.ones((60, 60), dtype=bool)
    subject[:10, :20] = False  # two 10 px squares side by side, touching, and no more
    assert two_fit_within(subject, 10, 60)
    assert not two_fit_within(subject, 10, 60, gap=2)
    subject[:10, :22] = False  # two px more: room with the gap
    assert two_fit_within(subject, 10, 60, gap=2) and not two_fit_within(subject, 10, 60, gap=3)
