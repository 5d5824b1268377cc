"""libjpeg-turbo's TurboJPEG transform API through ctypes: read a JPEG's DCT coefficients once, hand
some of them out and take changed ones back, write every coefficient once, all in this process.

`tjTransform` with n transforms reads the source's coefficients once (one entropy decode) and
then runs each transform in turn on those coefficients: a lossless crop (`TJXOPT_CROP`), or a
whole-picture copy whose `customFilter` callback sees every row of DCT blocks of every component
before they are entropy-coded again. The callback can change coefficients in place; every block
it leaves alone is written as it was read.

The library is the system's `libturbojpeg.so.0` (Debian/Ubuntu `libturbojpeg0`, the same
libjpeg-turbo that `jpegtran` comes with); the TurboJPEG 2.x API used here (tjInitTransform,
tjTransform, tjFree, tjGetErrorStr2, the tjtransform struct) is unchanged from 1.4 to 3.x.
`PPD_TURBOJPEG` names another library file, or "" to turn the in-process path off.
What tjTransform (2.x) cannot do: set a restart interval, optimise baseline Huffman tables, or
write arithmetic coding; such sources go to the jpegtran path.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from collections.abc import Callable, Container
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

TURBOJPEG_ENV = "PPD_TURBOJPEG"

TJXOPT_CROP = 4
TJXOPT_NOOUTPUT = 16
TJXOPT_PROGRESSIVE = 32
TJXOPT_COPYNONE = 64


class TurboUnavailable(Exception):
    """The library is missing, or it refused this file (corrupt data gives a warning: refused)."""


class TjRegion(ctypes.Structure):
    _fields_ = [("x", ctypes.c_int), ("y", ctypes.c_int), ("w", ctypes.c_int), ("h", ctypes.c_int)]


class TjTransform(ctypes.Structure):
    pass


FILTER = ctypes.CFUNCTYPE(
    ctypes.c_int,
    ctypes.c_void_p,  # short *coeffs: an address (cheaper to receive than a ctypes pointer)
    TjRegion,
    TjRegion,
    ctypes.c_int,
    ctypes.c_int,
    ctypes.POINTER(TjTransform),
)
TjTransform._fields_ = [
    ("r", TjRegion),
    ("op", ctypes.c_int),
    ("options", ctypes.c_int),
    ("data", ctypes.c_void_p),
    ("customFilter", FILTER),
]

# (block row of the component, the row's blocks as an int16 array of shape (blocks, 64), natural
# order, component index, transform index) -> None. Raising aborts the transform.
BlockRowFilter = Callable[[int, "np.ndarray", int, int], None]
# component index -> the block rows the filter wants to see (the callback returns at once for
# the others: it runs for every block row of a 12 MP picture, ~700 times).
WantedRows = Callable[[int], Container[int]]  # the block rows to hand on_row, per component

_lib: ctypes.CDLL | None = None
_lib_error: str | None = None


def library() -> ctypes.CDLL:
    """The loaded libturbojpeg, or TurboUnavailable with the reason (kept: tried once)."""
    global _lib, _lib_error
    override = os.environ.get(TURBOJPEG_ENV)
    if override is not None:  # an explicit choice is honoured on every call (tests switch it)
        if not override:
            raise TurboUnavailable(f"{TURBOJPEG_ENV} is empty: in-process path off")
        return _load(override)
    if _lib is None and _lib_error is None:
        try:  # the usual soname first: find_library runs `ldconfig -p` (a child process)
            _lib = _load("libturbojpeg.so.0")
        except TurboUnavailable as exc:
            _lib_error = str(exc)
            name = ctypes.util.find_library("turbojpeg")
            if name:
                try:
                    _lib, _lib_error = _load(name), None
                except TurboUnavailable as again:
                    _lib_error = str(again)
    if _lib is None:
        raise TurboUnavailable(_lib_error)
    return _lib


def _load(name: str) -> ctypes.CDLL:
    try:
        lib = ctypes.CDLL(name)
        lib.tjInitTransform.restype = ctypes.c_void_p
        lib.tjDestroy.argtypes = [ctypes.c_void_p]
        lib.tjFree.argtypes = [ctypes.c_void_p]
        lib.tjGetErrorStr2.restype = ctypes.c_char_p
        lib.tjGetErrorStr2.argtypes = [ctypes.c_void_p]
        lib.tjTransform.argtypes = [
            ctypes.c_void_p,
            ctypes.c_char_p,
            ctypes.c_ulong,
            ctypes.c_int,
            ctypes.POINTER(ctypes.c_void_p),
            ctypes.POINTER(ctypes.c_ulong),
            ctypes.POINTER(TjTransform),
            ctypes.c_int,
        ]
    except (OSError, AttributeError) as exc:
        raise TurboUnavailable(f"libturbojpeg not usable ({name}): {exc}") from exc
    return lib


def crop_spec(box: tuple[int, int, int, int]) -> TjTransform:
    """A lossless crop of the MCU-aligned box, no metadata copied."""
    x0, y0, x1, y1 = box
    return TjTransform(TjRegion(x0, y0, x1 - x0, y1 - y0), 0, TJXOPT_CROP | TJXOPT_COPYNONE, None, FILTER())


def filter_spec(
    on_row: BlockRowFilter,
    *,
    wanted: WantedRows | None = None,
    progressive: bool = False,
    copy_markers: bool = True,
    output: bool = True,
) -> tuple[TjTransform, object]:
    """The whole picture, every marker kept (copy_markers), with on_row called on each wanted block
    row (all when wanted is None; output=False: nothing written). Returns the struct and what must
    outlive the transform."""
    import numpy as np

    errors: list[BaseException] = []

    def trampoline(coeffs, array_region, _plane, component, index, _t) -> int:
        try:
            row = array_region.y // 8
            if wanted is not None and row not in wanted(component):
                return 0
            count = array_region.w // 8 * 64
            blocks = np.frombuffer((ctypes.c_short * count).from_address(coeffs), dtype=np.int16)
            on_row(row, blocks.reshape(-1, 64), component, index)
            return 0
        except BaseException as exc:  # an exception must not cross the C frames
            errors.append(exc)
            return -1

    callback = FILTER(trampoline)
    options = (TJXOPT_PROGRESSIVE if progressive else 0) | (0 if copy_markers else TJXOPT_COPYNONE)
    options |= 0 if output else TJXOPT_NOOUTPUT
    spec = TjTransform(TjRegion(0, 0, 0, 0), 0, options, None, callback)
    return spec, (callback, errors)


class Outputs:
    """The transforms' output buffers: a filter of transform i may read `finished(j)` for j < i
    (tjTransform finishes each output before it starts the next transform)."""

    def __init__(self, n: int) -> None:
        self.bufs = (ctypes.c_void_p * n)()
        self.sizes = (ctypes.c_ulong * n)()

    def finished(self, index: int) -> bytes:
        buf = self.bufs[index]
        if not buf:
            raise TurboUnavailable(f"transform {index} wrote nothing")
        return ctypes.string_at(buf, self.sizes[index])


def transform(
    data: bytes, specs: list[tuple[TjTransform, Any]], outputs: Outputs | None = None
) -> list[bytes]:
    """Run the transforms on data (one entropy decode); the output file of each. Any library error
    or warning (corrupt or truncated data) raises TurboUnavailable; an exception raised by a
    filter is re-raised as it was."""
    lib = library()
    n = len(specs)
    arr = (TjTransform * n)(*(s for s, _ in specs))
    outputs = outputs or Outputs(n)
    bufs, sizes = outputs.bufs, outputs.sizes
    handle = lib.tjInitTransform()
    if not handle:
        raise TurboUnavailable("tjInitTransform failed")
    try:
        rc = lib.tjTransform(handle, data, len(data), n, bufs, sizes, arr, 0)
        for _, keep in specs:
            if keep is not None and keep[1]:
                raise keep[1][0]
        if rc != 0:
            raise TurboUnavailable(f"libturbojpeg: {lib.tjGetErrorStr2(handle).decode(errors='replace')}")
        return [ctypes.string_at(buf, sizes[i]) if (buf := bufs[i]) else b"" for i in range(n)]
    finally:
        for i in range(n):
            if bufs[i]:
                lib.tjFree(bufs[i])
        lib.tjDestroy(handle)


def read_blocks(data: bytes) -> list[np.ndarray]:
    """Every component's DCT blocks of a JPEG: int16 arrays (rows, cols, 64), natural order; the
    rows run to a whole MCU row (padding rows included). One entropy decode, nothing written."""
    import numpy as np

    rows: dict[int, list[np.ndarray]] = {}

    def keep(_row: int, blocks: np.ndarray, component: int, _index: int) -> None:
        rows.setdefault(component, []).append(np.array(blocks))

    transform(data, [filter_spec(keep, copy_markers=False, output=False)])
    return [np.stack(rows[c]) for c in sorted(rows)]
