"""Where COLMAP's SIFT runs: the GPU with pycolmap's CUDA build (the `[gpu]` extra) and a CUDA
device, else the CPU. The parent asks sift_device_name() without loading pycolmap; the child,
which has loaded it, asks sift_device()."""

from __future__ import annotations

import functools
import os
from typing import Any

# GPU SIFT (SiftGPU) is another implementation than the CPU's. On lego's 800 px renders it cost
# `published` and `masked` their clean control (inconclusive, where the CPU's held: gpu.md round 5),
# on a 320 px set every profile's (round 4); on 6000 px photos it found the CPU's keypoints within 2%
# and 3x faster. So photos up to this long edge get the CPU's SIFT (seconds on them anyway).
GPU_SIFT_ABOVE_LONG_EDGE = 1600


def gpu_sift_suits(long_edge: int) -> bool:
    """Whether SIFT may run on a GPU for images this large (their longest side, in pixels)."""
    return long_edge > GPU_SIFT_ABOVE_LONG_EDGE


def cuda_device_count() -> int:
    """CUDA devices the driver sees (0 without a driver or a device); asks libcuda directly, so
    the answer needs neither torch nor a CUDA build of pycolmap."""
    import ctypes

    try:
        cuda = ctypes.CDLL("libcuda.so.1")
    except OSError:
        return 0
    count = ctypes.c_int(0)
    if cuda.cuInit(0) != 0 or cuda.cuDeviceGetCount(ctypes.byref(count)) != 0:
        return 0
    return int(count.value)


def sift_device_name(cpu_only: bool = False) -> str:
    """The device sift_device() will pick in the child, "cuda" or "cpu", told without importing
    pycolmap here (the parent never loads it): the CUDA build is the installed `pycolmap-cuda12`."""
    if cpu_only or os.environ.get("PPD_SFM_DEVICE", "auto") == "cpu":
        return "cpu"
    return "cuda" if _cuda_build_and_device() else "cpu"


@functools.cache
def _cuda_build_and_device() -> bool:
    """pycolmap-cuda12 installed and a CUDA device present: asked once (feature keys ask often)."""
    from importlib import metadata

    try:
        metadata.distribution("pycolmap-cuda12")
    except metadata.PackageNotFoundError:
        return False
    return cuda_device_count() > 0


def sift_device(cpu_only: bool = False) -> Any:
    """Where SIFT extraction and matching run: the GPU when this pycolmap is a CUDA build (the
    `[gpu]` extra, pycolmap-cuda12) and a CUDA device is present, else the CPU. cpu_only (small
    images: gpu_sift_suits) or PPD_SFM_DEVICE=cpu (e.g. to compare verdicts on one machine) force
    the CPU."""
    import pycolmap

    forced = cpu_only or os.environ.get("PPD_SFM_DEVICE", "auto") == "cpu"
    if forced or not getattr(pycolmap, "has_cuda", False):
        return pycolmap.Device.cpu
    return pycolmap.Device.cuda if cuda_device_count() > 0 else pycolmap.Device.cpu
