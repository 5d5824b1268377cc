"""A CPU 3D Gaussian Splatting renderer and trainer (our code, after Kerbl et al. 2023).

gsplat and the official rasteriser need CUDA; this runs anywhere torch runs. See docs/SPLAT.md.
torch is imported by the submodules; pycolmap only by `stage` (in the verification child).
"""

from __future__ import annotations

import os

# Idle OpenMP threads (torch's and numba's pools) sleep instead of spinning. On a 2-core machine
# shared with other work, spinning threads starved the training loop: 1-3 it/s instead of 10-15
# (bench/results/splat.md). libgomp reads this once when it loads, so it only takes effect when
# this package is imported before torch (the stage child and the bench make sure of that).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__all__ = ["camera", "gaussians", "render", "train", "stage", "kernel", "loss"]
