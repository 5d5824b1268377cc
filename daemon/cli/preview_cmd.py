"""`ppd preview FILE`: original and patched side by side, a zoom on the patch, and how visible
the mark is at display size (FLIP next to a JPEG q85 re-encode)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from daemon.cli.errors import die, one_line, open_ctx, os_error_text
from daemon.cli.options import SpecOptions, spec_options, subject_masks_option
from daemon.cli.output import console, err_console
from poisoner.errors import ExitStatus

if TYPE_CHECKING:
    from daemon.context import AppContext
    from poisoner.spec import PatchSpec


# The JPEG q85 budget is estimated on this fraction of the picture (verifier.visibility
# _quick_figures: tiles spread evenly; within a few percent of the whole picture's figure on photos,
# lower on a mostly plain picture), the mark's own figures evaluated around it (the whole picture's
# to rounding). Verification measures the whole picture.
PREVIEW_JPEG_SAMPLE = 0.05


def _is_video(path: Path) -> bool:
    from poisoner.media import is_video

    return is_video(path)


PREVIEW_PREFIX = "ppd-preview-"  # poisoner.scratch.PREFIXES: swept after a killed preview


def video_placement(spec: PatchSpec, source: Path) -> Any:
    """The first frame's placement exactly as poison_video decides it for the video at source (a
    per-photo mark: judged on the clip's keyframes; a vault copy has no suffix, the video is probed)."""
    from poisoner.video.driver import frame_placements
    from poisoner.video.model import VideoOptions
    from poisoner.video.source import probe

    return frame_placements(spec, probe(source), VideoOptions(), source)(0)


def video_mark_line(placement: Any, width: int, height: int, orientation: int | None = None) -> str:
    """Where the mark is on a video's first frame as players show it (a phone clip's rotation applied,
    as the preview draws it: it was drawn sideways, a black-box review), and where that is in the
    stored frame ppd poison writes."""
    from poisoner.orientation import display_size, orientation_of, position_words
    from poisoner.preview import oriented_placement

    x0, y0, x1, y1 = placement.box
    if orientation_of(orientation) == 1:
        return (f"mark at the {position_words(placement.box, width, height)} of the first frame, pixels "
                f"({x0},{y0})-({x1},{y1}) as stored (where ppd poison writes it on that frame)")  # fmt: skip
    shown = oriented_placement(placement, orientation, width, height).box
    words = position_words(shown, *display_size(width, height, orientation_of(orientation)))
    return (f"mark at the {words} of the first frame, pixels ({shown[0]},{shown[1]})-({shown[2]},{shown[3]}) "
            f"as players show it (the clip is stored turned: ppd poison writes it at ({x0},{y0})-({x1},{y1}) "
            "of the stored frame)")  # fmt: skip


def load_picture(path: Path, video: bool | None = None) -> tuple[Any, int | None]:
    """(stored RGB pixels, EXIF orientation or None); a video's first frame (video: whether path holds
    one; default: by its name) with the orientation its display matrix shows it in. ppd patches the
    stored pixels, so the preview works in them and orients only what it shows."""
    if _is_video(path) if video is None else video:
        import av

        from poisoner.orientation import display_orientation
        from poisoner.video import VideoFormatError, frame_to_rgb
        from poisoner.video.demux import main_video_stream, open_input
        from poisoner.video.errors import one_line as av_words
        from poisoner.video.source import frame_side_data

        with open_input(path) as container:  # the video's frames, not a cover picture listed first
            try:
                for frame in container.decode(main_video_stream(container, path.name)):
                    return frame_to_rgb(frame), display_orientation(frame_side_data(frame)[0])
            except av.error.FFmpegError as exc:  # libav's words, not its errno and path
                raise VideoFormatError(
                    f"{path.name}: cannot decode the first frame ({av_words(exc)})"
                ) from None
        raise ValueError("no video frame")
    from poisoner.image.read import decoded_rgb

    return decoded_rgb(path)  # as `ppd poison` opens it: HEIC, the bomb limit


def _load(path: Path, video: bool | None = None) -> tuple[Any, int | None]:
    from poisoner.errors import PpdError

    try:
        return load_picture(path, video)
    except PpdError as exc:  # an image's or a video's: one line that names the file already
        if (reason := _incomplete(path)) is not None:  # as `ppd poison` says it of the same file
            raise die(f"cannot read {path.name}: it is incomplete ({reason})") from None
        raise die(f"cannot read {one_line(exc)}") from None
    except (OSError, ValueError) as exc:
        raise die(f"cannot read {path.name}: {one_line(exc)}") from None


def _incomplete(path: Path) -> str | None:
    """Why path's structure is incomplete (a truncated upload), or None."""
    from poisoner.completeness import incomplete_reason

    try:
        return incomplete_reason(path)
    except OSError:
        return None


def _mark_of(spec: PatchSpec, source: Path, original: Any, file: Path, keep_out: Any) -> tuple[Any, Any]:
    """(stored placement, MarkPlace or None): a photo's place exactly as poison_file decides it
    (poisoner.preview.planned_mark: per photo, or a corner as the photo shows it), named as the
    file; a video its first frame's, as poison_video decides it."""
    if not _is_video(file):
        from poisoner.preview import planned_mark

        return planned_mark(source, spec, keep_out, name=file.name)
    return video_placement(spec, source), None


def _stored_pair(
    ctx: AppContext, file: Path, row: Any, keep_out: Any
) -> tuple[Any, Any, Any, Any, int | None, tuple[str, str]]:
    """A patched file against its vault original, with the spec it was patched with."""
    spec = ctx.store.get_spec(row["spec_id"])
    vault_copy = ctx.vault.path_for(row["original_sha256"])
    poisoned, orientation = _load(file)
    labels = ("original (vault)", f"patched ({file.name})")
    if not _is_video(file):
        original, _ = _load(vault_copy)
        placement, place = _mark_of(spec, vault_copy, original, file, keep_out)
        return original, poisoned, placement, place, orientation, labels
    from poisoner.scratch import owned_temp_dir

    # a vault copy's name is its hash: the video reader wants the container's suffix, as poisoning does
    with owned_temp_dir(PREVIEW_PREFIX) as scratch:
        named = scratch / f"original{file.suffix.lower()}"
        named.symlink_to(vault_copy)
        original, _ = _load(named)
        placement, place = _mark_of(spec, named, original, file, keep_out)
    return original, poisoned, placement, place, orientation, labels


def _planned_spec(
    ctx: AppContext, file: Path, options: SpecOptions, masks: Path | None
) -> tuple[Any, str | None]:
    """The spec `ppd poison` would give this file, and the corner line when its corner is chosen now
    (a new dataset's corner mark: judged on the file and its neighbours, as `ppd poison FOLDER` does)."""
    from daemon.datasets.dataset import attribute
    from daemon.datasets.subject_masks import corner_line, place_corner, sibling_images, wants_corner

    name, _root = attribute(ctx, file, folder=False)
    stored = ctx.store.dataset_spec(name)
    spec = options.build(stored or ctx.config.spec_for(name))
    if stored is None and wants_corner(spec, options.sets_position() or ctx.config.position_set(name)):
        placed = place_corner(spec, [file, *sibling_images(file)], masks)
        return placed.spec, corner_line(name, placed.choice)
    return spec, None


def _planned_pair(
    ctx: AppContext, file: Path, options: SpecOptions, masks: Path | None, keep_out: Any
) -> tuple[Any, Any, Any, Any, int | None, tuple[str, str]]:
    """Any photo with its dataset's spec (or the flags'), patched in memory only, where ppd poison
    would put it; off the subject (keep_out, the file's subject mask) where it has one."""
    from poisoner.blend import apply_patch

    spec, line = _planned_spec(ctx, file, options, masks)
    if line is not None:
        console().print(line, markup=False)
    original, orientation = _load(file)
    placement, place = _mark_of(spec, file, original, file, keep_out)
    # a video's first frame, as poison_video patches it (no keep-out for videos)
    poisoned = apply_patch(original, placement, None if _is_video(file) else keep_out)
    labels = (f"original ({file.name})", "patched (preview, not written)")
    return original, poisoned, placement, place, orientation, labels


def _oriented(mask: Any, orientation: int | None) -> Any:
    """A bool mask of the stored pixels as the picture is shown (uint8 0/255, H x W)."""
    import numpy as np

    from poisoner.preview import orient

    shown = orient(np.asarray(mask, np.uint8) * 255, orientation)
    return shown if shown.ndim == 2 else shown[..., 0]


def _subject_of(masks: Path | None, file: Path) -> Any:
    """The file's subject mask (stored pixels, bool), or None (no masks, none for it, a video)."""
    if masks is None or _is_video(file):
        return None
    from daemon.datasets.subject_masks import load_keep_out

    return load_keep_out(masks, file)


def _render(
    ctx: AppContext, file: Path, options: SpecOptions, masks: Path | None
) -> tuple[Any, Any, Any, Any, str]:
    """(preview picture, original, patched, subject mask or None, where the mark is and why), oriented
    as a viewer sees them; the subject's edge is drawn on the zooms."""
    from daemon.states import PATCHED_VALUES
    from poisoner.errors import ImageFormatError
    from poisoner.image.keep_out import checked_keep_out, written_pixels
    from poisoner.preview import mark_line, orient, render_preview, shown_placement
    from poisoner.spec import SpecError

    row = ctx.store.file(file)
    try:
        keep_out = _subject_of(masks, file)
        if row is not None and row["state"] in PATCHED_VALUES and not options.given():
            original, poisoned, placement, place, orientation, labels = _stored_pair(ctx, file, row, keep_out)
        else:
            planned = _planned_pair(ctx, file, options, masks, keep_out)
            original, poisoned, placement, place, orientation, labels = planned
        h, w = original.shape[:2]
        if _is_video(file):
            where = video_mark_line(placement, w, h, orientation)
        else:
            where = mark_line(placement, place, orientation, w, h)
        if written_pixels(placement, checked_keep_out(file.name, keep_out, (w, h))) == 0:
            where += "; NO pixel would change (the subject mask covers the mark): ppd poison fails this file"
        shown = shown_placement(placement, place, orientation, w, h)
        original, poisoned = orient(original, orientation), orient(poisoned, orientation)
        subject = None if keep_out is None else _oriented(keep_out, orientation)
        squares = getattr(place, "squares", ()) or ()  # split squares: each outlined and zoomed
        picture = render_preview(original, poisoned, shown, labels=labels, subject=subject, squares=squares)
        return picture, original, poisoned, subject, where
    except (SpecError, ValueError, ImageFormatError) as exc:
        raise die(one_line(exc)) from None


def _preview_masks(ctx: AppContext, file: Path, given: Path | None) -> Path | None:
    """The subject masks for this file's dataset (--subject-masks, else the config's), checked."""
    from daemon.datasets.dataset import attribute
    from daemon.datasets.subject_masks import SubjectMaskError, subject_masks_for

    try:
        return subject_masks_for(ctx, attribute(ctx, file, folder=False)[0], given)
    except SubjectMaskError as exc:
        raise die(str(exc)) from None


def _stored_video(ctx: AppContext, file: Path) -> bool:
    """Whether the preview compares a patched video with its vault original (both decoded)."""
    row = ctx.store.file(file)
    return row is not None and row.get("state") == "patched"


def _visibility_line(original: Any, poisoned: Any, display_width: int, subject: Any = None) -> str:
    """The visibility summary (arrays (H, W, C)); with the subject's mask, whether the mark touches it."""
    from verifier.visibility import VisibilityError, visibility_report

    try:
        with console().status("measuring visibility"):
            # A picture narrower than the screen is shown at its own size, not magnified (magnifying
            # would make a JPEG re-encode's artefacts, the budget, look larger than any viewer sees them).
            width = min(display_width, original.shape[1])
            figures = visibility_report(original, poisoned, display_width=width, subject_mask=subject,
                                        jpeg_sample=PREVIEW_JPEG_SAMPLE)  # fmt: skip
            touches = {True: "; changed pixels TOUCH the subject", False: "; no changed pixel on the subject"}
            touch = figures.touches_subject  # None: no subject mask to judge by
            return figures.summary() + (touches[touch] if touch is not None else "")
    except VisibilityError as exc:
        raise die(one_line(exc)) from None


def _user_file(given: Path) -> Path:
    """A file named on the command line as the store records it ('..' folded): the vault's original
    of a patched file is found by that path."""
    from daemon.cli.targets import TargetError, user_path

    try:
        return user_path(given)
    except TargetError as exc:
        raise die(exc) from None


def _check_protectable(file: Path, max_pixels: int | None) -> None:
    """One line, exit 2, for what `ppd poison` would not patch (a GIF it skips, a CMYK JPEG it fails):
    a preview of a mark that will never be written is a false promise (a black-box review)."""
    from poisoner.errors import ImageFormatError
    from poisoner.image.read import check_writable_image
    from poisoner.media import IMAGE, VIDEO, media_class

    kind = media_class(file)  # as ppd poison judges it: by suffix, else by its first bytes (no suffix)
    if kind == VIDEO:
        return
    if kind != IMAGE:
        raise die(f"{file.name}: not a photo or video ppd protects (ppd poison skips it)")
    try:
        check_writable_image(file, file.name, max_pixels)
    except ImageFormatError as exc:
        raise die(f"{one_line(exc)}; ppd poison fails this file") from None


def _first_file(ctx: AppContext, given: Path) -> Path:
    """A dataset (its name, its folder, a verification folder of it) or a folder: its first
    patched file, else the folder's first photo or video; or one line saying what to give."""
    from daemon.cli.targets import TargetError, resolve_target, say_note
    from daemon.states import FileState
    from poisoner.media import IMAGE, VIDEO, media_class

    try:
        chosen = resolve_target(ctx.store, str(given))
    except TargetError:
        if given.exists():  # /dev/null, a fifo: there, but nothing to preview
            raise die(f"{given} is not a photo, video or folder (a device, pipe or socket)") from None
        raise die(f"{given} does not exist, and is not a dataset (see `ppd status`)") from None
    say_note(chosen, err_console())
    if chosen.dataset is not None:
        rows = ctx.store.files(chosen.dataset, state=FileState.PATCHED)
        present = sorted(p for p in (Path(r.get("published_path") or r["path"]) for r in rows) if p.is_file())
        if present:
            return present[0]
    folder = chosen.folder
    media = sorted(p for p in folder.iterdir() if media_class(p) in (IMAGE, VIDEO)) if folder else []
    if not media:
        raise die(f"{given}: no photo or video to preview there")
    return media[0]


def default_target(cache_dir: Path, file: Path) -> Path:
    """previews/FOLDER-HASH/NAME.ppd-preview.png in the cache folder (daemon.paths.preview_folder): one
    per source file."""
    from daemon.paths import preview_folder

    return preview_folder(cache_dir, Path(os.path.abspath(file)).parent) / f"{file.name}.ppd-preview.png"


def _target(ctx: AppContext, file: Path, out: Path | None) -> Path:
    """The PNG to write: --out, or the cache folder's previews/. The picture shows the clean original:
    among photos (the previewed one's folder, a dataset's, the outbox, a publish folder) the next
    `ppd poison` would patch it as a photo and publish the original inside it (a black-box review
    found it written into the dataset folder by default, then patched). Refused there."""
    from daemon.cli.published import published_folder_holding

    if out is None:
        return default_target(Path(ctx.paths.cache_dir), file)
    target = Path(os.path.abspath(out.expanduser()))
    data = ctx.paths.data_dir
    if target.resolve().is_relative_to(data.resolve()) or target.is_relative_to(data):
        # a picture there made the data folder look like a photo folder: every command refused it after
        raise die(f"{out} is inside ppd's data folder {data}: write it elsewhere (or leave out --out)")
    published = published_folder_holding(target, ctx.paths, photo_folders=(file.parent,))
    if published is not None:
        raise die(f"{out} is inside {published}; the preview shows the original and would be patched or "
                  "published with the photos: write it elsewhere (or leave out --out)")  # fmt: skip
    return target


@spec_options(with_ratio=False)
def preview(
    file: Path = typer.Argument(
        ..., help="A photo or a video (original or patched), or a dataset (name or folder): its first file."
    ),
    out: Path | None = typer.Option(
        None, "--out", metavar="PNG",
        help="PNG to write (default: previews/FOLDER-HASH/NAME.ppd-preview.png in ppd's cache folder, one "
        "per photo; never among photos: it shows the original).",
    ),
    spec_options: SpecOptions = SpecOptions(),
    display_width: int = typer.Option(
        1920, "--display-width", metavar="PX", help="Screen width the visibility is judged at."
    ),
    visibility: bool = typer.Option(
        True, "--visibility/--no-visibility", help="Measure how visible the mark is (FLIP; a few seconds)."
    ),
    subject_masks: Path | None = subject_masks_option(),
) -> None:
    """Original and patched side by side, with a zoom on the patch, and how visible the mark is
    at display size (FLIP, next to a JPEG q85 re-encode of the same picture). A patched file is
    shown against its vault original; any other photo with its dataset's spec (or the flags').

    \b
    Examples:
      ppd preview IMG_0042.jpg                   the spec this file would get
      ppd preview castle                         a dataset's first patched file
      ppd preview IMG_0042.jpg --design paper    the paper's static patch
      ppd preview clip.mp4 --out clip.png        a frame of a video
      ppd preview image/000000.png --design watermark --subject-masks mask/
    """
    from PIL import Image

    if visibility and display_width < 1:
        raise die(f"--display-width must be a positive number of pixels, got {display_width}")
    ctx = open_ctx()
    try:
        file = _user_file(file) if file.is_file() else _first_file(ctx, file)
        target = _target(ctx, file, out)
        _check_protectable(file, ctx.config.max_pixels)
        masks = _preview_masks(ctx, file, subject_masks)
        image, original, poisoned, subject, where = _render(ctx, file, spec_options, masks)
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(image).save(target, format="PNG", compress_level=1)  # quick, not small
        except OSError as exc:
            raise die(os_error_text(exc, hint_out=False), ExitStatus.ENVIRONMENT) from None
        console().print(f"preview written to {target}", markup=False)
        console().print(where, markup=False, soft_wrap=True)
        if visibility:
            line = _visibility_line(original, poisoned, display_width, subject)
            if _is_video(file) and _stored_video(ctx, file):  # its frame was re-encoded, not only marked
                line += "; a patched video is re-encoded: most changed pixels are the codec's, not the mark's"
            console().print(line, markup=False, soft_wrap=True)
    finally:
        ctx.close()


def register(app: typer.Typer) -> None:
    app.command("preview")(preview)
