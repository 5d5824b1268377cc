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

    def _layer_maps(self, x: torch.Tensor, y: torch.Tensor) -> list[torch.Tensor]:
        """Per-tap distance maps (N x 1 x h x w) of N x 3 x H x W tensors already in [-1, 1]."""
        x = (x.to(self.dtype) - self._shift) / self._scale
        y = (y.to(self.dtype) - self._shift) / self._scale
        maps = []
        for fx, fy, lin in zip(self._features(x), self._features(y), self._lins, strict=True):
            nx = fx / (torch.sqrt((fx**2).sum(dim=1, keepdim=True)) + 1e-10)
            ny = fy / (torch.sqrt((fy**2).sum(dim=1, keepdim=True)) + 1e-10)
            maps.append(F.conv2d((nx - ny) ** 2, lin))
        return maps

    @torch.no_grad()
    def forward_signed(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """LPIPS of N x 3 x H x W tensors already in [-1, 1]; returns N distances."""
        total = torch.zeros(x.shape[0], dtype=self.dtype)
        for d in self._layer_maps(x, y):
            total = total + d.mean(dim=(1, 2, 3))
        return total

    def tap_sizes(self, height: int, width: int) -> list[tuple[int, int]]:
        """Spatial size of each tap's map for an H x W input (shape arithmetic, no compute)."""
        if self.net == "vgg":
            sizes, h, w = [], height, width
            for _ in range(5):
                sizes.append((h, w))
                h, w = h // 2, w // 2
            return sizes

        def conv(s: int, k: int, st: int, pad: int) -> int:
            return (s + 2 * pad - k) // st + 1

        def pool(s: int) -> int:
            return (s - 3) // 2 + 1

        h, w = conv(height, 11, 4, 2), conv(width, 11, 4, 2)
        sizes = [(h, w)]
        h, w = conv(pool(h), 5, 1, 2), conv(pool(w), 5, 1, 2)
        sizes.append((h, w))
        h, w = pool(h), pool(w)
        sizes += [(h, w)] * 3
        return sizes

    @torch.no_grad()
    def distance(self, a: np.ndarray, b: np.ndarray, local: bool = True) -> float:
        """LPIPS between two [0, 1] float images H x W x 3 (uint8 accepted too).

        local=True computes the same number over a crop around the pixels where a and b differ:
        a feature whose receptive field misses every differing pixel is identical in both images
        and adds exactly 0, so only taps within reach of the change need computing. The crop
        starts on the backbone's 16-px pooling grid and keeps one receptive field of context on
        every side, so each tap sees what it sees in the full image; sums are then divided by
        the full image's tap sizes. A local patch on an 800 px image costs ~1/8 of a full pass.
        """
        ta, tb = _to_nchw(a), _to_nchw(b)
        if ta.shape != tb.shape:
            raise ValueError(f"images differ in shape: {tuple(ta.shape)} vs {tuple(tb.shape)}")
        if self.scale_inputs:
            ta, tb = ta * 2.0 - 1.0, tb * 2.0 - 1.0
        height, width = ta.shape[2], ta.shape[3]
        box = change_box(ta[0], tb[0], height, width) if local else (0, 0, height, width)
        if box is None:
            return 0.0  # identical images: every tap's distance is exactly 0
        y0, x0, y1, x1 = box
        if (y1 - y0) * (x1 - x0) > 0.6 * height * width:
            return float(self.forward_signed(ta, tb)[0])
        maps = self._layer_maps(ta[:, :, y0:y1, x0:x1], tb[:, :, y0:y1, x0:x1])
        total = 0.0
        for d, (h, w) in zip(maps, self.tap_sizes(height, width), strict=True):
            total += float(d.sum()) / (h * w)
        return total


# Context around a change: VGG16 relu5_3's receptive field is 212 px wide (AlexNet relu5: 195 px).
# A tap whose field touches the change is centred within 106 px of it and needs 106 px more on
# the far side inside the crop: 212 px, plus the pooling grid's 16 px so the crop can start on it.
# (Measured: 200 px already agrees with the full pass to 1e-7; 150 px is off by 6e-5.)
_CONTEXT_PX = 212 + 16
_GRID_PX = 16


def change_box(a: torch.Tensor, b: torch.Tensor, height: int, width: int) -> tuple[int, int, int, int] | None:
    """(y0, x0, y1, x1) crop that holds every pixel where a != b plus its context, or None."""
    diff = (a != b).any(dim=0)
    rows = torch.nonzero(diff.any(dim=1)).flatten()
    if rows.numel() == 0:
        return None
    cols = torch.nonzero(diff.any(dim=0)).flatten()
    y0 = max(0, int(rows[0]) - _CONTEXT_PX) // _GRID_PX * _GRID_PX
    x0 = max(0, int(cols[0]) - _CONTEXT_PX) // _GRID_PX * _GRID_PX
    y1 = min(height, int(rows[-1]) + 1 + _CONTEXT_PX)
    x1 = min(width, int(cols[-1]) + 1 + _CONTEXT_PX)
    return y0, x0, y1, x1


def _to_nchw(img: np.ndarray) -> torch.Tensor:
    arr = np.asarray(img)
    if arr.dtype == np.uint8:
        arr = arr.astype(np.float32) / 255.0
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"expected an H x W x 3 image, got shape {arr.shape}")
    return torch.from_numpy(np.ascontiguousarray(arr, dtype=np.float32)).permute(2, 0, 1)[None]
