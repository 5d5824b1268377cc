"""PatchSpec: everything that decides what a dataset's patch looks like and where it goes.

A spec is resolved against an image size into a `PatchPlacement` (pixel geometry). Two images of the
same size resolve to the same placement: every image of a dataset gets a bit-identical patch at
identical pixel coordinates (the paper's mechanism).

A moving spec (issue #9: `motion` other than "static") also takes the image's file name: `resolve(width,
height, image_key)` moves the patch along a deterministic path indexed by the name (poisoner/motion.py),
so COLMAP's stationary-match filter no longer removes its matches. Without a key: index 0.

Sizes are pixels when given as an int (or a float >= 1) and a fraction of the image width
when given as a float in (0, 1) (poisoner.lengths: a 2:1 frame's width on a wider panorama): the
paper uses 12 px on 800x800 NeRF-Synthetic frames and 2%-25% of width on Mip-NeRF 360.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from poisoner.errors import SpecError
from poisoner.lengths import MIN_BLOCK_PX, Length, length_base, resolve_length
from poisoner.logo import LogoError, mark_shape
from poisoner.motion import (
    CORNER_MOTIONS,
    MOTIONS,
    image_index,
    path_offset,
    spin_pose,
    tilted_slide_offset,
    tumble_extent,
    tumble_pose,
)

SPEC_VERSION = 1

PATTERNS = (
    "checkerboard",
    "parallel_lines",
    "diagonal_lines",
    "intersecting_lines",
    "circles",
    "checkerboard+circles",
    "checkerboard+diagonal_lines",
    "diagonal_lines+circles",
    "all",
    "random_blocks",
    "multiscale_blocks",
)

POSITIONS = ("top-left", "top-right", "bottom-left", "bottom-right", "center", "auto")
# "auto" (issue 25): each photo's mark goes where that photo is plainest (poisoner.placement
# place_on_photo); resolve() then takes the photo's anchor, and without one uses auto_anchor().
AUTO = "auto"

# COLMAP's SIFT downsizes a picture whose long edge exceeds this (SiftExtraction.max_image_size, the
# extractor default pycolmap 4.2.1 uses): what a creator's 24 MP photo is to an attacker's SfM.
SIFT_MAX_EDGE = 3200

# Fields added by issues 9, 14 and later. They stay out of the canonical dict (and so out of spec_id)
# while at these defaults: every spec stored before them keeps its id.
NEW_FIELD_DEFAULTS: dict[str, Any] = {
    "motion": "static",
    "motion_step": 0,
    "motion_span": 0.25,
    "corner_region": 0.2,
    "tumble_scale": 0.75,
    "mark_text": "",
    "mark_image": "",
    "lanes": 1,
    "slide_run": 0,
    "sift_edge": 0,
}

# Lanes of a multi-lane mark: lane k sits k pitches inward (pitch = 7/6 of the mark, a gap of a
# sixth), moves k+1 times as fast and has its own texture (seed + LANE_SEED_STEP * k).
LANE_SEED_STEP = 101
MAX_LANES = 3
# All lanes together change at most this fraction of the image (issue 14's budget is 1%), and they
# stack inside corner_region of the height: on wide frames the lanes shrink instead of spilling over.
LANES_MAX_AREA = 0.0096
# A tilted slide (slide_run > 0) moves along the lattice direction (run, 1); below this run two stacked
# lanes could overlap (their gap is a sixth of the lane side, their x distance run px per px of y).
MIN_SLIDE_RUN = 6


@dataclass(frozen=True)
class PatchPlacement:
    """A spec resolved on one image size: where the patch goes, in stored pixel coordinates."""

    x: int
    y: int
    size: int
    block: int
    alpha8: int  # the paper's alpha as an 8-bit value: round(255 * alpha)
    contrast: int  # 0..255: bright level is 255, dark level is 255 - contrast (8-bit scale)
    pattern: str
    seed: int
    # issue 14 ("tumble"): the texture is texture_size px square, turned by angle degrees and
    # scaled by scale; size is then the side of its bounding box. texture_size 0: not turned.
    texture_size: int = 0
    angle: float = 0.0
    scale: float = 1.0
    # issue 14: the mark's shape is the creator's text or logo (poisoner/logo.py), filled with the texture
    mark_text: str = ""
    mark_image: str = ""
    # issue 14 ("lanes"): several marks in one box; each part is (dx, dy, seed) of a lane_size px
    # square relative to (x, y). Empty: one mark filling the box.
    parts: tuple[tuple[int, int, int], ...] = ()
    lane_size: int = 0
    # issue 25: the EXIF orientation of the picture the mark was placed for. The mark is laid out
    # as a viewer sees the picture (display space) and turned back into the stored pixels, so its
    # copies are pixel-identical across photos as they are shown. 1: stored = shown.
    turn: int = 1
    # issue 25 round 3: each lane's square shown at this side, the top-left lane_crop x lane_crop of
    # its lane_size texture (the same blocks, cropped, never rescaled: the copies' SIFT features stay
    # those of the full squares). 0: the whole square.
    lane_crop: int = 0

    @property
    def lane_side(self) -> int:
        """The side of each lane's square as written (lane_crop when cropped)."""
        return self.lane_crop or self.lane_size

    @property
    def box(self) -> tuple[int, int, int, int]:
        """(left, top, right, bottom), right/bottom exclusive."""
        return (self.x, self.y, self.x + self.size, self.y + self.size)


@dataclass(frozen=True)
class PatchSpec:
    """The one patch of a dataset.

    Defaults, and why:
    - checkerboard: the paper's main pattern; its corners are strong, repeatable SIFT extrema.
    - patch_size 0.06 of the width (48 px on an 800 px frame): we measured P=48, b=4, alpha=1
      in the top-left corner taking lego from 85% of cameras within 5 deg to 0%, while the
      paper's clean-vs-poisoned SSIM for P=48 is 0.9958. A fraction keeps the same share of
      the picture (and the same SSIM) on larger photos, where COLMAP downsizes to 3200 px.
    - block_size 0.005 of the width, at least MIN_BLOCK_PX (4 px on 800 px): the paper's
      b=4..6 is the strongest band.
    - alpha 1.0, contrast 255: the paper's strongest, measured setting.
    - ratio 1.0: the paper's ratio ablation shows 5%-10% do nothing; 50%-100% are needed.
    """

    pattern: str = "checkerboard"
    patch_size: Length = 0.06
    block_size: Length = 0.005
    alpha: float = 1.0
    contrast: int = 255
    position: str = "top-left"
    offset: tuple[Length, Length] = (0, 0)  # (dx, dy) inward from the chosen corner
    ratio: float = 1.0
    seed: int = 0
    version: int = field(default=SPEC_VERSION)
    # issue #9: a patch that moves from image to image (see poisoner/motion.py)
    motion: str = "static"  # static | drift | orbit | tumble | spin
    motion_step: Length = 0  # path length per image index, px or fraction of width
    motion_span: Length = 0.25  # extent of the path on each axis, px or fraction of width
    # issue 14: motions "tumble" (a random pose per image) and "spin" (a smooth turn and circle) keep
    # the mark inside one corner region (this fraction of the width and of the height) and turn,
    # scale and shift it per image (poisoner/motion.py)
    corner_region: float = 0.2
    tumble_scale: float = 0.75  # smallest per-image scale of a tumbling mark (largest: 1)
    # issue 14: the mark is the creator's text (e.g. "© Ana 2026") or logo (a PNG whose alpha is the
    # shape) filled with the texture; pixels of the square outside the glyphs are left alone
    mark_text: str = ""
    mark_image: str = ""
    # issue 14: several marks (lanes) in one corner, sliding along x at 1x, 2x, ... the step; their
    # parallel motions of different sizes read as parallax, not as the one translation of a watermark
    lanes: int = 1
    # issue 14: 0 = slide along x; N >= MIN_SLIDE_RUN = slide along (N, 1), N px along x per px
    # inward in y (whole pixels, lanes exactly parallel): exact x-only motion crashes COLMAP's
    # shared-focal solver (poisoner/motion.py tilted_slide_offset)
    slide_run: int = 0
    # issue 30: 0 = block_size is measured on the stored pixels; N = on the picture as COLMAP's SIFT
    # sees it (long edge downsized to N px: SIFT_MAX_EDGE), then scaled back to the stored pixels, so
    # a 6000 px photo's mark has the blocks that SIFT sees on a <= N px one (bench/results/protection_24mp.md)
    sift_edge: int = 0

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise SpecError(f"unknown pattern {self.pattern!r}; choose one of {', '.join(PATTERNS)}")
        if self.position not in POSITIONS:
            raise SpecError(f"unknown position {self.position!r}; choose one of {', '.join(POSITIONS)}")
        if not 0.0 <= self.alpha <= 1.0:
            raise SpecError(f"alpha must be in [0, 1], got {self.alpha}")
        if not 0 <= self.contrast <= 255:
            raise SpecError(f"contrast must be in [0, 255], got {self.contrast}")
        if not 0.0 <= self.ratio <= 1.0:
            raise SpecError(f"ratio must be in [0, 1], got {self.ratio}")
        if self.version != SPEC_VERSION:
            raise SpecError(f"spec version {self.version} is not supported (this ppd reads {SPEC_VERSION})")
        for v in (self.patch_size, self.block_size):
            resolve_length(v, 1000)  # validates type and sign
        if len(self.offset) != 2:
            raise SpecError("offset must be (dx, dy)")
        if self.motion not in MOTIONS:
            raise SpecError(f"unknown motion {self.motion!r}; choose one of {', '.join(MOTIONS)}")
        if self.motion_step != 0:
            resolve_length(self.motion_step, 1000)
        resolve_length(self.motion_span, 1000)
        if not 0.0 < self.corner_region <= 0.5:
            raise SpecError(f"corner_region must be in (0, 0.5], got {self.corner_region}")
        if not 0.0 < self.tumble_scale <= 1.0:
            raise SpecError(f"tumble_scale must be in (0, 1], got {self.tumble_scale}")
        if self.motion in CORNER_MOTIONS and self.position in ("center", AUTO):
            raise SpecError(f"a tumbling mark lives in a corner: position must not be {self.position!r}")
        if not isinstance(self.mark_text, str) or not isinstance(self.mark_image, str):
            raise SpecError("mark_text and mark_image must be strings")
        lanes_ok = isinstance(self.lanes, int) and not isinstance(self.lanes, bool)
        if not lanes_ok or not 1 <= self.lanes <= MAX_LANES:
            raise SpecError(f"lanes must be an integer from 1 to {MAX_LANES}, got {self.lanes!r}")
        if self.lanes > 1 and (self.motion != "slide" or self.position == "center"):
            raise SpecError("lanes > 1 needs motion 'slide' and a corner position")
        run_ok = isinstance(self.slide_run, int) and not isinstance(self.slide_run, bool)
        if not run_ok or not (self.slide_run == 0 or self.slide_run >= MIN_SLIDE_RUN):
            raise SpecError(f"slide_run must be 0 or an integer >= {MIN_SLIDE_RUN}, got {self.slide_run!r}")
        if self.slide_run and self.motion != "slide":
            raise SpecError("slide_run needs motion 'slide'")
        edge_ok = isinstance(self.sift_edge, int) and not isinstance(self.sift_edge, bool)
        if not edge_ok or self.sift_edge < 0:
            raise SpecError(f"sift_edge must be 0 or a long edge in px, got {self.sift_edge!r}")
        if self.mark_text and self.mark_image:
            raise SpecError("give mark_text or mark_image, not both")
        if self.mark_text and not self.mark_text.strip():
            raise SpecError("mark_text is blank")
        object.__setattr__(self, "offset", (self.offset[0], self.offset[1]))

    # ---- geometry -------------------------------------------------------------------------
    def resolve(
        self,
        width: int,
        height: int,
        image_key: str | None = None,
        *,
        index: float | None = None,
        anchor: tuple[int, int] | None = None,
        lanes_at: tuple[tuple[int, int], ...] | None = None,
        crop: int = 0,
    ) -> PatchPlacement:
        """Pixel placement of this spec's patch on a width x height image.

        image_key (the image's file name) only matters for a moving spec: it picks the image's
        point on the path; a static spec places every image's patch identically. `index` gives
        the point on the path directly instead (videos: a fractional index per frame).
        anchor (position "auto" only): the photo's own anchor, the top-left the mark's path starts
        from (poisoner.placement.place_on_photo); None: auto_anchor(width, height).
        lanes_at (position "auto", lanes > 1): each lane's own anchor instead (round 2: where no
        place holds the lanes stacked, each square goes to its own plain place); the box is then
        the smallest square holding them, inside the frame.
        crop (lanes > 1; round 3): each lane's square cropped to this side (px, 0 or >= the lane's
        side: whole), where no plain place holds it whole (poisoner.shrink).
        """
        if self.position == AUTO:
            ax, ay = anchor if anchor is not None else self.auto_anchor(width, height)
            # the mark's path starts at the anchor and runs right/down, as from a top-left corner
            corner = self.replace(position="top-left", offset=(max(0, int(ax)), max(0, int(ay))))
            if (ax < 0 or ay < 0) and lanes_at is None:  # a path starting before the frame's edge
                if self.motion in CORNER_MOTIONS:
                    raise SpecError(f"anchor ({ax},{ay}) falls outside a {width}x{height} image")
                if self.lanes > 1:
                    lanes_at = corner._stacked_anchors(width, height, (int(ax), int(ay)))
                else:  # one square: the path's point moved back by what lies before the edge
                    one = corner.resolve(width, height, image_key, index=index, crop=crop)
                    x, y = one.x + min(0, int(ax)), one.y + min(0, int(ay))
                    if x < 0 or y < 0:
                        raise SpecError(f"patch at ({x},{y}) falls outside a {width}x{height} image")
                    return dataclasses.replace(one, x=x, y=y)
            return corner.resolve(width, height, image_key, index=index, lanes_at=lanes_at, crop=crop)
        base = length_base(width, height)
        size = resolve_length(self.patch_size, base)
        block = min(self.block_px(width, height), size)
        dx = 0 if self.offset[0] == 0 else resolve_length(abs(self.offset[0]), base)
        dy = 0 if self.offset[1] == 0 else resolve_length(abs(self.offset[1]), base)
        if size > width or size > height:
            raise SpecError(f"patch of {size} px does not fit a {width}x{height} image")
        if self.motion in CORNER_MOTIONS:
            return self._resolve_tumble(width, height, size, block, image_key, index)
        if self.lanes > 1:
            return self._resolve_lanes(width, height, size, block, (dx, dy), image_key, index, lanes_at, crop)
        if lanes_at is not None or crop:
            raise SpecError("lanes_at and crop need a mark of several lanes")
        mx, my = self._motion_offset(base, image_key, index)
        if self.position == "center":
            x, y = (width - size) // 2 + dx + mx, (height - size) // 2 + dy + my
        else:
            # the path runs inward from the chosen corner, like the offset
            x = dx + mx if self.position.endswith("left") else width - size - dx - mx
            y = dy + my if self.position.startswith("top") else height - size - dy - my
        if x < 0 or y < 0 or x + size > width or y + size > height:
            raise SpecError(f"patch at ({x},{y}) size {size} falls outside a {width}x{height} image")
        return self._placement(x, y, size, block)

    def block_px(self, width: int, height: int) -> int:
        """The texture's block in stored pixels on a width x height picture (before the patch's
        side caps it). With sift_edge, measured on the picture as SIFT sees it and scaled back."""
        seen = min(1.0, self.sift_edge / max(width, height)) if self.sift_edge else 1.0
        seen_width = max(1, math.floor(length_base(width, height) * seen + 0.5))
        block = resolve_length(self.block_size, seen_width)
        if isinstance(self.block_size, float) and self.block_size < 1:
            block = max(block, MIN_BLOCK_PX)
        return block if seen >= 1.0 else math.floor(block / seen + 0.5)  # whole pixels

    def too_small(self, width: int, height: int) -> str | None:
        """Why a width x height picture cannot hold this mark (None: it can): it does not fit, or its
        squares would be one flat block, no texture for SIFT (a 64x64 photo: a 4 px square of one 4 px
        block had been called patched; a black-box review)."""
        try:
            one = self.resolve(width, height, index=0)
        except SpecError as exc:  # its own words: which part does not fit, and what to change
            return f"{width}x{height} cannot hold the mark: {exc}"
        side = one.lane_size or one.texture_size or one.size
        if side <= one.block:
            flat = f"its {side} px squares would be one flat block"
            return f"{width}x{height} is too small for the mark: {flat}"
        return None

    def _placement(self, x: int, y: int, size: int, block: int, **tumble: Any) -> PatchPlacement:
        if self.mark_text or self.mark_image:
            try:  # a bad logo file or unrenderable text is the spec's error, said before any pixel is written
                mark_shape(self.mark_text, self.mark_image, tumble.get("texture_size") or size)
            except LogoError as exc:
                raise SpecError(str(exc)) from exc
        return PatchPlacement(
            x=x,
            y=y,
            size=size,
            block=block,
            alpha8=int(math.floor(255 * self.alpha + 0.5)),
            contrast=int(self.contrast),
            pattern=self.pattern,
            seed=self.seed,
            mark_text=self.mark_text,
            mark_image=self.mark_image,
            **tumble,
        )

    def _resolve_tumble(
        self, width: int, height: int, texture: int, block: int, image_key: str | None, index: float | None
    ) -> PatchPlacement:
        """A corner mark: turned, scaled and shifted per image inside the corner region.

        The region is corner_region x width by corner_region x height at the chosen corner; the
        offset is not used (the shift inside the region replaces it). The mark must fit the region
        at its largest (scale 1, turned 45 degrees) or the spec is refused for this image size.
        """
        rw, rh = int(self.corner_region * width), int(self.corner_region * height)
        if tumble_extent(texture, 1.0, 45.0) > min(rw, rh):
            raise SpecError(
                f"a {texture} px mark turned 45 deg does not fit the {rw}x{rh} px corner region of a "
                f"{width}x{height} image; use a smaller patch_size or a larger corner_region"
            )
        if index is None:
            index = image_index(image_key) if image_key is not None else 0
        pose = spin_pose if self.motion == "spin" else tumble_pose
        angle, scale, fx, fy = pose(index, self.seed, self.tumble_scale)
        size = tumble_extent(texture, scale, angle)
        dx, dy = int(round(fx * (rw - size))), int(round(fy * (rh - size)))
        x = dx if self.position.endswith("left") else width - size - dx
        y = dy if self.position.startswith("top") else height - size - dy
        return self._placement(x, y, size, block, texture_size=texture, angle=angle, scale=scale)

    def _resolve_lanes(
        self,
        width: int,
        height: int,
        size: int,
        block: int,
        offset: tuple[int, int],
        image_key: str | None,
        index: float | None,
        lanes_at: tuple[tuple[int, int], ...] | None = None,
        crop: int = 0,
    ) -> PatchPlacement:
        """Several slide marks in one square box anchored at the corner (the box's other pixels
        are left alone: patch_coverage); lanes_at: each lane's own top-left anchor (top-left only);
        crop: each square's side as written (its texture cropped, the lanes' layout and slide kept)."""
        base = length_base(width, height)
        step = resolve_length(self.motion_step, base) if self.motion_step != 0 else 0
        span = resolve_length(self.motion_span, base)
        if index is None:
            index = image_index(image_key) if image_key is not None else 0
        size = min(size, self._lane_cap(width, height))
        if crop < 0:
            raise SpecError(f"crop must be >= 0, got {crop}")
        shown = size if crop == 0 or crop >= size else crop
        pitch = round(size * 7 / 6)
        left, top = self.position.endswith("left"), self.position.startswith("top")
        lanes = []
        if lanes_at is not None and (len(lanes_at) != self.lanes or not (left and top)):
            raise SpecError(f"lanes_at needs {self.lanes} anchors and a top-left position")
        for k in range(self.lanes):
            mx, my = self._slide_offset(index, step * (k + 1), span)
            if lanes_at is not None:
                lanes.append((lanes_at[k][0] + mx, lanes_at[k][1] + my))
                continue
            inward_y = offset[1] + k * pitch + my
            x = offset[0] + mx if left else width - shown - offset[0] - mx
            y = inward_y if top else height - shown - inward_y
            lanes.append((x, y))
        x0, y0 = min(x for x, _ in lanes), min(y for _, y in lanes)
        x1, y1 = max(x for x, _ in lanes) + shown, max(y for _, y in lanes) + shown
        side = max(x1 - x0, y1 - y0)
        bx, by = (x0 if left else x1 - side), (y0 if top else y1 - side)
        # The box is square, its side the lanes' longer extent: on the other axis it can pass the
        # frame's edge while every lane is inside (split lanes; a video's mark anchored at the far
        # edge of its path, its lanes slid along: it slides back inside the frame, the lanes unmoved.
        bx, by = max(0, min(bx, width - side)), max(0, min(by, height - side))
        if x0 < 0 or y0 < 0 or x1 > width or y1 > height or side > min(width, height):
            raise SpecError(f"{self.lanes} lanes of {size} px do not fit a {width}x{height} image")
        parts = tuple(
            (x - bx, y - by, self.seed + LANE_SEED_STEP * k) for k, (x, y) in enumerate(lanes)
        )
        cropped = {"lane_crop": shown} if shown < size else {}
        return self._placement(bx, by, side, block, parts=parts, lane_size=size, **cropped)

    def _stacked_anchors(self, width: int, height: int, at: tuple[int, int]) -> tuple[tuple[int, int], ...]:
        """Each lane's anchor in the stacked layout from one (lanes_at's form: may lie before the edge)."""
        size = min(resolve_length(self.patch_size, length_base(width, height)), self._lane_cap(width, height))
        pitch = round(size * 7 / 6)
        return tuple((at[0], at[1] + k * pitch) for k in range(self.lanes))

    def _slide_offset(self, index: float, step: int, span: int) -> tuple[int, int]:
        """Inward (dx, dy) on the slide path: along x, or along (slide_run, 1) when tilted."""
        if self.slide_run:
            return tilted_slide_offset(index, step, span, self.slide_run)
        return path_offset("slide", index, step, span)

    def capped_side(self, width: int, height: int) -> tuple[int, int] | None:
        """(the lane side patch_size asks for, the side the visibility budget allows) on a width x
        height picture when the budget is the smaller (a lanes mark only; None otherwise)."""
        if self.lanes <= 1:  # one square is not capped (resolve: only a mark of lanes is)
            return None
        asked = resolve_length(self.patch_size, length_base(width, height))
        allowed = self._lane_cap(width, height)
        return (asked, allowed) if allowed < asked else None

    def _lane_cap(self, width: int, height: int) -> int:
        """Largest lane side within LANES_MAX_AREA and stacked inside corner_region of the height
        (less the y a tilted slide travels)."""
        by_area = math.isqrt(int(LANES_MAX_AREA / self.lanes * width * height))
        span = resolve_length(self.motion_span, length_base(width, height))
        rise = span // self.slide_run if self.slide_run else 0
        by_height = int((int(self.corner_region * height) - rise) / (1 + 7 / 6 * (self.lanes - 1)))
        return max(MIN_BLOCK_PX, min(by_area, by_height))

    def _motion_offset(self, width: int, image_key: str | None, index: float | None) -> tuple[int, int]:
        """Inward (dx, dy) of this image's point on the motion path (centred for "center")."""
        if self.motion == "static" or self.motion_step == 0:
            return (0, 0)
        step = resolve_length(self.motion_step, width)
        span = resolve_length(self.motion_span, width)
        if index is None:
            index = image_index(image_key) if image_key is not None else 0
        if self.motion == "slide":
            mx, my = self._slide_offset(index, step, span)
        else:
            mx, my = path_offset(self.motion, index, step, span)
        if self.position == "center":
            return (mx - span // 2, my - span // 2)
        return (mx, my)

    @property
    def corner_bound(self) -> bool:
        """Whether the mark lives in one corner region (the corner is `position`): a dataset's
        corner can then be chosen off its subject (poisoner.subject.dataset_corner)."""
        moving = self.motion in CORNER_MOTIONS or self.motion == "slide"
        return self.position not in ("center", AUTO) and moving

    @property
    def per_photo(self) -> bool:
        """Whether each photo's mark goes where that photo is plainest (position "auto", issue 25)."""
        return self.position == AUTO

    def path_extent(self, width: int, height: int) -> tuple[int, int]:
        """(w, h) px the mark covers over its whole path from a top-left anchor (every index)."""
        base = length_base(width, height)
        if self.lanes > 1 or self.motion == "slide":
            span = resolve_length(self.motion_span, base)
            one = self.replace(position="top-left", offset=(0, 0)).resolve(width, height, index=0)
            size = one.lane_size or one.size
            rise = span // self.slide_run if self.slide_run else 0
            pitch = round(size * 7 / 6)
            return (span + size, rise + (self.lanes - 1) * pitch + size)
        one = self.replace(position="top-left", offset=(0, 0)).resolve(width, height, index=0)
        span = resolve_length(self.motion_span, base) if self.moves else 0
        return (one.size + span, one.size + span)

    def auto_anchor(self, width: int, height: int) -> tuple[int, int]:
        """The preferred anchor of a per-photo mark: its whole path centred across the top of the
        frame. Where the top is as plain as anywhere, every photo takes this one, so the lanes move
        between photos exactly as in one fixed place; off the four corners, which an attacker
        who masks corners (the `masked` profile) removes. A tilted slide's anchor sits as far below
        the top edge as the slide's line drops from the left corner region to it (20 px on an
        800 px frame), so that other photos' anchors can move either way along that line
        (poisoner.placement.choose_spot) without leaving the frame."""
        ew, eh = self.path_extent(width, height)
        x = max(0, (width - ew) // 2)
        if not self.slide_run:
            return (x, 0)
        drop = math.ceil(max(0, x - int(self.corner_region * width)) / self.slide_run)
        return (x, max(0, min(drop, height - eh)))

    @property
    def slide_direction(self) -> tuple[int, int]:
        """The direction (whole px) the mark slides along between photos: (slide_run, 1), or along x."""
        return (self.slide_run, 1) if self.slide_run else (1, 0)

    @property
    def moves(self) -> bool:
        """Whether the placement depends on the image (its file name)."""
        return self.motion in CORNER_MOTIONS or (self.motion != "static" and self.motion_step != 0)

    # ---- poisoning ratio ------------------------------------------------------------------
    def selects(self, image_key: str) -> bool:
        """Whether the image named image_key carries the patch under this spec's ratio.

        A keyed hash of the name, so the choice is deterministic, independent of the order
        images arrive in, and stable when images are added later.
        """
        if self.ratio >= 1.0:
            return True
        if self.ratio <= 0.0:
            return False
        digest = hashlib.sha256(f"{self.seed}:{image_key}".encode()).digest()
        return int.from_bytes(digest[:8], "big") / 2**64 < self.ratio

    # ---- serialisation --------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["offset"] = list(self.offset)
        for name, default in NEW_FIELD_DEFAULTS.items():
            if d[name] == default and type(d[name]) is type(default):
                del d[name]  # keeps the spec_id of every spec stored before these fields
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PatchSpec:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise SpecError(f"unknown spec field(s): {', '.join(sorted(unknown))}")
        kwargs = dict(data)
        if "offset" in kwargs:
            kwargs["offset"] = tuple(kwargs["offset"])
        return cls(**kwargs)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> PatchSpec:
        return cls.from_dict(json.loads(text))

    def to_toml(self) -> str:
        lines = []
        for k, v in self.to_dict().items():
            if isinstance(v, str):
                lines.append(f'{k} = "{v}"')
            elif isinstance(v, list):
                lines.append(f"{k} = [{', '.join(repr(x) for x in v)}]")
            else:
                lines.append(f"{k} = {v!r}")
        return "\n".join(lines) + "\n"

    @classmethod
    def from_toml(cls, text: str) -> PatchSpec:
        data = tomllib.loads(text)
        return cls.from_dict(data.get("patch", data))

    @classmethod
    def load(cls, path: Path) -> PatchSpec:
        text = Path(path).read_text()
        if str(path).endswith(".json"):
            return cls.from_json(text)
        return cls.from_toml(text)

    def replace(self, **changes: Any) -> PatchSpec:
        return dataclasses.replace(self, **changes)

    @property
    def spec_id(self) -> str:
        """A short content hash: equal specs share an id in the store."""
        return hashlib.sha256(self.to_json().encode()).hexdigest()[:16]
