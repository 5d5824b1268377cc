"""LPIPS v0.1 (Zhang et al. 2018) in plain PyTorch, fully offline.

VGG16 backbone by default (as official 3DGS `metrics.py`), AlexNet as an option. Weights come
from the .npz files that `python -m verifier.lpips_weights --install` writes at set-up (see
that module); nothing is downloaded here. When they are missing, `lpips_available()` returns
(False, reason) and callers report "n/a" with the reason, never a made-up number.

The forward pass is LPIPS v0.1's: inputs in [-1, 1] -> (x - shift) / scale with LPIPS's
shift/scale -> backbone ReLU taps (VGG relu1_2, relu2_2, relu3_3, relu4_3, relu5_3; AlexNet
relu1..relu5) -> unit-normalise each feature vector over channels (eps 1e-10) -> squared
difference -> 1x1 linear layer (no bias) -> spatial mean -> sum over taps.

`Lpips.distance(a, b)` takes [0, 1] float images (H x W x 3) and scales them to [-1, 1] as
LPIPS expects. Note: 3DGS's metrics.py goes through `lpipsPyTorch`, which (as we read it) feeds
its [0, 1] images straight in without that scaling; pass `scale_inputs=False` to mimic it.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from verifier.lpips_weights import NETS, WeightsError, weights_path

_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)

# VGG16 config: conv channel counts, "M" = 2x2 max pool; taps after these conv indices' ReLU.
_VGG_CFG: list[int | str] = [
    64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512,
]
_VGG_TAPS = {1, 3, 6, 9, 12}

INSTALL_HINT = "run scripts/setup.sh (or: python -m verifier.lpips_weights --install)"


def lpips_available(net: str = "vgg") -> tuple[bool, str]:
    """(True, path) when this net's converted weights are present, else (False, reason)."""
    try:
        path = weights_path(net)
    except WeightsError as exc:
        return False, str(exc)
    if not path.is_file():
        return False, f"LPIPS {net} weights not installed at {path}; {INSTALL_HINT}"
    return True, str(path)


def _load_npz(net: str) -> dict[str, torch.Tensor]:
    ok, reason = lpips_available(net)
    if not ok:
        raise WeightsError(reason)
    with np.load(weights_path(net), allow_pickle=False) as z:
        return {k: torch.from_numpy(np.array(z[k])) for k in z.files if k != "source_sha256"}


class Lpips:
    """LPIPS v0.1 distance. `Lpips(net="vgg"|"alex").distance(a, b) -> float`."""

    def __init__(self, net: str = "vgg", scale_inputs: bool = True, dtype: torch.dtype = torch.float32):
        if net not in NETS:
            raise WeightsError(f"unknown LPIPS net {net!r}: expected one of {', '.join(NETS)}")
        self.net = net
        self.scale_inputs = scale_inputs
        self.dtype = dtype
        params = _load_npz(net)
        self._convs = [
            (params[f"features.{i}.weight"].to(dtype), params[f"features.{i}.bias"].to(dtype))
            for i in range(sum(1 for k in params if k.startswith("features.") and k.endswith(".weight")))
        ]
        self._lins = [params[f"lin.{j}.weight"].to(dtype) for j in range(5)]
        self._shift = torch.tensor(_SHIFT, dtype=dtype).view(1, 3, 1, 1)
        self._scale = torch.tensor(_SCALE, dtype=dtype).view(1, 3, 1, 1)

    def _features(self, x: torch.Tensor) -> list[torch.Tensor]:
        taps: list[torch.Tensor] = []
        if self.net == "vgg":
            conv_i = 0
            for v in _VGG_CFG:
                if v == "M":
                    x = F.max_pool2d(x, 2, 2)
                    continue
                w, b = self._convs[conv_i]
                x = F.relu(F.conv2d(x, w, b, padding=1))
                if conv_i in _VGG_TAPS:
                    taps.append(x)
                conv_i += 1
            return taps
        # AlexNet (torchvision layout): conv11/4 p2, pool, conv5 p2, pool, conv3 x3.
        strides_pads = [(4, 2), (1, 2), (1, 1), (1, 1), (1, 1)]
        for i, ((w, b), (stride, pad)) in enumerate(zip(self._convs, strides_pads, strict=True)):
            if i in (1, 2):
                x = F.max_pool2d(x, 3, 2)
            x = F.relu(F.conv2d(x, w, b, stride=stride, padding=pad))
            taps.append(x)
        return taps

    @torch.no_grad()
    def forward_signed(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """LPIPS of N x 3 x H x W tensors already in [-1, 1]; returns N distances."""
        x = (x.to(self.dtype) - self._shift) / self._scale
        y = (y.to(self.dtype) - self._shift) / self._scale
        total = torch.zeros(x.shape[0], dtype=self.dtype)
        for fx, fy, lin in zip(self._features(x), self._features(y), self._lins, strict=True):
            nx = fx / (torch.sqrt((fx**2).sum(dim=1, keepdim=True)) + 1e-10)
            ny = fy / (torch.sqrt((fy**2).sum(dim=1, keepdim=True)) + 1e-10)
            d = F.conv2d((nx - ny) ** 2, lin)
            total = total + d.mean(dim=(1, 2, 3))
        return total

    def distance(self, a: np.ndarray, b: np.ndarray) -> float:
        """LPIPS between two [0, 1] float images H x W x 3 (uint8 accepted too)."""
        ta, tb = _to_nchw(a), _to_nchw(b)
        if ta.shape != tb.shape:
            raise ValueError(f"images differ in shape: {tuple(ta.shape)} vs {tuple(tb.shape)}")
        if self.scale_inputs:
            ta, tb = ta * 2.0 - 1.0, tb * 2.0 - 1.0
        return float(self.forward_signed(ta, tb)[0])


def _to_nchw(img: np.ndarray) -> torch.Tensor:
    arr = np.asarray(img)
    if arr.dtype == np.uint8:
        arr = arr.astype(np.float32) / 255.0
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"expected an H x W x 3 image, got shape {arr.shape}")
    return torch.from_numpy(np.ascontiguousarray(arr, dtype=np.float32)).permute(2, 0, 1)[None]
