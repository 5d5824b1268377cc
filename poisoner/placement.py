"""Where the mark goes in each photo (issue 25, the default design's position "auto"):
`place_on_photo` / `choose_spot` below, pure functions (arrays in, answers out). A corner spec's one
corner per dataset (issue 14) is poisoner.corner.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from poisoner.array_search import integral_image, lexsort_first, lexsort_head
from poisoner.mark_place import MarkPlace
from poisoner.orientation import INVERSE_ORIENTATION, display_size, orientation_of, turn_square
from poisoner.spec import PatchPlacement, PatchSpec

# ---- per-photo placement (issue 25) ---------------------------------------------------------------
# One dataset-wide corner lands on the subject whenever the subject fills that corner in some views (13 of
# 25 views of a subject-filling capture), and an attacker who masks the four corners removes it. So each
# photo gets its own place, in what a viewer sees (EXIF orientation applied): the plainest spot for the
# mark's footprint in that photo (no subject pixel where masks are given, the least image detail
# otherwise), anywhere in the frame, ties going to one preferred anchor (the top edge's centre) so that
# the photos of a plain-background set share their anchor and the lanes move between them exactly as the
# measured corner lanes did.

# A footprint with at most this much detail cost is plain: all plain places are equally good, so the
# preferred anchor wins (round 2: shares of 0.01 against 0.00 had moved 11 of dtu_scan37's 25 marks off
# their shared anchor, breaking the lanes' common motion between those photos).
PLAIN_SHARE = 0.02
COST_STEP = 0.02  # detail shares within one step are equally plain: the preferred anchor decides
GRID = 24  # candidate anchors per frame side (the stride is the shorter side / GRID)
MARGIN = 0.03  # of the shorter side: the footprint is judged grown by this much ("away from")
# Without masks a plain patch inside the frame may be part of the subject (a white ruler, a blade's
# highlight); the frame's border band rarely is. A footprint d (fraction of the shorter side) from
# the nearest edge costs EDGE_WEIGHT * d, as if that share of it held detail.
EDGE_WEIGHT = 0.5
# Round 2 (the masked attacker): the four corner regions (this share of the width and of the height)
# are what the `masked` profile removes; a plain place off them wins over a plain corner.
CORNER_REGION = 0.2
# Round 7 (no masks): a plain place is doubtful when one of its squares, grown by the margin, holds more than
# this share of FAINT detail (poisoner.subject.FAINT_LEVEL): a subject's face may look plain at DETAIL_LEVEL
# where it shows a photo of what lies beside it (creator-fill: pavement on the box's lower face just above
# the real pavement, their edge too faint to count; 0.09 to 0.16 on the three views whose mark touched it).
# A studio backdrop has next to no faint texture: at most 0.036 at the places lego, dtu_scan37 (800 and
# 1600 px) and the dtu/lego fill crops get, none doubtful, so their marks stay where they were, byte for
# byte. A doubtful place is kept unless each square finds its own place, plain and not doubtful, off any
# corner region the stacked mark kept off (place_on_photo); moving the stacked mark to a less faint place
# instead moved creator-fill's view_16 onto the box's plain lower-left corner.
FAINT_DOUBT = 0.06


@dataclass(frozen=True)
class Spot:
    """The anchor (display px) chosen for a photo's mark and how plain its footprint is there.

    detail: share of the footprint (grown by the margin) holding image detail; subject: share on
    the subject mask (None without one); free: no subject pixel (masks) / plain (no masks)."""

    x: int
    y: int
    detail: float
    subject: float | None
    free: bool
    plain: bool = True  # plain with the margin (False: the fallback without it, or nowhere plain)
    doubtful: bool = False  # plain, but its faint share is above FAINT_DOUBT (round 7)
    cornered: bool = False  # reaches into a corner region (what the masked attacker removes)


def _axis(lo: int, hi: int, preferred: int, stride: int) -> np.ndarray:
    """Sorted anchors on one axis: the preferred, each stride either way, both ends (np.unique: numpy.ma)."""
    if hi < lo:
        return np.array([], dtype=np.int64)
    p = min(max(preferred, lo), hi)
    below = np.arange(p, lo - 1, -stride) if stride > 0 else np.array([p])
    above = np.arange(p, hi + 1, stride) if stride > 0 else np.array([p])
    return np.array(sorted({*below.tolist(), *above.tolist(), lo, hi}), dtype=np.int64)


def _rect_sums(
    integral: np.ndarray, x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray
) -> np.ndarray:
    """Sums of a map over [y0, y1) x [x0, x1) from its integral image (one row/column of zeros first)."""
    return integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]


def _line(
    preferred: tuple[int, int], direction: tuple[int, int], xr: tuple[int, int], yr: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Every whole-step anchor on the line through `preferred` along `direction` (either way) whose
    x and y stay within the ranges (inclusive)."""
    dx, dy = direction
    reach = max(xr[1] - xr[0], yr[1] - yr[0]) // max(1, min(abs(dx) or 1, abs(dy) or 1)) + 1
    u = np.arange(-reach, reach + 1)
    lx, ly = preferred[0] + dx * u, preferred[1] + dy * u
    ok = (lx >= xr[0]) & (lx <= xr[1]) & (ly >= yr[0]) & (ly <= yr[1])
    return lx[ok].astype(np.int64), ly[ok].astype(np.int64)


def _in_corners(
    ax: np.ndarray,
    ay: np.ndarray,
    rects: list[tuple[int, int, int, int]],
    size: tuple[int, int],
    region: float,
) -> np.ndarray:
    """1 where any part of the mark at anchor (ax, ay) overlaps one of the four corner regions."""
    w, h = size
    rw, rh = int(region * w), int(region * h)
    hit = np.zeros(ax.shape, dtype=bool)
    for x0, y0, x1, y1 in rects:
        left, right = ax + x0 < rw, ax + x1 > w - rw
        top, bottom = ay + y0 < rh, ay + y1 > h - rh
        hit |= (left | right) & (top | bottom)
    return hit.astype(np.int64)


def _anchor_range(lo: int, hi: int, side: int, reach: bool) -> tuple[int, int]:
    """The anchors on one axis of a mark covering lo..hi relative to its anchor, in a frame `side` px
    long. The anchor is where the mark's path starts, so by default never left of or above the frame;
    with reach it may be, as far as this photo's squares, slid along the path, stay inside (a plain
    strip at the left edge narrower than the slide: 15 of 24 such masked photos failed, none at the
    right edge; only with masks, where the frame holds no better place: place_on_photo)."""
    return (-lo if reach else max(0, -lo), side - hi)


def _better(reached: Spot, spot: Spot) -> bool:
    """Whether a place found with reach beats one found without it: freer of the subject, else off
    the corner regions where the other is not, else plain where the other is not (a plain place in a
    corner is not worth the split lanes off it that a place not plain leads to; a shade less detail
    is not worth moving a mark that was measured)."""

    def rank(s: Spot) -> tuple[bool, float, bool, bool]:
        return (not s.free, round(s.subject or 0.0, 6), s.cornered, not s.plain)

    return rank(reached) < rank(spot)


def choose_spot(
    detail: np.ndarray,
    subject: np.ndarray | None,
    size: tuple[int, int],
    rects: list[tuple[int, int, int, int]],
    preferred: tuple[int, int],
    bounds: tuple[int, int, int, int] | None = None,
    direction: tuple[int, int] = (1, 0),
    corner_region: float = CORNER_REGION,
    faint: np.ndarray | None = None,
    reach: bool = False,
) -> Spot:
    """The anchor for a mark whose parts cover `rects` (display px, relative to the anchor) in a
    frame of `size` (w, h) display px: the plainest place, judged on `detail` (a thumbnail of the
    frame, True/1 = image detail) and `subject` (same grid, True = subject; None: no mask).

    Order: no subject pixel first (masks), then the least detail (every footprint up to PLAIN_SHARE
    equally plain, then COST_STEP steps), then off the four corner regions (what the masked attacker
    removes), then on the line through `preferred` along `direction` (the mark's own slide direction:
    two photos whose anchors differ along it still show the lanes moving in parallel by different
    amounts, one consistent phantom geometry; any other shift breaks it for that pair), then the
    nearest to `preferred`, then top-left first: deterministic for a given picture. bounds
    (relative to the anchor, default: the rects' union) must lie inside the frame. faint: the
    detail map at a lower level (same grid; None: not checked; only without masks): the spot is
    said `doubtful` where it is plain but a square's faint share is above FAINT_DOUBT. reach: the
    anchor may also lie left of or above the frame (_anchor_range)."""
    w, h = size
    th, tw = detail.shape
    sx, sy = tw / w, th / h
    margin = max(1, round(MARGIN * min(w, h)))
    rx0, ry0, rx1, ry1 = bounds or (
        min(r[0] for r in rects), min(r[1] for r in rects), max(r[2] for r in rects), max(r[3] for r in rects)
    )
    stride = max(1, min(w, h) // GRID)
    xr, yr = _anchor_range(rx0, rx1, w, reach), _anchor_range(ry0, ry1, h, reach)
    xs, ys = _axis(*xr, preferred[0], stride), _axis(*yr, preferred[1], stride)
    if xs.size == 0 or ys.size == 0:
        raise ValueError(f"the mark ({rx1 - rx0}x{ry1 - ry0} px) does not fit a {w}x{h} frame")
    gx, gy = (a.ravel() for a in np.meshgrid(xs, ys))
    lx, ly = _line(preferred, direction, xr, yr)
    ax, ay = np.concatenate([gx, lx]), np.concatenate([gy, ly])

    maps = {"detail": integral_image(detail)}
    if subject is not None:
        maps["subject"] = integral_image(subject)
    inward = np.minimum.reduce([ax + rx0, ay + ry0, w - (ax + rx1), h - (ay + ry1)]) / min(w, h)
    cornered = _in_corners(ax, ay, rects, (w, h), corner_region)
    dx, dy = direction
    off_line = np.abs((ax - preferred[0]) * dy - (ay - preferred[1]) * dx)  # x |direction|: same order
    distance = (ax - preferred[0]) ** 2 + (ay - preferred[1]) ** 2

    core, _ = _shares(maps, rects, ax, ay, 0, (sx, sy))

    def best_at(grow: int) -> tuple[int, np.ndarray, np.ndarray, bool]:
        share, on_subject = _shares(maps, rects, ax, ay, grow, (sx, sy))
        cost = share + EDGE_WEIGHT * np.maximum(inward, 0)
        # plain: a little detail in the margin, none under the squares themselves (a plain-looking
        # place whose squares reach a subject's edge is not plain)
        steps = np.where((cost <= PLAIN_SHARE) & (core == 0), 0, np.ceil(cost / COST_STEP) + 1)
        # lexsort: the last key is the primary one
        best = lexsort_first((ax, ay, distance, off_line, cornered, steps, np.round(on_subject, 6)))
        return best, share, on_subject, bool(on_subject[best] == 0 and steps[best] == 0)

    best, share, on_subject, plain = best_at(margin)
    doubtful, one = False, slice(best, best + 1)
    if plain and faint is not None and subject is None:  # round 7
        doubtful = bool(_doubtful(faint, rects, ax[one], ay[one], margin, (sx, sy))[0])
    if not plain:
        # Nowhere plain with the margin (a subject filling the frame, a small backdrop): the place
        # where the squares themselves are plainest, even close to the subject, beats one on it.
        best, share, on_subject, _ = best_at(0)
    subject_share = float(on_subject[best]) if subject is not None else None
    # without masks, only a place plain with its margin is called free: the fallback's low detail
    # may be a plain part of the subject (a stone's smooth face, a ruler), so ppd says so
    free = subject_share == 0.0 if subject_share is not None else plain
    return Spot(int(ax[best]), int(ay[best]), float(share[best]), subject_share, free, plain, doubtful,
                bool(cornered[best]))  # fmt: skip


def _doubtful(
    faint: np.ndarray,
    rects: list[tuple[int, int, int, int]],
    ax: np.ndarray,
    ay: np.ndarray,
    margin: int,
    scale: tuple[float, float],
) -> np.ndarray:
    """Round 7: True at each anchor where a square, grown by the margin, holds more than FAINT_DOUBT
    faint detail. Each square on its own: the sliver of a subject's face that one square reaches is
    half as much of both."""
    maps = {"detail": integral_image(faint)}
    share = np.maximum.reduce([_shares(maps, [r], ax, ay, margin, scale)[0] for r in rects])
    return np.asarray(np.round(share, 6) > FAINT_DOUBT)


SPLIT_CANDIDATES = 80  # best places kept per square when each square looks for its own
# Round 4: each square alone looks on a finer grid than the stacked mark (GRID): the plain pockets a subject
# filling the frame leaves along the edges are a few strides of GRID wide, and a square with its margin fits
# them only at some anchors (fountain-fill's pavement corner). Reached only where no place holds the
# stacked mark plain: a photo that has one is placed as before.
SPLIT_GRID = 96


def split_gap(side: int) -> int:
    """How far apart, in x or y, choose_split keeps two squares of this side: a sixth of a side."""
    return max(1, side // 6)


def _badness(
    maps: dict[str, np.ndarray],
    rects: list[tuple[int, int, int, int]],
    ax: np.ndarray,
    ay: np.ndarray,
    margin: int,
    scale: tuple[float, float],
    inward: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(badness, core detail share, core subject share) of a mark's parts at each anchor, one number
    in choose_spot's two-pass order: 0 = no subject and plain with the margin; then by the subject
    and detail under the parts themselves. inward (without masks): each anchor's distance from the
    nearest frame edge (share of the shorter side), costed as choose_spot costs it."""
    share_m, subject_m = _shares(maps, rects, ax, ay, margin, scale)
    core, subject_c = _shares(maps, rects, ax, ay, 0, scale)
    edge = 0.0 if inward is None else EDGE_WEIGHT * np.maximum(inward, 0)
    plain = (share_m + edge <= PLAIN_SHARE) & (core == 0) & (subject_m == 0)
    fallback = 1 + (subject_c > 0) * 1000 + np.ceil(np.round(core + edge, 6) / COST_STEP)
    return np.where(plain, 0, fallback), core, subject_c


def choose_split(
    detail: np.ndarray,
    subject: np.ndarray | None,
    size: tuple[int, int],
    lane_rects: list[tuple[int, int, int, int]],
    preferred: list[tuple[int, int]],
    direction: tuple[int, int] = (1, 0),
    corner_region: float = CORNER_REGION,
    faint: np.ndarray | None = None,
) -> tuple[list[Spot], float] | None:
    """Each lane's square in its own place (round 2: a subject filling the frame leaves plain places
    too small for the stacked lanes): lane k's square covers lane_rects[k] relative to its anchor,
    its preferred anchor preferred[k] (the stacked layout's), candidates on its own line along
    `direction` first, as in choose_spot, so lanes that split stay on the lines the stacked lanes
    move along. The pair is the best of each square's SPLIT_CANDIDATES places that do not overlap
    (a sixth of a square apart) and fit one square box inside the frame, worst square first.
    Returns (spots, worst badness) or None when no pair fits. faint (round 7, a doubtful stacked
    place's split): a plain square doubtful by it (_doubtful) has badness 0.5."""
    w, h = size
    th, tw = detail.shape
    scale = (tw / w, th / h)
    margin = max(1, round(MARGIN * min(w, h)))
    stride = max(1, min(w, h) // SPLIT_GRID)
    maps = {"detail": integral_image(detail)}
    if subject is not None:
        maps["subject"] = integral_image(subject)
    picks = []
    for (x0, y0, x1, y1), pref in zip(lane_rects, preferred, strict=True):
        xr, yr = _anchor_range(x0, x1, w, False), _anchor_range(y0, y1, h, False)
        xs, ys = _axis(*xr, pref[0], stride), _axis(*yr, pref[1], stride)
        if xs.size == 0 or ys.size == 0:
            return None
        gx, gy = (a.ravel() for a in np.meshgrid(xs, ys))
        lx, ly = _line(pref, direction, xr, yr)
        ax, ay = np.concatenate([gx, lx]), np.concatenate([gy, ly])
        # round 4: without masks a split square, like the stacked mark, is plain only near an edge (a
        # plain patch inside the frame may be the subject's smooth face: fountain-fill's basin)
        inward = _inward(ax, ay, (x0, y0, x1, y1), size) if subject is None else None
        bad, core, subj = _badness(maps, [(x0, y0, x1, y1)], ax, ay, margin, scale, inward)
        if faint is not None:
            bad = np.where((bad == 0) & _doubtful(faint, [(x0, y0, x1, y1)], ax, ay, margin, scale), 0.5, bad)
        cornered = _in_corners(ax, ay, [(x0, y0, x1, y1)], size, corner_region)
        off_line = np.abs((ax - pref[0]) * direction[1] - (ay - pref[1]) * direction[0])
        distance = (ax - pref[0]) ** 2 + (ay - pref[1]) ** 2
        o = lexsort_head((ax, ay, distance, off_line, cornered, bad), SPLIT_CANDIDATES)
        picks.append((ax[o] + x0, ay[o] + y0, bad[o], core[o], subj[o], ax[o], ay[o]))
    (px, py, pb, pc, ps, pax, pay), (qx, qy, qb, qc, qs, qax, qay) = picks[0], picks[1]
    side = lane_rects[0][2] - lane_rects[0][0]
    gap = split_gap(side)
    i, j = np.meshgrid(np.arange(px.size), np.arange(qx.size), indexing="ij")
    apart = (np.abs(px[i] - qx[j]) >= side + gap) | (np.abs(py[i] - qy[j]) >= side + gap)
    box = np.maximum(np.abs(px[i] - qx[j]), np.abs(py[i] - qy[j])) + side
    ok = apart & (box <= min(w, h))
    if not ok.any():
        return None
    worst, total, rank = np.maximum(pb[i], qb[j]), pb[i] + qb[j], i + j
    flat = np.lexsort((rank.ravel(), total.ravel(), worst.ravel(), ~ok.ravel()))
    a, b = np.unravel_index(flat[0], ok.shape)
    spots = []
    for (xx, yy, cc, ss, bb), k in (((pax, pay, pc, ps, pb), a), ((qax, qay, qc, qs, qb), b)):
        subject_share = float(ss[k]) if subject is not None else None
        free = subject_share == 0.0 if subject_share is not None else bool(bb[k] == 0)
        spots.append(Spot(int(xx[k]), int(yy[k]), float(cc[k]), subject_share, free, bool(worst[a, b] == 0)))
    return spots, float(worst[a, b])


def _inward(
    ax: np.ndarray, ay: np.ndarray, box: tuple[int, int, int, int], size: tuple[int, int]
) -> np.ndarray:
    """How far a box (relative to each anchor) lies from the nearest frame edge, as a share of the
    frame's shorter side (choose_spot's `inward`)."""
    (x0, y0, x1, y1), (w, h) = box, size
    return np.minimum.reduce([ax + x0, ay + y0, w - (ax + x1), h - (ay + y1)]) / min(w, h)


def most_plain_count(cells: int) -> int:
    """The most detail cells a footprint of `cells` cells may hold and still be plain: the largest
    count c with c / cells <= PLAIN_SHARE exactly as float division decides it, so comparing whole
    counts with it answers as comparing the shares does (-1: not even an empty footprint)."""
    c = math.floor(PLAIN_SHARE * cells)
    while (c + 1) / cells <= PLAIN_SHARE:
        c += 1
    while c >= 0 and c / cells > PLAIN_SHARE:
        c -= 1
    return c


def _shares(
    maps: dict[str, np.ndarray],
    rects: list[tuple[int, int, int, int]],
    ax: np.ndarray,
    ay: np.ndarray,
    grow: int,
    scale: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """(detail share, subject share) of the mark's parts at each anchor, each part grown by `grow`
    px, counted in thumbnail cells (outward); the subject share is 0 without a subject map."""
    sx, sy = scale
    th, tw = (n - 1 for n in maps["detail"].shape)
    sums = {k: np.zeros(ax.shape) for k in maps}
    area = np.zeros(ax.shape)
    for x0, y0, x1, y1 in rects:
        cx0 = np.clip(np.floor((ax + x0 - grow) * sx), 0, tw).astype(np.int64)
        cy0 = np.clip(np.floor((ay + y0 - grow) * sy), 0, th).astype(np.int64)
        cx1 = np.clip(np.ceil((ax + x1 + grow) * sx), 0, tw).astype(np.int64)
        cy1 = np.clip(np.ceil((ay + y1 + grow) * sy), 0, th).astype(np.int64)
        area += np.maximum(cx1 - cx0, 0) * np.maximum(cy1 - cy0, 0)
        for k, m in maps.items():
            sums[k] += _rect_sums(m, cx0, cy0, cx1, cy1)
    area = np.maximum(area, 1)
    on_subject = sums["subject"] / area if "subject" in sums else np.zeros(ax.shape)
    return sums["detail"] / area, on_subject


def _parts(placement: PatchPlacement) -> list[tuple[int, int, int, int]]:
    """The squares a placement writes (lanes, or its box), frame coordinates."""
    if not placement.parts:
        return [placement.box]
    s = placement.lane_side
    return [(placement.x + dx, placement.y + dy, placement.x + dx + s, placement.y + dy + s)
            for dx, dy, _ in placement.parts]  # fmt: skip


def place_on_photo(
    spec: PatchSpec,
    width: int,
    height: int,
    image_key: str | None,
    orientation: int,
    detail: np.ndarray | None,
    subject: np.ndarray | None = None,
    *,
    index: float | None = None,
    split: bool = True,
    crop: int = 0,
    faint: np.ndarray | None = None,
) -> tuple[PatchPlacement, MarkPlace]:
    """A per-photo spec's placement on one stored width x height photo, in stored pixels, and where
    it shows. detail / subject: display-oriented thumbnails (True = detail / subject); detail None:
    nothing to judge on (the preferred anchor). split False: the lanes stay stacked (a video's
    keyframes: one anchor glides between them for both lanes). crop: each lane's square cropped to
    this side (poisoner.shrink). faint: choose_spot's. The mark is laid out in display space (its
    lanes slide right and down as the photo is shown) and turned back with the photo
    (PatchPlacement.turn)."""
    o = orientation_of(orientation)
    dw, dh = display_size(width, height, o)
    preferred = spec.auto_anchor(dw, dh)
    if detail is None:
        spot = Spot(preferred[0], preferred[1], 0.0, None, True)
        source = "preferred"
    else:
        zero = spec.resolve(dw, dh, image_key, index=index, anchor=(0, 0), crop=crop)
        where = (detail, subject, (dw, dh), _parts(zero), preferred, zero.box, spec.slide_direction,
                 spec.corner_region, faint)  # fmt: skip
        spot, last_resort = choose_spot(*where), None
        # Before the edge only with masks, where the frame's free places otherwise fail the photo. Without
        # masks it moved two marks of a dtu_scan37 70% crop off the subject (a cropped or split mark),
        # and the default attacker recovered 0-87% of the cameras at seeds 0-4 where it had 0% (round 8)
        reaching = subject is not None and split and not spot.plain  # a video's keyframes: never
        if reaching and _better(reached := choose_spot(*where, reach=True), spot):
            # the stacked mark where it is off the corners, else only where the lanes find no split
            # place either (what such a photo got before)
            spot, last_resort = (reached, None) if not reached.cornered else (spot, reached)
        # round 7: a doubtful plain place tries each square in its own place too
        stacked = (spot.plain and not spot.doubtful) or not split
        lanes = None if stacked else _split_lanes(spec, (dw, dh), zero, spot, detail, subject, preferred,
                                                  faint if spot.doubtful else None)  # fmt: skip
        if lanes is not None:
            return _placed(spec, (width, height), o, (image_key, index, crop), lanes, subject is not None,
                           spot.doubtful)  # fmt: skip
        spot = last_resort or spot
        if subject is not None:
            source = "masks" if spot.free else "no-free-masks"
        else:
            source = "estimated" if spot.free else "no-plain"
    shown = spec.resolve(dw, dh, image_key, index=index, anchor=(spot.x, spot.y), crop=crop)
    stored = turned_to_stored(shown, o, (dw, dh))
    place = MarkPlace(shown.box, (dw, dh), source, spot.free, spot.detail, spot.subject, o, (spot.x, spot.y))
    return stored, place


def _split_lanes(
    spec: PatchSpec,
    frame: tuple[int, int],
    zero: PatchPlacement,
    spot: Spot,
    detail: np.ndarray,
    subject: np.ndarray | None,
    preferred: tuple[int, int],
    faint: np.ndarray | None = None,
) -> list[Spot] | None:
    """Each lane's own place, when that is better than the best stacked place (None otherwise).
    faint: the stacked place is plain but doubtful (round 7): only a split whose squares are both
    plain and not doubtful is better."""
    parts = _parts(zero)
    if len(parts) < 2:
        return None
    base = [k * round(zero.lane_size * 7 / 6) for k in range(len(parts))]  # lane k's row in the stack
    rects = [(x0, y0 - b, x1, y1 - b) for (x0, y0, x1, y1), b in zip(parts, base, strict=True)]
    prefs = [(preferred[0], preferred[1] + b) for b in base]
    # never before the edge (choose_spot's reach): see place_on_photo
    found = choose_split(detail, subject, frame, rects, prefs, spec.slide_direction, spec.corner_region,
                         faint)  # fmt: skip
    if found is None:
        return None
    spots, worst = found
    if faint is not None:  # and never into a corner region the stacked place kept off
        one = np.zeros(1, dtype=np.int64)
        was_in = _in_corners(one + spot.x, one + spot.y, parts, frame, spec.corner_region)[0]
        now_in = any(_in_corners(one + s.x, one + s.y, [r], frame, spec.corner_region)[0]
                     for s, r in zip(spots, rects, strict=True))  # fmt: skip
        return spots if worst == 0 and (was_in or not now_in) else None
    at = np.array([spot.x]), np.array([spot.y])
    stacked, _, _ = _badness(
        {"detail": integral_image(detail),
         **({"subject": integral_image(subject)} if subject is not None else {})},
        parts, *at, max(1, round(MARGIN * min(frame))),
        (detail.shape[1] / frame[0], detail.shape[0] / frame[1]),
        _inward(*at, zero.box, frame) if subject is None else None,
    )  # fmt: skip
    # round 4: a split that is not plain wins by keeping more of the mark off the subject mask (badness
    # 1000 and up: on it) or by at most half the stacked mark's detail steps; a shade less detail is
    # not worth breaking the stack (the finer grid finds split squares a shade less busy on any busy
    # photo: random texture, 49 steps against 50), a nearly plain pair is (fountain-fill: 1 against 3)
    bar = float(stacked[0])
    if worst < 1 or worst // 1000 < bar // 1000:
        return spots
    steps, bar_steps = worst % 1000 - 1, bar % 1000 - 1
    return spots if worst // 1000 == bar // 1000 and 2 * steps <= bar_steps else None


def _placed(
    spec: PatchSpec,
    size: tuple[int, int],
    o: int,
    which: tuple[str | None, float | None, int],
    lanes: list[Spot],
    masked: bool,
    doubted: bool = False,
) -> tuple[PatchPlacement, MarkPlace]:
    """The placement and MarkPlace of split lanes (display anchors), turned back to stored pixels;
    which: (image_key, index, crop) as place_on_photo got them; doubted: split from a doubtful place."""
    dw, dh = display_size(*size, o)
    at = tuple((s.x, s.y) for s in lanes)
    image_key, index, crop = which
    shown = spec.resolve(dw, dh, image_key, index=index, lanes_at=at, crop=crop)
    stored = turned_to_stored(shown, o, (dw, dh))
    free = all(s.free for s in lanes)
    if masked:
        source = "masks-split" if free else "no-free-masks"
        subject: float | None = max(s.subject or 0.0 for s in lanes)
    else:
        source = ("estimated-doubt-split" if doubted else "estimated-split") if free else "no-plain"
        subject = None
    detail = max(s.detail for s in lanes)
    s, x, y = shown.lane_side, shown.x, shown.y
    # each square's box as shown, top first (the words read down the picture)
    squares = tuple(sorted(((x + dx, y + dy, x + dx + s, y + dy + s) for dx, dy, _ in shown.parts),
                           key=lambda b: (b[1], b[0])))  # fmt: skip
    place = MarkPlace(shown.box, (dw, dh), source, free, detail, subject, o, at[0], squares=squares)
    return stored, place


def turned_to_stored(shown: PatchPlacement, orientation: int, size: tuple[int, int]) -> PatchPlacement:
    """A placement laid out on the picture as shown (size: its display w, h) turned back into the
    stored pixels with the photo (PatchPlacement.turn: every writer honours it)."""
    x, y = turn_square(shown.x, shown.y, shown.size, INVERSE_ORIENTATION[orientation], *size)
    return dataclasses.replace(shown, x=x, y=y, turn=orientation)


def stored_box_shown(placement: PatchPlacement, width: int, height: int) -> tuple[int, int, int, int]:
    """A stored placement's box as shown under its own turn (the inverse of place_on_photo's turn)."""
    x, y = turn_square(placement.x, placement.y, placement.size, placement.turn, width, height)
    return (x, y, x + placement.size, y + placement.size)


def shown_squares(placement: PatchPlacement, width: int, height: int) -> list[tuple[int, int, int, int]]:
    """The squares a stored placement writes, as shown (its lanes are laid out in display space
    around the shown anchor: place_on_photo, _placed)."""
    x0, y0, _, _ = stored_box_shown(placement, width, height)
    return _parts(dataclasses.replace(placement, x=x0, y=y0))


def reaches_a_corner(
    placement: PatchPlacement, width: int, height: int, frame: tuple[int, int], region: float
) -> bool:
    """Whether a square of a stored width x height placement overlaps, as shown in `frame` (w, h),
    one of the four corner regions (`region` of each side: what the masked attacker masks), by
    choose_spot's own rule (_in_corners)."""
    at = np.zeros(1, dtype=np.int64)
    return bool(_in_corners(at, at, shown_squares(placement, width, height), frame, region)[0])

