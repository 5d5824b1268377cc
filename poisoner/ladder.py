"""The candidate ladder: concrete patch designs for auto mode, least visible first by intent.

Contract with auto mode (verifier/auto_search.py, issue #9): `candidate_ladder()` returns concrete
`Candidate`s (every spec a valid PatchSpec, never "auto"), ordered from least to most visible by
design intent. Auto mode measures each candidate's actual visibility on the dataset and never
relies on this order for the visibility budget.

The first rung is ppd's default, the watermark-like kind `watermark-lanes-2` (two identical marks
sliding in one corner; docs/DESIGNS.md "Default"). The roaming rungs after it:

Why these designs (measured: bench/results/designs.md, docs/DESIGNS.md):
- The paper's static checkerboard is left out: COLMAP's `filter_stationary_matches` removes it
  (lego 0/40 within 5 deg under default, 33/40 under hardened, issue #9), so a preflight that
  checks the hardened profile would spend two SfM runs to reject it every time.
- Every roaming candidate MOVES (motion="drift"): its matches are not stationary, so the stationary
  filter keeps them, and the consistent per-image shift reads as a phantom camera rotation.
  Non-repetitive random blocks, not a checkerboard: a repetitive pattern's descriptors are
  ambiguous, SIFT's ratio test drops most of its matches (lego, 48 px moving 6 px/image:
  random blocks 0/40 under hardened, checkerboard 23/40, issue #9).
- Offsets of 15% of the width put the first image's patch outside COLMAP's watermark border
  band (10% of the image diagonal: 14.1% of the width on square images, 12% on 3:2) on
  landscape and square images, and the drift moves it further inward.
- Steps of 0.75% / 1.3% of the width stay above COLMAP's 4 px stationary threshold at the sizes
  COLMAP processes (<= 3200 px) and after a platform's 2048 px downscale.
- Larger rungs trade visibility for keypoints: multiscale_blocks has corners at b, 2b and 4b, so
  its keypoints survive the 8192-feature cap (which drops the finest scales first) and a
  downscale. Whole-image SSIM >= 0.99 caps an opaque patch at about 1% of the image area
  (8% of the width on 3:2 photos: fountain-P11 SSIM 0.9905 at 246 px).
"""

from __future__ import annotations

from dataclasses import dataclass

from poisoner.spec import SIFT_MAX_EDGE, PatchSpec


@dataclass(frozen=True)
class Candidate:
    """One concrete design: a name for records, its spec, and why it is on the ladder."""

    name: str
    spec: PatchSpec
    why: str


# Shared placement: outside the watermark band, drifting inward (see the module docstring).
_OFFSET = (0.15, 0.15)
_SPAN = 0.25  # fits 0.15 + 0.10 + 0.25 <= 0.5625: every rung fits a 16:9 landscape frame


def _drifting(pattern: str, size: float, step: float) -> PatchSpec:
    """A ladder rung: `pattern` at `size` (fraction of the width), 0.5% blocks, drifting inward."""
    return PatchSpec(
        pattern=pattern,
        patch_size=size,
        block_size=0.005,
        offset=_OFFSET,
        motion="drift",
        motion_step=step,
        motion_span=_SPAN,
    )


def candidate_ladder() -> list[Candidate]:
    """Concrete candidates ordered from least to most visible by design intent."""
    return [
        Candidate(
            name=DEFAULT_KIND,
            spec=WATERMARK_LANES_2_SPEC,
            why="ppd's default: two identical marks sliding in parallel in one corner, off the subject "
            "(watermark-like); holds lego and dtu_scan37 at full size, not an attacker who masks corners",
        ),
        Candidate(
            name="texture-6pct-drift",
            spec=_drifting("random_blocks", 0.06, 0.0075),
            why="non-repetitive texture, the paper's size (P=6% of width, b=0.5%), moving 0.75% of "
            "the width per image: beats COLMAP's stationary filter on object sets (issue #9 probe)",
        ),
        Candidate(
            name="multiscale-6pct-drift",
            spec=_drifting("multiscale_blocks", 0.06, 0.0075),
            why="same size and motion, corners at three scales: keypoints that survive COLMAP's "
            "8192-feature cap and a platform downscale",
        ),
        Candidate(
            name="multiscale-8pct-drift",
            spec=_drifting("multiscale_blocks", 0.08, 0.013),
            why="the largest opaque patch within SSIM 0.99 on 3:2 photos (fountain-P11: 0.9905): "
            "more patch keypoints against a textured scene's votes",
        ),
        Candidate(
            name="multiscale-10pct-drift",
            spec=_drifting("multiscale_blocks", 0.10, 0.013),
            why="above the default budget on photos; for users who accept more visibility",
        ),
    ]


ROAMING_DESIGN = "texture-6pct-drift"  # the ladder's first roaming rung: the named kind "roaming"
DEFAULT_KIND = "watermark-lanes-2"  # what a dataset gets when its config names no patch (default_spec)

# Issue 14: the kinds of protection a creator chooses between, by name.
# - "paper": the paper's static corner checkerboard (reference; COLMAP's stationary filter removes it).
# - "roaming": a visible square of moving texture anywhere in the frame (today's default design).
# - "watermark": a mark inside one corner region (20% of the width x 20% of the height), turned,
#   scaled and shifted differently in every image ("tumble"): neither stationary nor a pure
#   translation, so COLMAP's two defences do not remove it by construction; 7.5% of the width so
#   that it fits the corner region of a 16:9 frame turned 45 degrees and changes < 1% of a 4:3 image.
WATERMARK_SPEC = PatchSpec(
    pattern="random_blocks",
    patch_size=0.075,
    block_size=0.005,
    motion="tumble",
    corner_region=0.2,
    tumble_scale=0.75,
)


# - "watermark-lanes": two marks of random blocks (6% of the width each) in two lanes of one corner,
#   sliding along x at 0.75% and 1.5% of the width per image, never turned: every copy is
#   pixel-identical to the others (SIFT matches them as well as a real object), the two motions are
#   parallel (one epipolar geometry, like two planes at different depths) but of different sizes, so
#   no single translation explains them (COLMAP's watermark test) and neither is stationary.
#   The lanes reach 13% of the width inward: inside a 20% x 20% corner on 4:3, 3:2 and square
#   frames, about 23% of the height on 16:9. bench/results/watermark.md has its measurements.
WATERMARK_LANES_SPEC = PatchSpec(
    pattern="random_blocks",
    patch_size=0.06,
    block_size=0.005,
    motion="slide",
    motion_step=0.0075,
    motion_span=0.14,
    lanes=2,
)


# - "watermark-lanes-2": the same two lanes sliding along the lattice direction (8, 1) instead of x: every
#   copy still at whole pixels (identical descriptors), the two lanes still move exactly in parallel by
#   different amounts, but no mark match keeps its row. Lanes that move exactly along x make pycolmap
#   4.2.1 segfault in PoseLib's shared-focal 6-point solver (the default path for one camera without a
#   focal prior), which is a crash, not protection; tilted by one pixel in eight they do not.
#   bench/results/watermark.md ("Round 3") has the measurements.
#   Blocks of 0.25% of the width, at least 4 px (MIN_BLOCK_PX): 4 px up to 1600 px wide (pixel-identical
#   to 0.5% blocks at 800 px), so a full-size photo's mark has four times the blocks of a 0.5% mark and
#   about three times the keypoints under COLMAP's 8192-feature cap (dtu_scan37 at 1600x1200: the mark's
#   share of the two-view inliers is what decides; bench/results/patch_votes.md).
# Issue 25: position "auto": each photo's lanes go where that photo is plainest as it is shown
# (poisoner.placement.place_on_photo), not in one corner per dataset; `--position CORNER` keeps one corner.
WATERMARK_LANES_2_SPEC = WATERMARK_LANES_SPEC.replace(slide_run=8, block_size=0.0025, position="auto")


# - WATERMARK_LANES_3_SPEC (issue 30; measured, not offered by name): watermark-lanes-2 with blocks of
#   4 px as COLMAP's SIFT sees the photo
#   (sift_edge: a long edge above 3200 px is downsized to 3200 first), so 8 px on a 6000 x 4000 photo
#   where watermark-lanes-2 has 15 px (8 px as SIFT sees it). Pixel-identical to watermark-lanes-2 up to
#   1600 px wide. Measured, NOT the default: it gives the mark back the inliers per pair it has at 1600 px
#   (~500 a neighbour pair at 6000 px, ~150 with 8 px blocks as seen) but a finely textured 24 MP object
#   gives neighbouring views ~2500, and it holds no better than watermark-lanes-2 (12 views of 6000 px,
#   seeds 0 / 1: 58% / 58% within 5 deg under default, against 67% / 0%; bench/results/protection_24mp.md).
WATERMARK_LANES_3_SPEC = WATERMARK_LANES_2_SPEC.replace(block_size=4, sift_edge=SIFT_MAX_EDGE)


def named_specs() -> dict[str, PatchSpec]:
    """The named kinds of protection (see above); every spec is concrete."""
    return {
        "paper": PatchSpec(),
        "roaming": next(c.spec for c in candidate_ladder() if c.name == ROAMING_DESIGN),
        "watermark": WATERMARK_SPEC,
        "watermark-multiscale": WATERMARK_SPEC.replace(pattern="multiscale_blocks"),
        "watermark-lanes": WATERMARK_LANES_SPEC,
        "watermark-lanes-2": WATERMARK_LANES_2_SPEC,
    }


def design_specs() -> dict[str, PatchSpec]:
    """Every design a user can name (`--design`, `[patch] design`): "default", the named kinds of
    protection and automatic mode's ladder rungs."""
    specs = {"default": default_spec(), **named_specs()}
    for candidate in candidate_ladder():
        specs.setdefault(candidate.name, candidate.spec)
    return specs


def named_spec(name: str) -> PatchSpec:
    """One named kind of protection; a clear error for an unknown name."""
    specs = named_specs()
    if name not in specs:
        raise ValueError(f"unknown protection {name!r}; choose one of {', '.join(specs)}")
    return specs[name]


def default_spec() -> PatchSpec:
    """The spec a dataset gets when its config names none: the watermark-like kind "watermark-lanes-2".

    Chosen on real COLMAP runs (bench/results/watermark.md, watermark_spread.md; docs/DESIGNS.md
    "Default"): on lego and dtu_scan37 it keeps as few cameras within 5° of the clean solution as the
    roaming square did at 800 px, holds dtu_scan37 at its full 1600 px where roaming does not, never
    crashed COLMAP, and every changed pixel is in one corner region, off the subject's mask. What it
    cannot survive, by construction: an attacker who masks the corners (the `masked` profile); the
    roaming kind (`--design roaming`) is for users who accept a square anywhere in the frame for that.
    """
    return named_spec(DEFAULT_KIND)


def strongest_spec() -> PatchSpec:
    """The ladder's strongest candidate by design (its last): what an automatic dataset's files get
    while nothing is measured yet (daemon.verification.auto_mode's interim spec)."""
    return candidate_ladder()[-1].spec
