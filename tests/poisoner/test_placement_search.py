"""Issue 30, the patch pass: the placement search's cheaper steps answer exactly as the plain ones.

Per-photo placement ranks thousands of candidate anchors and scans every box position of the
thumbnail for a plain square; the cheaper forms (whole counts instead of shares, a partial sort
instead of a full one) must give the same answers, ties and the float boundary of PLAIN_SHARE
included, or the mark would move. bench.same_bytes and the fill sets check the whole placement on
real photos; these check each step against its definition on random data."""

from __future__ import annotations

import numpy as np
import pytest

from poisoner.array_search import count_integral, integral_image, lexsort_first, lexsort_head
from poisoner.placement import PLAIN_SHARE, most_plain_count
from poisoner.shrink import _some_square_plain


def tied_keys(rng: np.random.Generator, size: int) -> tuple[np.ndarray, ...]:
    """Keys shaped like the anchors' (few distinct values in the primary ones: many ties)."""
    return (
        rng.integers(0, 1000, size),  # x
        rng.integers(0, 3, size),  # y: a few rows
        rng.integers(0, 5, size),  # distance
        rng.integers(0, 2, size),  # off the line
        rng.integers(0, 2, size),  # in a corner
        np.round(rng.integers(0, 4, size) * 0.5, 6),  # badness: 0, 0.5, 1, 1.5
    )


def test_lexsort_head_is_the_head_of_lexsort_ties_and_all() -> None:
    rng = np.random.default_rng(3)
    for size in (1, 2, 5, 79, 80, 81, 300, 4000):
        for count in (1, 7, 80, 500):
            keys = tied_keys(rng, size)
            assert np.array_equal(lexsort_head(keys, count), np.lexsort(keys)[:count])


def test_lexsort_first_is_lexsorts_first_ties_and_all() -> None:
    rng = np.random.default_rng(4)
    for size in (1, 2, 3, 50, 3000):
        for _ in range(20):
            keys = tied_keys(rng, size)
            assert lexsort_first(keys) == int(np.lexsort(keys)[0])
    same = tuple(np.zeros(10) for _ in range(4))  # every key tied everywhere: the lowest index
    assert lexsort_first(same) == 0


def test_most_plain_count_is_where_the_share_stops_being_plain() -> None:
    for cells in range(1, 20000):
        c = most_plain_count(cells)
        assert c / cells <= PLAIN_SHARE < (c + 1) / cells
    assert most_plain_count(49) == 0 and most_plain_count(50) == 1  # 1/50 is PLAIN_SHARE exactly


def test_count_integral_holds_integral_images_sums_and_takes_only_true_false_maps() -> None:
    rng = np.random.default_rng(5)
    mask = rng.random((171, 256)) < 0.4
    assert np.array_equal(count_integral(mask), integral_image(mask))
    with pytest.raises(TypeError):
        count_integral(mask.astype(np.float64))


def shares_reference(integral: np.ndarray, frame: tuple[int, int], side: int) -> bool:
    """_some_square_plain as its definition reads: any box position whose detail SHARE is plain."""
    import math

    th, tw = (n - 1 for n in integral.shape)
    spans = [sorted({max(1, math.ceil(c) - 1), math.ceil(c), math.ceil(c) + 1})
             for c in (side * tw / frame[0], side * th / frame[1])]  # fmt: skip
    for cw in spans[0]:
        for ch in spans[1]:
            if cw <= tw and ch <= th:
                sums = integral[ch:, cw:] - integral[:-ch, cw:] - integral[ch:, :-cw] + integral[:-ch, :-cw]
                if (sums / (cw * ch) <= PLAIN_SHARE).any():
                    return True
    return False


def test_some_square_plain_on_counts_answers_as_the_shares_do_at_the_boundary() -> None:
    """Busy maps with one pocket holding exactly the most detail a plain box may (or one cell
    more): yes and no both occur, and the whole counts agree with the shares every time."""
    rng = np.random.default_rng(6)
    answers = []
    for k in range(40):
        detail = np.ones((171, 256), dtype=bool)
        s = 8 + k % 12  # the pocket's side in cells
        y, x = rng.integers(0, 171 - s), rng.integers(0, 256 - s)
        pocket = np.zeros((s, s), dtype=bool)
        specks = most_plain_count(s * s) + (k % 2)  # at the boundary, or one over it
        pocket.flat[rng.choice(s * s, size=specks, replace=False)] = True
        detail[y : y + s, x : x + s] = pocket
        counts, shares = count_integral(detail), integral_image(detail)
        for side in range(s * 4240 // 256 + 40, s * 4240 // 256 - 60, -10):
            answer = _some_square_plain(counts, (4240, 2832), side)
            assert answer == shares_reference(shares, (4240, 2832), side)
            answers.append(answer)
    assert any(answers) and not all(answers)


def test_lexsort_helpers_leave_nan_and_empty_keys_to_lexsort() -> None:
    """NaN sorts last in lexsort; the narrowing would lose it (NaN == NaN is false), so such keys,
    which the True/False maps never give, go to lexsort itself."""
    nan = np.nan
    primary = np.array([nan, 1.0, nan, 0.0, 2.0])
    keys = (np.arange(5), primary)
    assert lexsort_first(keys) == int(np.lexsort(keys)[0]) == 3
    assert np.array_equal(lexsort_head(keys, 4), np.lexsort(keys)[:4])
    secondary = (np.array([nan, 0.0, 1.0]), np.zeros(3))
    assert lexsort_first(secondary) == int(np.lexsort(secondary)[0])
    assert lexsort_head((np.array([], dtype=float),), 3).size == 0
