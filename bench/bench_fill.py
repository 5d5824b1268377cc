"""Issue 25, rounds 4 and 5: subject-filling captures judged per view, fairly.

`nice -n 19 python -m bench.bench_fill touch`    every own set, no masks given to ppd (a few minutes)
`nice -n 19 python -m bench.bench_fill picture`  one view per new set with its mask outline and mark
`nice -n 19 python -m bench.bench_fill cost`     what this round's finer split grid costs

Each own set is poisoned as `ppd poison` writes it (poison_file, the default design, no masks) and
judged as round 3 judged it (bench.bench_placement judge_set: a touch is a changed pixel on the
subject, as shown). New in round 4, per view (display orientation, from the subject mask):
- `room`: the side of the largest square holding no subject pixel, against the mark's square side
  (`full`) and the smallest side ppd crops a square to (`floor`, poisoner.shrink.SHRINK_FLOOR);
- `two at floor` / `two whole`: whether two non-overlapping squares of that side fit off the subject
  (the default mark is two squares; where no place holds both, each takes its own);
so a touch where two floor-size squares had room off the subject ("a free place existed") is counted
apart from a touch where no placement could avoid the subject.
The sets: bench.bench_placement's dtu crops (70%, 55%, 70% stored with EXIF orientation 6) and
lego-fill; fountain-fill (round 3's crops of fountain-P11) judged on a per-view mask of the fountain
drawn by eye as polygons (bench/fountain_masks.json; round 3 judged a hand-marked box); creator-fill
(testkit/fill_set.py: a box of real photo faces filling about 2/3 of the frame in front of a real
photo wall and pavement, exact masks).

Results: the round 4 block at the top of bench/results/placement.md (WORK/fill.json).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw  # PIL before anything that may load pycolmap

from bench.bench_placement import (
    FILL_WORK,
    RESULTS_MD,
    ROOT,
    judge_set,
    make_crops,
    make_lego_crops,
    shown_rgb,
)
from bench.bench_shrink import make_fountain
from poisoner.placement import MARGIN, split_gap
from testkit.free_room import largest_free_square, two_fit, two_fit_within

WORK = FILL_WORK  # its own folder: other rounds' files stay as they were
POLYGONS = ROOT / "bench" / "fountain_masks.json"
PICTURE = ROOT / "bench" / "results" / "placement_fill_sets.png"
# the tables between BEGIN and END, notes (by hand) after them up to NOTES_END: bench_placement's
# write_markdown carries the whole block over when it rewrites the page
BEGIN, END, NOTES_END = "<!-- round 4 -->", "<!-- /round 4 -->", "<!-- /round 4 notes -->"


# ---- the sets ------------------------------------------------------------------------------------------
def fountain_mask(i: int, box: tuple[int, int, int, int], size: tuple[int, int]) -> np.ndarray:
    """The fountain's mask in fountain-P11's view i (a photo of `size`, w x h): its polygon, filled
    (255 = subject; `box`, round 3's judge, unused)."""
    data = json.loads(POLYGONS.read_text())
    scale = data["scale"]
    mask = Image.new("L", size, 0)
    points = [(x * scale, y * scale) for x, y in data["views"][f"{i:04d}"]]
    ImageDraw.Draw(mask).polygon(points, fill=255)
    return np.asarray(mask)


def make_set(name: str) -> tuple[Path, Path]:
    folder = WORK / name
    if name == "crop70":
        return make_crops(0.70, 1, folder)
    if name == "crop55":
        return make_crops(0.55, 1, folder)
    if name == "crop70-exif6":
        return make_crops(0.70, 6, folder)
    if name == "lego-fill":
        return make_lego_crops(0.55, folder)
    if name == "fountain-fill":  # round 3's crops (the same pixels), judged on the outline
        return make_fountain(folder, mask_of=fountain_mask)
    if name == "creator-fill":
        from testkit.fill_set import make_fill_set

        return make_fill_set(folder)
    raise SystemExit(f"unknown set {name!r}")


SETS = ("crop70", "crop55", "crop70-exif6", "lego-fill", "fountain-fill", "creator-fill")


# ---- the room off the subject (testkit/free_room.py) ---------------------------------------------------
def room(subject: np.ndarray, full: int, floor: int, margin: int) -> dict[str, Any]:
    """The view's room off the subject against the mark's sides; `two_floor_margin`: two floor-size
    squares each with ppd's margin around it (without masks ppd calls a place plain only with it)."""
    return {"room": largest_free_square(subject), "full": full, "floor": floor, "margin": margin,
            "two_whole": two_fit(subject, full), "two_floor": two_fit(subject, floor),
            "two_floor_margin": two_fit(subject, floor + 2 * margin),
            # round 5: as the mark can be placed, both squares inside one square of the shorter side;
            # 2026-11-27: and as far apart as poisoner.placement.choose_split keeps them
            "two_floor_box": two_fit_within(subject, floor, min(subject.shape), split_gap(floor)),
            }  # fmt: skip


def sides(width: int, height: int, name: str) -> tuple[int, int]:
    """(the mark's square side, the floor side) on a width x height frame as shown."""
    from poisoner.ladder import default_spec
    from poisoner.shrink import crop_sides

    p = default_spec().resolve(width, height, name)
    tried = crop_sides(p.lane_size, p.block)
    return p.lane_size, (tried[-1] if tried else p.lane_size)


# ---- the judge -----------------------------------------------------------------------------------------
def judge(name: str, give_masks: bool = False) -> dict[str, Any]:
    """A set poisoned as ppd poison writes it (no masks; give_masks: with them, as --subject-masks),
    judged per view."""
    from poisoner.ladder import default_spec

    images, masks = make_set(name)
    out = WORK / name / ("out-masks" if give_masks else "out-new")
    r = judge_set(images, masks, out, default_spec(), give_masks=give_masks)
    for v in r["per_view"]:
        subject = np.asarray(Image.open(masks / f"{Path(v['name']).stem}.png")) > 0
        full, floor = sides(subject.shape[1], subject.shape[0], v["name"])
        margin = max(1, round(MARGIN * min(subject.shape)))  # poisoner.placement's margin
        v.update(room(subject, full, floor, margin))
    views = r["per_view"]
    r.update(set=name, design="masks given" if give_masks else "per-photo (default)",
             touch_apart=sum(v["touches"] and v["two_floor"] for v in views),
             touch_free=sum(v["touches"] and v["two_floor_box"] for v in views),
             touch_margin=sum(v["touches"] and v["two_floor_margin"] for v in views),
             touch_no_room=sum(v["touches"] and not v["two_floor_box"] for v in views),
             no_room=sum(not v["two_floor_box"] for v in views))  # fmt: skip
    return r


def touch(args: argparse.Namespace) -> None:
    rows = []
    for name in args.sets.split(","):
        # with the masks: the floor, what room the masks leave ppd (exif6's masks are as shown, ppd
        # takes them in stored pixels: not given there, as in round 3)
        for give_masks in (False, True) if name != "crop70-exif6" else (False,):
            r = judge(name, give_masks)
            print(json.dumps({k: v for k, v in r.items() if k != "per_view"}), flush=True)
            rows.append(r)
    path = WORK / "fill.json"
    done = {r["set"] for r in rows}
    kept = [r for r in (json.loads(path.read_text()) if path.exists() else []) if r["set"] not in done]
    every = sorted(kept + rows, key=lambda r: (SETS.index(r["set"]), r["design"] == "masks given"))
    path.write_text(json.dumps(every))
    write_markdown(every)


# ---- the page ------------------------------------------------------------------------------------------
ABOUT = {
    "crop70": "dtu_scan37 cropped to 70% around the subject, 800x600",
    "crop55": "dtu_scan37 cropped to 55% around the subject, 800x600",
    "crop70-exif6": "crop70 stored turned with EXIF orientation 6 (judged as shown)",
    "lego-fill": "lego's first 25 views cropped to 55% around the model, 600x600",
    "fountain-fill": "fountain-P11 cropped square around the fountain, 800x800; mask: the fountain "
    "drawn by eye per view (bench/fountain_masks.json)",
    "creator-fill": "testkit/fill_set.py: a box of real photo faces in front of a real photo wall and "
    "pavement, 800x800, exact masks",
}


def write_markdown(rows: list[dict[str, Any]]) -> None:
    lines = [BEGIN, "## (a) Subject-filling captures, no masks given, judged per view: round 7", "",
             "`python -m bench.bench_fill touch` (its docstring). `touch`: views with a changed pixel on",
             "the subject (as shown); `touch, room existed`: of those, views where two squares of the",
             "floor side (half the mark's side) fit off the subject inside one square of the frame's",
             "shorter side, a sixth of a side apart (as ppd places its two squares; the gap since",
             "2026-11-27), so a placement off it existed; `no room`:",
             "views where they do not (no placement of the mark avoids the subject); `two apart`: of the",
             "touches, views where two such squares fit off the subject anywhere (round 4's judge: pockets",
             "at opposite ends of the frame count); `with margin`: of the touches, views where the two",
             "squares fit with ppd's margin around each (3% of the shorter side: without masks ppd calls",
             "a place plain only with it); `said`: views ppd reported 'no plain region'; `shrunk`: squares",
             "cropped to fit. Goal: touch <= 10% of views.", "",
             "| set | subject | touch (of N) | touch, room existed | two apart | of which with margin "
             "| touch, no room | no room | said | shrunk | goal (<= 10%) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    given = [r for r in rows if r["design"] == "masks given"]
    rows = [r for r in rows if r["design"] != "masks given"]
    for r in rows:
        n = r["views"]
        met = "met" if r["touch"] <= 0.10 * n else "**not met**"
        lines.append(f"| {r['set']} | {r['subject_share']:.0%} | {r['touch']} of {n} | {r['touch_free']} "
                     f"| {r['touch_apart']} | {r['touch_margin']} | {r['touch_no_room']} | {r['no_room']} "
                     f"| {r['said_not_free']} "
                     f"| {r['shrunk']} "
                     f"| {met} |")  # fmt: skip
    lines += ["", "Sets: " + "; ".join(f"`{r['set']}`: {ABOUT[r['set']]}" for r in rows) + ".", ""]
    if given:
        lines += ["The same sets with the subject masks given (`--subject-masks`; ppd never writes on them):",
                  "`unwritten`: the mask covered the whole mark, the file failed (never \"patched\").", "",
                  "| set | touch (of N) | no room | said 'no free region' | unwritten | shrunk |",
                  "|---|---|---|---|---|---|"]  # fmt: skip
        for r in given:
            lines.append(f"| {r['set']} | {r['touch']} of {r['views']} | {r['no_room']} "
                         f"| {r['said_not_free']} | {r['unwritten']} | {r['shrunk']} |")  # fmt: skip
        lines.append("")
    lines += ["Per view (`room`: the largest square with no subject pixel, px; `full` / `floor`: the mark's",
              "square side and the smallest side ppd crops it to; `two`: two squares of that side fit off",
              "the subject (`+ margin`: floor-size squares with ppd's margin); `touch`: a changed pixel on",
              "the subject; `said`: 'no plain region'):",
              ""]  # fmt: skip
    for r in rows:
        lines += [f"<details><summary>{r['set']}: per view</summary>", "",
                  "| view | subject | room | full / floor | two whole | two at floor | in one box | + margin "
                  "| touch | said | shrunk | place |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for v in r["per_view"]:
            yes = {True: "yes", False: "-"}
            lines.append(
                f"| {v['name']} | {v['subject_share']:.0%} | {v['room']} | {v['full']} / {v['floor']} "
                f"| {yes[v['two_whole']]} | {yes[v['two_floor']]} | {yes[v['two_floor_box']]} "
                f"| {yes[v['two_floor_margin']]} "
                f"| {'**touch**' if v['touches'] else '-'} "
                f"| {yes[v['free'] is False]} | {yes[bool(v.get('shrunk'))]} | {v['words']} |"
            )
        lines += ["", "</details>", ""]
    lines.append(END)
    block = "\n".join(lines)
    text = RESULTS_MD.read_text()
    if BEGIN in text:
        head, rest = text.split(BEGIN, 1)
        text = head + block + rest.split(END, 1)[1]
    else:  # first time: right under the page's title and its one line, notes to be written after it
        first, sep, rest = text.partition("\n\n")
        second, sep2, rest2 = rest.partition("\n\n")
        text = first + sep + second + sep2 + block + "\n\n" + NOTES_END + "\n\n" + rest2
    RESULTS_MD.write_text(text)


# ---- the cost ------------------------------------------------------------------------------------------
def cost(args: argparse.Namespace) -> None:
    """Placement alone (poisoner.shrink.place_fitting on the display thumbnail) per view of the sets, this
    round's split grid (SPLIT_GRID) against round 3's (the stacked mark's GRID) in the same process,
    interleaved, median of 5 rounds per view; the ratio's median per kind of view (whole mark plain:
    never reaches the split, so the same work; split or cropped; nowhere plain)."""
    import statistics
    import time

    from poisoner import placement
    from poisoner.ladder import default_spec
    from poisoner.shrink import place_fitting
    from poisoner.subject import display_detail

    spec, fine = default_spec(), placement.SPLIT_GRID
    kinds: dict[str, list[float]] = {}
    for name in args.sets.split(","):
        images, _ = make_set(name)
        for f in sorted(images.iterdir()):
            detail, o = display_detail(f.read_bytes(), f.name)
            with Image.open(f) as im:
                size = im.size
            times: dict[int, list[float]] = {fine: [], placement.GRID: []}
            for _ in range(5):
                for grid in times:
                    placement.SPLIT_GRID = grid
                    t = time.perf_counter()
                    _, place = place_fitting(spec, *size, f.name, o, detail)
                    times[grid].append(time.perf_counter() - t)
            placement.SPLIT_GRID = fine
            whole = place.free and not place.shrunk and place.source == "estimated"
            kind = "whole, stacked" if whole else ("split or cropped" if place.free else "nowhere plain")
            ratio = statistics.median(times[fine]) / statistics.median(times[placement.GRID])
            kinds.setdefault(kind, []).append(ratio)
    rows = [{"kind": k, "views": len(v), "ratio_median": round(statistics.median(v), 2),
             "ratio_max": round(max(v), 2)} for k, v in kinds.items()]  # fmt: skip
    print(json.dumps(rows))
    (WORK / "cost.json").write_text(json.dumps(rows))


# ---- the picture ---------------------------------------------------------------------------------------
def picture(args: argparse.Namespace) -> None:
    """A view of fountain-fill and one of creator-fill as poisoned by `touch`: the subject mask's outline
    in green, the changed pixels in red."""
    tiles = []
    for name, view in (("fountain-fill", "0005.png"), ("creator-fill", "view_12.png")):
        folder = WORK / name
        a, b = shown_rgb(folder / "images" / view), shown_rgb(folder / "out-new" / view)
        subject = np.asarray(Image.open(folder / "masks" / view)) > 0
        edge = subject ^ np.roll(subject, 1, 0) | subject ^ np.roll(subject, 1, 1)
        tile = b.copy()
        grown = edge | np.roll(edge, 1, 0) | np.roll(edge, 1, 1)
        tile[grown] = (0, 255, 0)
        tile[np.any(a != b, axis=2)] = (255, 0, 0)
        tiles.append(tile)
    gap = np.full((tiles[0].shape[0], 8, 3), 32, dtype=np.uint8)
    row = Image.fromarray(np.concatenate([tiles[0], gap, tiles[1]], axis=1))
    row = row.resize((1008, round(row.height * 1008 / row.width)), Image.Resampling.LANCZOS)
    row.quantize(256).save(PICTURE, optimize=True)  # repo-sized
    print(f"wrote {PICTURE}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="part", required=True)
    t = sub.add_parser("touch")
    t.add_argument("--sets", default=",".join(SETS))
    sub.add_parser("picture")
    c = sub.add_parser("cost")
    c.add_argument("--sets", default="crop55,fountain-fill,creator-fill")
    args = parser.parse_args(argv)
    WORK.mkdir(parents=True, exist_ok=True)
    {"touch": touch, "picture": picture, "cost": cost}[args.part](args)


if __name__ == "__main__":
    main()
