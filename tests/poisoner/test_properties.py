"""Property-based tests (hypothesis) on the poisoner's pure functions, and a fuzz run of the
file readers: whatever bytes arrive, a reader answers with its one-line error type (or a
complete output), never another exception. The long fuzz run is `python -m bench faults`."""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path

import numpy as np
import PIL.Image
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from poisoner.blend import apply_patch, poison_array
from poisoner.formats import poison_file
from poisoner.patterns import pattern_levels, pattern_mask
from poisoner.spec import PATTERNS, POSITIONS, PatchSpec, SpecError
from testkit.fuzz import SEEDS, fuzz_image_reader, mutate

lengths = st.one_of(st.integers(1, 64), st.floats(0.001, 0.5))
specs = st.builds(
    PatchSpec,
    pattern=st.sampled_from(sorted(PATTERNS)),
    patch_size=lengths,
    block_size=lengths,
    alpha=st.floats(0.0, 1.0, exclude_min=True),  # 0 is refused (test_mark_faint.py)
    contrast=st.integers(1, 255),
    position=st.sampled_from(sorted(POSITIONS)),
    offset=st.tuples(st.integers(0, 8), st.integers(0, 8)),
    seed=st.integers(0, 2**31),
)
sizes = st.tuples(st.integers(1, 300), st.integers(1, 300))


@given(spec=specs, size=sizes)
def test_resolve_places_the_patch_inside_the_image_or_refuses(spec: PatchSpec, size: tuple[int, int]) -> None:
    width, height = size
    try:
        placement = spec.resolve(width, height)
    except SpecError as exc:
        assert str(exc) and "\n" not in str(exc)
        return
    x0, y0, x1, y1 = placement.box
    assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height
    assert 1 <= placement.block <= placement.size == x1 - x0 == y1 - y0
    assert spec.resolve(width, height) == placement  # deterministic


@given(pattern=st.sampled_from(sorted(PATTERNS)), size=st.integers(1, 80), block=st.integers(1, 80),
       seed=st.integers(0, 1000), contrast=st.integers(0, 255))  # fmt: skip
def test_pattern_mask_shape_levels_and_determinism(
    pattern: str, size: int, block: int, seed: int, contrast: int
) -> None:
    mask = pattern_mask(pattern, size, block, seed)
    assert mask.shape == (size, size) and mask.dtype == bool
    assert np.array_equal(mask, pattern_mask(pattern, size, block, seed))
    levels = pattern_levels(mask, contrast)
    assert levels.min() >= 255 - contrast - 1e-9 and levels.max() <= 255
    assert np.all(levels[~mask] == 255)


pixel_arrays = st.one_of(
    arrays(np.uint8, st.tuples(st.integers(8, 64), st.integers(8, 64), st.sampled_from([3, 4]))),
    arrays(np.uint16, st.tuples(st.integers(8, 64), st.integers(8, 64))),
    arrays(np.uint8, st.tuples(st.integers(8, 64), st.integers(8, 64))),
)


@settings(suppress_health_check=[HealthCheck.too_slow], deadline=None)
@given(pixels=pixel_arrays, spec=specs)
def test_poison_changes_only_the_patch_box_and_is_deterministic(pixels: np.ndarray, spec: PatchSpec) -> None:
    try:
        out, placement = poison_array(pixels, spec)
    except SpecError:
        return
    assert out.shape == pixels.shape and out.dtype == pixels.dtype
    x0, y0, x1, y1 = placement.box
    outside = np.ones(pixels.shape[:2], dtype=bool)
    outside[y0:y1, x0:x1] = False
    assert np.array_equal(out[outside], pixels[outside])  # nothing outside the box moves
    assert np.array_equal(out, apply_patch(pixels, placement))
    if placement.alpha8 == 255 and pixels.ndim == 3 and pixels.shape[2] == 4:
        assert np.all(out[y0:y1, x0:x1, 3] == 255)  # the patch is opaque on RGBA
    if placement.alpha8 == 0 and not (pixels.ndim == 3 and pixels.shape[2] == 4):
        assert np.array_equal(out, pixels)  # alpha 0 is the identity (colour images w/o alpha)


@given(spec=specs)
def test_spec_round_trips_through_json_and_toml(spec: PatchSpec) -> None:
    assert PatchSpec.from_json(spec.to_json()) == spec
    assert PatchSpec.from_json(spec.to_json()).spec_id == spec.spec_id


@given(ratio=st.floats(0.0, 1.0), seed=st.integers(0, 100), names=st.lists(st.text(min_size=1), max_size=20))
def test_ratio_selection_is_a_pure_function_of_the_name(ratio: float, seed: int, names: list[str]) -> None:
    spec = PatchSpec(ratio=ratio, seed=seed)
    picked = [spec.selects(n) for n in names]
    assert picked == [spec.selects(n) for n in reversed(names)][::-1]
    if ratio == 1.0:
        assert all(picked)
    if ratio == 0.0:
        assert not any(picked)


# ---- fuzzing the readers ------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", sorted(SEEDS))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=8),
    cut=st.one_of(st.none(), st.integers(0, 4000)),
)
def test_fuzz_image_readers_only_raise_their_one_line_error(
    tmp_path: Path, suffix: str, edits: list[tuple[int, int]], cut: int | None
) -> None:
    fuzz_image_reader(tmp_path, suffix, mutate(SEEDS[suffix], edits, cut))


@pytest.mark.parametrize(
    "edits",
    [[(130, 1)], [(8, 255)], [(72, 7)]],
    ids=["missing-dimensions", "bad-byte-order", "bytes-strip-offset"],
)
def test_corrupt_tiff_tags_that_make_pillow_raise_typeerror_are_refused(
    tmp_path: Path, edits: list[tuple[int, int]]
) -> None:
    """Regressions the fuzz run found: Pillow raises TypeError on these one-byte TIFF corruptions."""
    assert fuzz_image_reader(tmp_path, ".tif", mutate(SEEDS[".tif"], edits, None)) == "refused"


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=2000), suffix=st.sampled_from([".png", ".jpg", ".webp", ".tif", ".heic"]))
def test_fuzz_random_bytes_with_image_names(tmp_path: Path, data: bytes, suffix: str) -> None:
    fuzz_image_reader(tmp_path, suffix, data)


# ---- fuzzing the metadata readers (location, provenance, limits, completeness) --------------------
def _metadata_seeds() -> dict[str, bytes]:
    """Small files carrying GPS EXIF, XMP and a provenance marker: the parsers' real inputs."""
    rng = np.random.default_rng(4)
    pixels = rng.integers(0, 256, (40, 56, 3), dtype=np.uint8)
    exif = PIL.Image.Exif()
    exif[0x010F] = "cam"
    exif.get_ifd(0x8825)[2] = (48.0, 51.0, 29.0)
    xmp = b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
    xmp += b'<rdf:Description xmlns:exif="http://ns.adobe.com/exif/1.0/" exif:GPSLatitude="1"/>'
    xmp += b"</rdf:RDF></x:xmpmeta>"
    with tempfile.TemporaryDirectory(prefix="ppd-fuzz-seeds-") as tmp:
        return _write_metadata_seeds(Path(tmp), pixels, exif, xmp)


def _write_metadata_seeds(
    folder: Path, pixels: np.ndarray, exif: PIL.Image.Exif, xmp: bytes
) -> dict[str, bytes]:
    from poisoner.provenance import Marker

    seeds = {}
    for fmt, suffix in (("PNG", ".png"), ("JPEG", ".jpg"), ("WEBP", ".webp")):
        src = folder / f"s{suffix}"
        extra = {"xmp": xmp} if fmt != "PNG" else {}
        PIL.Image.fromarray(pixels).save(src, format=fmt, exif=exif, **extra)
        poison_file(
            src,
            folder / f"m{suffix}",
            PatchSpec(patch_size=8, block_size=2),
            marker=Marker.placeholder(bytes(32), "s", "0" * 64),
        )
        seeds[suffix] = (folder / f"m{suffix}").read_bytes()
    return seeds


METADATA_SEEDS = _metadata_seeds()


@pytest.mark.parametrize("suffix", sorted(METADATA_SEEDS))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=8),
    cut=st.one_of(st.none(), st.integers(0, 4000)),
)
def test_fuzz_metadata_readers_never_raise(
    tmp_path: Path, suffix: str, edits: list[tuple[int, int]], cut: int | None
) -> None:
    from poisoner.completeness import incomplete_reason
    from poisoner.limits import HeaderError, decoded_size
    from poisoner.provenance import Seal, read_seal

    path = tmp_path / f"f{suffix}"
    path.write_bytes(mutate(METADATA_SEEDS[suffix], edits, cut))
    assert read_seal(path, bytes(32)) is None or isinstance(read_seal(path, bytes(32)), Seal)
    reason = incomplete_reason(path)
    assert reason is None or (reason and "\n" not in reason)
    with contextlib.suppress(HeaderError):
        decoded_size(path)
    fuzz_image_reader(tmp_path, suffix, path.read_bytes())  # location stripping runs on the output


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=600))
def test_fuzz_metadata_block_parsers_raise_only_their_error(data: bytes) -> None:
    from poisoner import location

    for parse in (
        location.strip_exif_gps,
        location.strip_iim_location,
        location.strip_photoshop_location,
        location.strip_jpeg_location,
    ):
        with contextlib.suppress(location.MetadataParseError):
            parse(data)
    for ctype in (b"eXIf", b"iTXt", b"zTXt", b"tEXt"):
        location.clean_png_chunk(ctype, data)
    location.strip_xmp_location(data)
