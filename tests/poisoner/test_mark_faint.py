"""A mark too faint to change a decoded pixel is never called patched (a black-box review,
2026-12-07: `ppd poison --alpha 0` on noisy JPEGs said "patched 4"; the splice's re-encode of the
mark's MCUs moved coefficients, so the coded pictures differed though the mark had changed nothing)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from poisoner.errors import MarkNotWritten
from poisoner.formats import poison_file
from poisoner.ladder import default_spec


def noisy_jpeg(path: Path, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)).save(path, quality=80)
    return path


@pytest.mark.parametrize("alpha", [0.0, 0.001])  # round(255 * alpha) is 0: blends nothing in
def test_a_mark_that_changes_no_pixel_of_a_noisy_jpeg_fails(tmp_path: Path, alpha: float) -> None:
    src, dst = noisy_jpeg(tmp_path / "noisy.jpg"), tmp_path / "out.jpg"
    with pytest.raises(MarkNotWritten, match="too faint to change any pixel"):
        poison_file(src, dst, default_spec().replace(alpha=alpha))
    assert not dst.exists()


def test_a_faint_mark_that_changes_pixels_is_patched(tmp_path: Path) -> None:
    src, dst = noisy_jpeg(tmp_path / "noisy.jpg"), tmp_path / "out.jpg"
    report = poison_file(src, dst, default_spec().replace(alpha=0.05))  # +-6 levels: it changes pixels
    assert report.written > 0 and dst.stat().st_size > 0


@pytest.mark.parametrize(("field", "value"), [("alpha", 0), ("alpha", 0.001), ("contrast", 0), ("ratio", 0)])
def test_a_spec_that_writes_no_texture_is_refused_where_the_user_gives_it(field: str, value: float) -> None:
    """Flags, a spec file and the config go through spec_from_table: refused there. A spec read back
    from the store (a dataset made before) still loads."""
    from daemon.config import mark_problem, spec_from_table
    from poisoner.errors import SpecError
    from poisoner.spec import PatchSpec

    with pytest.raises(SpecError, match=field):
        spec_from_table({field: value})
    stored = default_spec().replace(**{field: value})
    assert PatchSpec.from_json(stored.to_json()) == stored and mark_problem(stored) is not None
