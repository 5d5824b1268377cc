"""The mark designs bench/bench_watermark.py measures (tests/bench/test_watermark_bench_designs.py checks
the claims its results table leans on): the product's named kinds plus issue 14's hypotheses."""

from __future__ import annotations

from poisoner.ladder import WATERMARK_LANES_2_SPEC, WATERMARK_LANES_SPEC, WATERMARK_SPEC, named_specs
from poisoner.spec import PatchSpec

# Issue 14's hypotheses for a corner mark that holds on a textured scene, measured here only (the
# product's named kinds are poisoner.ladder.named_specs). A design is one spec or several specs
# whose marks share the corner (each tumbling on its own).
BENCH_DESIGNS: dict[str, tuple[PatchSpec, ...]] = {
    # the creator's text filled with the texture (poisoner/logo.py); larger square, glyphs fill ~35%
    "watermark-text": (WATERMARK_SPEC.replace(mark_text="\u00a9 Ana 2026", patch_size=0.1),),
    # as many corners as the 1% area budget allows, at three scales (survives the 8192-feature cap)
    "watermark-ms-large": (WATERMARK_SPEC.replace(pattern="multiscale_blocks", patch_size=0.085),),
    # a smooth turn and circle instead of a random pose per image (neighbouring views match the mark)
    "watermark-spin": (WATERMARK_SPEC.replace(motion="spin"),),
    "watermark-spin-ms": (
        WATERMARK_SPEC.replace(motion="spin", pattern="multiscale_blocks", patch_size=0.085),
    ),
    # two marks in two lanes of the corner sliding along x at different speeds, pixel-identical copies
    # (no turn): parallel motions of different size read as parallax, not as one translation
    "watermark-lanes": (
        WATERMARK_LANES_SPEC.replace(lanes=1),
        WATERMARK_LANES_SPEC.replace(lanes=1, motion_step=0.015, offset=(0, 0.07), seed=101),
    ),
    # the lanes with blocks at b, 2b, 4b: keypoints at coarser octaves for full-size photos, where
    # COLMAP's 8192-feature cap drops the finest scales first
    "watermark-lanes-ms": (WATERMARK_LANES_SPEC.replace(pattern="multiscale_blocks"),),
    # the tilted lanes with 4 px blocks at every size (pixel-identical to watermark-lanes-2 at 800 px wide):
    # at full size four times the blocks, so ~3x the keypoints on the mark under the 8192 cap
    "watermark-lanes-2-b4": (WATERMARK_LANES_2_SPEC.replace(block_size=4),),
    # the tilted lanes with blocks of 0.5% of the width (8 px at 1600): watermark-lanes-2 before its
    # blocks were made finer on large frames (pixel-identical to it up to 800 px wide)
    "watermark-lanes-2-b05": (WATERMARK_LANES_2_SPEC.replace(block_size=0.005),),
    # two marks with independent textures and poses: two false motions in one corner
    "watermark-twin": (
        WATERMARK_SPEC.replace(pattern="multiscale_blocks", patch_size=0.055),
        WATERMARK_SPEC.replace(pattern="multiscale_blocks", patch_size=0.055, seed=101),
    ),
}


def designs() -> dict[str, tuple[PatchSpec, ...]]:
    return {**{k: (v,) for k, v in named_specs().items()}, **BENCH_DESIGNS}
