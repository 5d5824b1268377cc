"""A CPU 3D Gaussian Splatting renderer and trainer in plain PyTorch (our code, after Kerbl et al. 2023).

gsplat and the official rasteriser need CUDA; this runs anywhere torch runs. See docs/SPLAT.md.
torch is imported by the submodules; pycolmap only by `stage` (in the verification child).
"""

from __future__ import annotations

__all__ = ["camera", "gaussians", "render", "train", "stage"]
