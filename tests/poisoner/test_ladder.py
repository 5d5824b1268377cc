"""poisoner/ladder.py: the A1/A2 contract (concrete, valid, distinct, placeable candidates)."""

from __future__ import annotations

import dataclasses
from typing import Any, cast

import numpy as np
import pytest

from poisoner.blend import apply_patch
from poisoner.ladder import Candidate, candidate_ladder
from poisoner.spec import PatchSpec


def test_ladder_is_a_non_empty_list_of_frozen_candidates_with_concrete_specs() -> None:
    ladder = candidate_ladder()
    assert ladder and all(isinstance(c, Candidate) for c in ladder)
    for c in ladder:
        assert isinstance(c.spec, PatchSpec) and c.name and c.why
        assert PatchSpec.from_json(c.spec.to_json()) == c.spec  # storable as-is
        with pytest.raises(dataclasses.FrozenInstanceError):
            cast(Any, c).name = "x"  # refused at run time too, not only by a type checker


def test_names_and_spec_ids_are_unique() -> None:
    ladder = candidate_ladder()
    assert len({c.name for c in ladder}) == len(ladder)
    assert len({c.spec.spec_id for c in ladder}) == len(ladder)


SIZES = [(800, 800), (3072, 2048), (640, 480), (2048, 1365), (1920, 1080)]


@pytest.mark.parametrize(("width", "height"), SIZES)
def test_every_candidate_places_on_common_image_sizes_for_many_images(width: int, height: int) -> None:
    image = np.full((height, width, 3), 128, np.uint8)
    for c in candidate_ladder():
        for key in ("r_0.png", "r_57.png", "IMG_0999.JPG", "holiday.jpg"):
            placement = c.spec.resolve(width, height, image_key=key)
            x0, y0, x1, y1 = placement.box
            assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height
        out = apply_patch(image, c.spec.resolve(width, height, image_key="r_5.png"))
        assert not np.array_equal(out, image)  # it really marks the image


def test_ladder_is_deterministic() -> None:
    assert candidate_ladder() == candidate_ladder()


def test_named_kinds_of_protection() -> None:
    from poisoner.ladder import named_spec, named_specs

    specs = named_specs()
    assert specs["paper"] == PatchSpec()
    assert specs["roaming"].spec_id == "62922c22a5cae028"  # today's default design, id unchanged
    assert specs["watermark"].motion == "tumble" and specs["watermark"].corner_region <= 0.2
    for width, height in SIZES:  # the mark fits every common frame, <= 1% of the area at its largest
        p = specs["watermark"].resolve(width, height, image_key="r_1.png")
        assert p.texture_size**2 <= 0.01 * width * height
    with pytest.raises(ValueError, match="unknown protection"):
        named_spec("glitter")
