"""What images reach COLMAP's database and under which cameras, and the masked profile's corner masks:
the SfM child's side of feature extraction (verifier.sfm runs it; pycolmap is imported here only
inside functions).

convert.py's one shared camera (CameraMode.SINGLE) makes COLMAP skip every image whose stored size
is not the first one's (CAMERA_SINGLE_DIM_ERROR): a phone photo stored turned (EXIF orientation 6
or 8), a portrait among landscapes. An attacker's COLMAP in its default camera mode, or one who
turns the photos upright first, uses them all; so a set of several stored sizes gets one camera per
size (`import_per_size`, SfmSettings.camera_per_size), and whatever COLMAP still leaves out is read
back from the database (`left_out`) and named in the report (a black-box review: "6/6 images" and
"protected" for a dataset of 8, two of them turned).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def corner_mask(width: int, height: int, fraction: float) -> Any:
    """uint8 H x W mask for COLMAP: 0 in the four corner regions (no features there), 255 elsewhere."""
    import numpy as np

    mask = np.full((height, width), 255, dtype=np.uint8)
    rw, rh = int(round(fraction * width)), int(round(fraction * height))
    if rw > 0 and rh > 0:
        for ys in (slice(0, rh), slice(height - rh, height)):
            for xs in (slice(0, rw), slice(width - rw, width)):
                mask[ys, xs] = 0
    return mask


def write_corner_masks(image_dir: Path, names: list[str], mask_dir: Path, fraction: float) -> None:
    """One mask per image, named as COLMAP expects (`<image name>.png`), at the image's size."""
    from PIL import Image

    mask_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        with Image.open(image_dir / name) as im:
            width, height = im.size
        Image.fromarray(corner_mask(width, height, fraction)).save(mask_dir / f"{name}.png")


def stored_size(path: Path) -> tuple[int, int] | None:
    """The image's size as stored, as COLMAP reads it (no EXIF orientation applied: the header, as
    verifier.plan.stored_sizes reads it); None when it cannot be read (COLMAP then decides alone)."""
    from poisoner.limits import HeaderError, decoded_size

    try:
        size = decoded_size(path)
    except HeaderError:
        return None
    return (size.width, size.height)


def import_per_size(database: Path, image_dir: Path, names: Sequence[str], reader: Any) -> None:
    """The images into database in name order, one camera per stored size: the first image of a size
    makes its camera as SINGLE mode does (COLMAP's prior focal length from its EXIF, else its size),
    the others of that size take it (ImageReaderOptions.existing_camera_id). One import per image
    keeps COLMAP's ids in name order, as one import of a one-size set numbers them."""
    import pycolmap

    cameras: dict[tuple[int, int], int] = {}
    for name in names:
        size = stored_size(image_dir / name)
        options = copy.copy(reader)
        if size is not None and size in cameras:
            options.existing_camera_id = cameras[size]
        pycolmap.import_images(database, image_dir, camera_mode=pycolmap.CameraMode.SINGLE,
                               image_names=[name], options=options)  # fmt: skip
        if size is not None and size not in cameras:
            with pycolmap.Database.open(database) as db:
                image = db.read_image_with_name(name)  # None: COLMAP refused it (its log says why)
            if image is not None:
                cameras[size] = image.camera_id


def left_out(database: Path, names: Sequence[str]) -> list[str]:
    """The images COLMAP did not take into database (its log says why: a size its single camera does
    not have, a file it cannot decode), in the order of names; the others are its num_images."""
    import pycolmap

    with pycolmap.Database.open(database) as db:
        taken = {image.name for image in db.read_all_images()}
    return [n for n in names if n not in taken]
