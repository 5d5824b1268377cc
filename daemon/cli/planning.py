"""`ppd poison`'s plan: one job per file (its dataset, the dataset's root, where its copy goes
with --out), checked before anything is written: one root per dataset, writable folders, the
spec each dataset gets."""

from __future__ import annotations

import contextlib
import os
import shlex
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.cli.errors import die, one_line, os_error_text
from poisoner.errors import ExitStatus

if TYPE_CHECKING:
    from daemon.cli.options import SpecOptions
    from daemon.context import AppContext
    from poisoner.spec import PatchSpec


@dataclass(frozen=True)
class Job:
    path: Path
    dataset: str
    root: Path
    out_path: Path | None


def media_files(folder: Path, *, recursive: bool = True) -> list[Path]:
    """Regular, non-hidden files under folder (hidden folders skipped too; only those right in it when
    not recursive), sorted."""
    from daemon.protect.one_file import is_ignored_name

    files = []
    for p in sorted(folder.rglob("*") if recursive else folder.glob("*")):
        rel = p.relative_to(folder)
        if any(part.startswith(".") for part in rel.parts) or is_ignored_name(p):
            continue
        if p.is_symlink() or p.is_file():  # symlinks are listed so protect_file refuses them loudly
            files.append(p)
    return files


def plan_jobs(
    ctx: AppContext, targets: list[Path], dataset: str | None, out: Path | None, dry_run: bool = False
) -> list[Job]:
    """One job per file of the targets, each with its dataset by the one rule of attribution
    (daemon.datasets.dataset.attribute: a folder is one dataset, a file belongs to its outbox dataset or
    to one named after its parent; --dataset names it, and a known name keeps its root). A dataset whose
    folder moved there (the outbox moved) follows it, unless dry_run (it exited 2: a review, F2)."""
    from daemon.cli.targets import TargetError, same_folder, user_path
    from daemon.datasets.dataset import DatasetConflict, DatasetNameError, attribute

    try:
        targets = [user_path(t) for t in targets]
        out = None if out is None else user_path(out)
    except TargetError as exc:
        raise die(exc) from None
    if out is not None and out.exists() and not out.is_dir():
        raise die(f"--out must be a folder: {out} is a file")
    jobs: list[Job] = []
    planned: set[Path] = set()  # a file named twice (`a.jpg a.jpg`, a folder and a file in it) is one job
    for target in targets:
        if not target.exists() and not target.is_symlink():
            raise die(f"{target} does not exist")
        if not (target.is_symlink() or target.is_dir() or target.is_file()):  # /dev/null, a fifo
            raise die(f"{target} is not a photo, video or folder (a device, pipe or socket); nothing done")
        try:
            name, root = attribute(ctx, target, dataset, adopt=not dry_run)
        except (DatasetConflict, DatasetNameError) as exc:
            raise die(one_line(exc)) from None
        if out is not None:
            check_out_outside(out, root, name, folder=target.is_dir())
        files = media_files(target) if target.is_dir() else [target]
        # the outbox itself: each file goes to its own outbox dataset (a first-level folder, or
        # "default" for loose files), as the daemon files it, not all to one dataset "outbox"
        per_file = dataset is None and same_folder(target, ctx.paths.outbox)
        for f in files:
            if f.absolute() in planned:
                continue
            planned.add(f.absolute())
            if per_file:
                name, root = attribute(ctx, f, None, adopt=not dry_run)
            out_path = None
            if out is not None and target.is_dir():  # OUT/DATASET/<the file's path in the dataset>:
                # a subfolder's copies never land on the dataset's other copies (OUT/castle/a.jpg)
                rel = f.relative_to(root) if f.is_relative_to(root) else f.relative_to(target)
                out_path = out.absolute() / name / rel
            elif out is not None:
                out_path = out.absolute() / f.name
            jobs.append(Job(f, name, root, out_path))
    return jobs


def check_out_outside(out: Path, root: Path, name: str, *, folder: bool) -> None:
    """--out must lie outside the dataset's folder: copies inside it would be files of the dataset
    they protect (counted as not patched yet, and a restore would put originals there); and a
    folder's copies (OUT/NAME/...) must not land in it either (`--out` its parent: over the inputs)."""
    where, source = out.resolve(), root.resolve()
    copies = (out / name).resolve() if folder else where
    if where == source or where.is_relative_to(source):
        raise die(f"--out {out} is inside the dataset's folder {root}: choose a folder outside it")
    if copies == source or copies.is_relative_to(source) or source.is_relative_to(copies):
        raise die(f"--out {out} would put the copies into the dataset's folder {root}: choose another")


def refuse_held_elsewhere(ctx: AppContext, jobs: list[Job]) -> None:
    """`--dataset NAME` on files another dataset's rows call patched: refused (exit 2), naming it. A
    black-box review: `ppd poison top/sub --dataset other --design paper` said "unchanged 6 ... other:
    nothing patched" (exit 0), the design asked for not applied, and other's folder "held 0 files". They
    stay that dataset's with its mark; taking them into another would leave one folder two marks or
    re-mark another dataset's files unasked, so the user chooses."""
    from daemon.states import FileState

    held: dict[str, list[Path]] = {}
    for job in jobs:
        row = ctx.store.file(job.path)
        if row is not None and row["dataset"] != job.dataset and row["state"] in (
                FileState.PATCHED, FileState.PENDING):  # fmt: skip
            held.setdefault(row["dataset"], []).append(job.path)
    if not held:
        return
    holder, files = max(held.items(), key=lambda item: len(item[1]))
    named = next(j.dataset for j in jobs if j.path == files[0])
    shown = f"{files[0]}{', ...' if len(files) > 1 else ''}"
    raise die(f"{len(files)} file(s) here belong to dataset {holder!r}, patched with its spec ({shown}): "
              f"--dataset {named} cannot take them (a file is one dataset's, with its mark); leave out "
              f"--dataset (`ppd dataset set {shlex.quote(holder)} ... --reprotect` changes its spec), or "
              "move them out of its folder first")  # fmt: skip


def check_dataset_roots(ctx: AppContext, jobs: list[Job]) -> None:
    from daemon.datasets.moved import moved_here

    seen: dict[str, Path] = {}
    for job in jobs:
        root = seen.setdefault(job.dataset, job.root)
        if root.absolute() != job.root.absolute():
            raise die(f"dataset {job.dataset!r} would cover both {root} and {job.root}; use --dataset")
        # patched in place, the folder is what gets published
        if (why := ctx.paths.publishes_data(job.root)) and job.out_path is None:
            raise die(f"dataset {job.dataset!r}: {why}: publishing it would publish them; move PPD_DATA_DIR "
                      "or patch a folder beside it", ExitStatus.ENVIRONMENT)  # fmt: skip
        row = ctx.store.dataset(job.dataset)
        # its folder moved there: followed by attribute (a dry run's is not, and goes on as if it were)
        if row is not None and Path(row["root"]).absolute() != job.root.absolute() and (
                moved_here(ctx, job.dataset, job.root) is None):  # fmt: skip
            raise die(
                f"dataset {job.dataset!r} already belongs to {row['root']}; name this one with --dataset NAME"
            )
        if row is None:  # a new dataset takes the config's publish folder: apart from its folder (F3)
            _check_new_publish_dir(ctx, job.dataset, job.root)


def _check_new_publish_dir(ctx: AppContext, dataset: str, root: Path) -> None:
    """A new dataset whose folder the config's publish folders lie in, or hold, is refused (exit 2)
    before it is made: its published files would be taken in as its own, and `ppd restore` would put
    the originals there (a diff review, F3); made, it would stop every command at the config's check."""
    from daemon.context import configured_publish_dirs
    from daemon.paths import publish_in_datasets

    for key, folder in configured_publish_dirs(ctx.config):
        if why := publish_in_datasets(folder, [(dataset, root)]):
            where = f"{ctx.config.source}: " if ctx.config.source else ""
            raise die(f"{where}{key}: {why}; patch a folder apart from it, or choose another publish folder")


def without_published(ctx: AppContext, jobs: list[Job]) -> tuple[list[Job], list[str]]:
    """The jobs without the files in their dataset's own publish folder when it lies inside the
    dataset's folder (stored so before `dataset set` refused it): they are its published, patched
    copies; taken in, their rows were carried over as 'moved' there, and `ppd restore` then wrote the
    unprotected originals into the publish folder (a diff review, F3). One line per such folder."""
    published: dict[str, Path | None] = {}
    kept: list[Job] = []
    left: dict[Path, int] = {}
    for job in jobs:
        if job.dataset not in published:
            row = ctx.store.dataset(job.dataset)
            stored = row["publish_dir"] if row else None
            published[job.dataset] = Path(stored).absolute() if stored else None
        folder = published[job.dataset]
        if folder is not None and job.path.absolute().is_relative_to(folder):
            left[folder] = left.get(folder, 0) + 1
            continue
        kept.append(job)
    notes = [f"left {n} file(s) in {folder}, the dataset's publish folder, as they are (published copies)"
             for folder, n in sorted(left.items())]  # fmt: skip
    return kept, notes


def check_writable(jobs: list[Job], dry_run: bool) -> list[Path]:
    """Refuse before touching anything when a folder ppd must write into is not writable
    (instead of one `[Errno 13] ... .ppd-tmp-x.jpg` per file). Returns the --out folders it made,
    deepest first, for remove_if_empty once the run is over."""
    if dry_run:
        return []
    folder = not_writable({job.path.parent for job in jobs if job.out_path is None})
    if folder is not None:
        raise die(f"folder not writable: {folder}; use --out DIR", ExitStatus.ENVIRONMENT)
    made: list[Path] = []
    for out_folder in sorted({job.out_path.parent for job in jobs if job.out_path is not None}):
        missing = [f for f in (out_folder, *out_folder.parents) if not f.exists()]
        try:
            out_folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            remove_if_empty(made)
            raise die(os_error_text(exc, hint_out=False), ExitStatus.ENVIRONMENT) from None
        made = [*missing, *made]
        if not os.access(out_folder, os.W_OK | os.X_OK):
            remove_if_empty(made)
            raise die(f"folder not writable: {out_folder}", ExitStatus.ENVIRONMENT)
    return sorted(set(made), key=lambda f: len(f.parts), reverse=True)


def not_writable(folders: Iterable[Path]) -> Path | None:
    """The first of folders (sorted) that this process cannot write into; os.access also says no to
    root on a read-only mount."""
    return next((f for f in sorted(folders) if not os.access(f, os.W_OK | os.X_OK)), None)


def remove_if_empty(folders: list[Path]) -> None:
    """The folders check_writable made, where nothing was written into them (every file failed, a
    refusal came later, Ctrl-C): an empty --out folder is not left behind. Deepest first."""
    for folder in sorted(folders, key=lambda f: len(f.parts), reverse=True):
        with contextlib.suppress(OSError):  # not empty, or gone: left as it is
            folder.rmdir()


def dataset_masks(ctx: AppContext, jobs: list[Job], given: Path | None) -> dict[str, Path | None]:
    """Each dataset's subject-mask folder (given, else its config's), checked before anything is
    written: a folder that is missing, unreadable or inside the outbox is a one-line error (exit 2;
    3 when it is the dataset's own folder that is not there: daemon.datasets.subject_masks)."""
    from daemon.datasets.subject_masks import SubjectMaskError, subject_masks_for

    masks: dict[str, Path | None] = {}
    for job in jobs:
        if job.dataset not in masks:
            try:
                masks[job.dataset] = subject_masks_for(ctx, job.dataset, given)
            except SubjectMaskError as exc:  # 3 for a dataset's folder not there (a drive unplugged)
                raise die(str(exc), exc.exit_status) from None
    return masks


def without_masks(jobs: list[Job], masks: dict[str, Path | None]) -> tuple[list[Job], list[str]]:
    """The jobs without the subject masks themselves (a folder given whole may hold its mask folder:
    DTU's `scan/image` and `scan/mask`), and one line per mask folder left as it is."""
    folders = {m.absolute() for m in masks.values() if m is not None}
    kept = [job for job in jobs if not any(job.path.absolute().is_relative_to(f) for f in folders)]
    notes = []
    for folder in sorted(folders):
        left = sum(job.path.absolute().is_relative_to(folder) for job in jobs)
        if left:
            notes.append(f"left {left} subject mask(s) in {folder} as they are (masks are never patched)")
    return kept, notes


def _masked(jobs: list[Job], dataset: str, folder: Path | None) -> tuple[int, int] | None:
    """(photos of the dataset here with a mask in folder, photos); None without a folder."""
    if folder is None:
        return None
    from poisoner.media import is_photo
    from poisoner.subject import mask_path

    names = [j.path.name for j in jobs if j.dataset == dataset and is_photo(j.path)]
    return sum(mask_path(folder, n) is not None for n in names), len(names)


def missing_mask_lines(jobs: list[Job], done: set[Path], masks: dict[str, Path | None]) -> list[str]:
    """One line per mask folder that lacks a mask for some of the photos patched here (`done`): their
    marks were placed without keep-out, which the per-file warning alone left easy to miss."""
    from poisoner.media import is_photo
    from poisoner.subject import mask_path

    lines = []
    for folder in sorted({m for m in masks.values() if m is not None}):
        paths = [j.path for j in jobs if masks.get(j.dataset) == folder and j.path in done]
        missing = [p.name for p in paths if is_photo(p) and mask_path(folder, p.name) is None]
        if missing:
            s, more = ("", "") if len(missing) == 1 else ("s", ", ...")
            lines.append(f"no subject mask in {folder} for {len(missing)} photo{s} ({missing[0]}{more}): "
                         "marked without keeping off a subject")  # fmt: skip
    return lines


def turned_mask_lines(outcomes: list[Any], masks: dict[str, Path | None]) -> list[str]:
    """One line per mask folder used on photos shown turned (EXIF orientation other than 1): their
    masks are read in the stored pixels, as COLMAP reads the photos. A mask drawn on such a photo as
    shown is refused where its shape differs (a portrait shot), and silently upside down where it does
    not (orientation 3: a black-box review found the mark on the subject, called patched)."""
    from daemon.protect.job import shown_name
    from poisoner.subject import mask_path

    turned: dict[Path, list[tuple[str, int]]] = {}
    for o in outcomes:
        folder, place = masks.get(o.dataset or ""), getattr(getattr(o, "report", None), "place", None)
        if folder is None or place is None or place.orientation == 1 or o.state != "patched":
            continue
        if mask_path(folder, o.path.name) is not None:
            turned.setdefault(folder, []).append((shown_name(o.path), place.orientation))
    lines = []
    for folder, names in sorted(turned.items()):
        (first, orientation), s = names[0], "" if len(names) == 1 else "s"
        more = "" if len(names) == 1 else ", ..."
        lines.append(f"{len(names)} photo{s} shown turned ({first}: EXIF orientation {orientation}{more}): "
                     f"their masks in {folder} were read in the files' stored pixels, as COLMAP reads them; "
                     "a mask drawn on the photo as shown must be turned back first")  # fmt: skip
    return lines


# The default's squares are 12 blocks across where its protection was measured (48 px of 4 px blocks
# at 800 px; 9 at 640 px): a square of fewer blocks gives SIFT few features of its own.
FEW_BLOCKS = 8


def small_mark_lines(outcomes: list[Any]) -> list[str]:
    """One line when some photos got squares of fewer than FEW_BLOCKS blocks across (a very small
    photo, a panorama whose height caps the squares: a black-box review found 3 x 3 blocks on a
    200 x 150 photo, said nowhere); a cropped square is said apart (place_lines)."""
    from daemon.protect.job import shown_name
    from poisoner.media import is_video

    small = []
    for o in outcomes:
        placement = getattr(getattr(o, "report", None), "placement", None)
        if o.state != "patched" or placement is None or not placement.lane_size or placement.lane_crop:
            continue
        if (across := placement.lane_size // max(1, placement.block)) < FEW_BLOCKS:
            small.append((shown_name(o.path), across, placement.lane_size, is_video(o.path)))
    if not small:
        return []
    name, across, side, _ = min(small, key=lambda item: item[1])
    videos = sum(item[3] for item in small)
    kind = "video" if videos == len(small) else "photo" if videos == 0 else "file"  # a clip is no photo
    s, which = ("", "") if len(small) == 1 else ("s", "fewest: ")  # of several, one named: which one
    return [f"{len(small)} {kind}{s} got squares of fewer than {FEW_BLOCKS} blocks across ({which}{name}: "
            f"{across} blocks, {side} px; ppd's mark was measured with 12): a small picture or a wide "
            "panorama caps them, and `ppd verify` tells whether they hold"]


def capped_lines(
    outcomes: list[Any], wanted: dict[str, PatchSpec], options: SpecOptions,
    stored: Callable[[str], PatchSpec | None] = lambda _name: None,
) -> list[str]:  # fmt: skip
    """One line per dataset whose asked patch size the visibility budget capped (the lanes' squares
    together change at most poisoner.spec.LANES_MAX_AREA of a picture): said, never silent. Asked: by
    --patch-size, or a patch_size other than the default's in the config or the dataset's spec (a
    config's 8.5% gave the default's squares in silence: a black-box review); the default's own size,
    which the budget caps on wide frames, is not the user's asking. stored: a dataset's spec in the
    store (wanted holds only the specs this run set)."""
    from poisoner.ladder import default_spec
    from poisoner.spec import LANES_MAX_AREA

    by_option = any(name == "patch_size" for name, _ in options.values)
    default_size = default_spec().patch_size
    capped: dict[str, list[tuple[int, int]]] = {}
    for o in outcomes:
        spec, report = wanted.get(o.dataset or "") or stored(o.dataset or ""), getattr(o, "report", None)
        if spec is None or report is None or o.state != "patched":
            continue
        if not by_option and spec.patch_size == default_size:
            continue
        pair = spec.capped_side(report.width, report.height)
        if pair is not None:
            capped.setdefault(o.dataset, []).append(pair)
    lines = []
    for name, pairs in sorted(capped.items()):
        asked, allowed = max(a for a, _ in pairs), min(b for _, b in pairs)
        s = "" if len(pairs) == 1 else "s"
        budget = f"the visibility budget (all squares at most {LANES_MAX_AREA:.2%} of the picture)"
        asking = "--patch-size asks" if by_option else "its spec's patch_size asks"
        lines.append(f"{name}: {asking} {asked} px squares; {budget} kept them at {allowed} px "
                     f"in {len(pairs)} photo{s}")  # fmt: skip
    return lines


def without_nested(ctx: AppContext, jobs: list[Job]) -> tuple[list[Job], list[str]]:
    """The jobs without the files of another dataset whose folder lies inside this one's (`ppd
    poison PARENT` with PARENT/inner a dataset of its own): they are that dataset's, with its spec
    and rows, so they are left to it, one line per such dataset."""
    roots = {Path(d["root"]).absolute(): d["name"] for d in ctx.store.datasets()}
    kept: list[Job] = []
    left: dict[tuple[str, Path], int] = {}
    for job in jobs:
        root, path = job.root.absolute(), job.path.absolute()
        inside = [(r, n) for r, n in roots.items() if r != root and r.is_relative_to(root)]
        inner = [(r, n) for r, n in inside if n != job.dataset and path.is_relative_to(r)]
        if not inner:
            kept.append(job)
            continue
        folder, name = max(inner, key=lambda rn: len(rn[0].parts))  # the innermost dataset holds the file
        left[(name, folder)] = left.get((name, folder), 0) + 1
    notes = []
    for (name, folder), n in sorted(left.items()):
        command = shlex.join(["ppd", "poison", str(folder)])
        notes.append(f"left {n} file(s) to dataset {name!r}, whose folder is inside: `{command}` does them")
    return kept, notes


def _flag_spec(ctx: AppContext, dataset: str, options: SpecOptions) -> PatchSpec | None:
    """The spec the flags give a dataset (on its stored or configured one); None without flags."""
    from poisoner.spec import SpecError

    if not options.given():
        return None
    base = ctx.store.dataset_spec(dataset) or ctx.config.spec_for(dataset)
    try:
        return options.build(base)
    except (SpecError, OSError, ValueError) as exc:
        raise die(one_line(exc)) from None


def apply_spec(
    ctx: AppContext, jobs: list[Job], options: SpecOptions, dry_run: bool, masks: dict[str, Path | None]
) -> tuple[dict[str, PatchSpec], list[tuple[str, str]]]:
    """The spec each dataset will use when flags were given or its corner is chosen now (set on
    new datasets now), and (dataset, line) for each new dataset's placement: per photo, or the corner
    chosen. A new dataset whose mark is corner-bound gets the corner
    daemon.datasets.subject_masks.place_corner picks over all its files given here."""
    from daemon.datasets.subject_masks import (
        corner_line,
        per_photo_line,
        place_corner,
        record_choice,
        wants_corner,
    )
    from daemon.protect.job import media_kind
    from daemon.store import DatasetSpecLocked

    wanted: dict[str, PatchSpec] = {}
    lines: list[tuple[str, str]] = []
    for name in dict.fromkeys(job.dataset for job in jobs):
        spec, choice = _flag_spec(ctx, name, options), None
        # a dataset whose spec a rebuild lost is no new one: its files say which spec it needs back
        new = ctx.store.dataset_spec(name) is None and ctx.store.lost_spec(name) is None
        base = spec or ctx.config.spec_for(name)
        if new and base.per_photo:  # issue 25: no corner for the set; each photo's own place
            clips = all(media_kind(j.path) == "video" for j in jobs if j.dataset == name)
            masked = _masked(jobs, name, masks.get(name))
            lines.append((name, per_photo_line(name, masks.get(name), masked, videos_only=clips)))
        if new and wants_corner(base, options.sets_position() or ctx.config.position_set(name)):
            placed = place_corner(base, [job.path for job in jobs if job.dataset == name], masks.get(name))
            spec, choice = placed.spec, placed.choice
            lines.append((name, corner_line(name, choice)))
        if spec is None:
            continue
        wanted[name] = spec
        try:
            if dry_run:  # refused as the real run would be, storing nothing
                ctx.store.check_spec_change(name, spec)
                continue
            ctx.store.set_dataset_spec(name, spec, root=next(j.root for j in jobs if j.dataset == name))
        except DatasetSpecLocked as exc:
            raise die(str(exc)) from None
        if choice is not None:
            record_choice(ctx, name, choice, masks.get(name))
    return wanted, lines


def output_places(jobs: list[Job]) -> list[str]:
    """Where --out put the copies: one folder per dataset (a single file: its own path)."""
    by_dataset: dict[str, list[Path]] = {}
    for job in jobs:
        if job.out_path is not None:
            by_dataset.setdefault(job.dataset, []).append(job.out_path)
    places = []
    for paths in by_dataset.values():
        places.append(str(paths[0]) if len(paths) == 1 else str(Path(os.path.commonpath(paths))) + os.sep)
    return places
