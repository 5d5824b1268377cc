"""CPU Gaussian splat: analytic single Gaussian, tile culling vs brute force, finite-difference
gradients, one densification step, and the stage on a real (tiny) pycolmap model."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from verifier.metrics import ssim_torch
from verifier.splat.camera import Camera, camera_from_blender
from verifier.splat.gaussians import Gaussians, from_points
from verifier.splat.loss import ssim_fast
from verifier.splat.render import ALPHA_MIN, DILATION, RenderSettings, project, rasterise, render
from verifier.splat.train import SplatOptions, densify_and_prune, train_splat

F64 = torch.float64


def _camera(width: int = 48, height: int = 40, focal: float = 50.0) -> Camera:
    return Camera(np.eye(3), np.zeros(3), focal, focal, width / 2, height / 2, width, height)


def _gaussians(
    means: list[list[float]],
    scales: list[list[float]],
    quats: list[list[float]],
    opacities: list[float],
    colours: list[list[float]],
) -> Gaussians:
    def t(x: object) -> torch.Tensor:
        return torch.tensor(x, dtype=F64)

    op = t(opacities)
    rgb = t(colours)
    return Gaussians(
        means=t(means),
        log_scales=torch.log(t(scales)),
        quats=t(quats),
        opacity_logits=torch.log(op / (1 - op)),
        sh_dc=(rgb - 0.5) / 0.28209479177387814,
        sh_rest=torch.zeros(len(means), 3, 3, dtype=F64),
    )


def _analytic(
    cov2d: np.ndarray,
    centre: tuple[float, float],
    opacity: float,
    colour: np.ndarray,
    bg: np.ndarray,
    width: int,
    height: int,
) -> np.ndarray:
    """Independent numpy: one 2D Gaussian composited over bg at pixel centres (i + 0.5, j + 0.5)."""
    inv = np.linalg.inv(cov2d + DILATION * np.eye(2))
    xs, ys = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    d = np.stack([xs - centre[0], ys - centre[1]], -1)
    power = -0.5 * np.einsum("hwi,ij,hwj->hw", d, inv, d)
    alpha = np.minimum(opacity * np.exp(power), 0.99)
    alpha[alpha < ALPHA_MIN] = 0.0
    return alpha[..., None] * colour + (1 - alpha[..., None]) * bg


BACKENDS = ("kernel", "torch")


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_isotropic_gaussian_matches_analytic(backend: str) -> None:
    cam = _camera()
    z, s = 4.0, 0.3
    g = _gaussians([[0.0, 0.0, z]], [[s, s, s]], [[1.0, 0, 0, 0]], [0.8], [[0.9, 0.2, 0.1]])
    bg = np.array([0.0, 0.0, 1.0])
    settings = RenderSettings(backend=backend)
    img = render(g, cam, torch.tensor(bg), sh_degree=0, settings=settings).image.permute(1, 2, 0).numpy()
    sigma_px = cam.fx * s / z
    expected = _analytic(
        np.eye(2) * sigma_px**2, (cam.cx, cam.cy), 0.8, np.array([0.9, 0.2, 0.1]), bg, cam.width, cam.height
    )
    assert np.abs(img - expected).max() < 1e-9
    assert img[20, 24, 0] > 0.5  # the centre is mostly the Gaussian's red


@pytest.mark.parametrize("backend", BACKENDS)
def test_rotated_anisotropic_gaussian_matches_analytic(backend: str) -> None:
    cam = _camera()
    z, theta = 5.0, 0.6
    q = [math.cos(theta / 2), 0.0, 0.0, math.sin(theta / 2)]  # rotation about the optical axis
    g = _gaussians([[0.0, 0.0, z]], [[0.6, 0.15, 0.2]], [q], [0.95], [[0.1, 0.8, 0.3]])
    bg = np.zeros(3)
    settings = RenderSettings(backend=backend)
    img = render(g, cam, torch.tensor(bg), sh_degree=0, settings=settings).image.permute(1, 2, 0).numpy()
    rot = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    cov = (cam.fx / z) ** 2 * rot @ np.diag([0.6**2, 0.15**2]) @ rot.T
    expected = _analytic(cov, (cam.cx, cam.cy), 0.95, np.array([0.1, 0.8, 0.3]), bg, cam.width, cam.height)
    assert np.abs(img - expected).max() < 1e-9


def _random_scene(n: int, seed: int, dtype: torch.dtype = F64) -> Gaussians:
    rng = np.random.default_rng(seed)
    g = from_points(rng.uniform(-1, 1, (n, 3)) * [1.5, 1.2, 1.0], rng.random((n, 3)), dtype=dtype)
    with torch.no_grad():
        g.opacity_logits.copy_(torch.tensor(rng.uniform(-2, 4, n), dtype=dtype))
        g.quats.copy_(torch.tensor(rng.normal(size=(n, 4)), dtype=dtype))
        g.log_scales.add_(torch.tensor(rng.normal(0, 0.3, (n, 3)), dtype=dtype))
        g.sh_rest.copy_(torch.tensor(rng.normal(0, 0.3, (n, 3, 3)), dtype=dtype))
    return g


@pytest.mark.parametrize("backend", BACKENDS)
def test_tile_culling_equals_brute_force(backend: str) -> None:
    cam = Camera(np.eye(3), np.array([0.0, 0.0, 4.0]), 60.0, 60.0, 27.0, 21.0, 53, 41)
    g = _random_scene(400, seed=1)
    bg = torch.tensor([1.0, 1.0, 1.0], dtype=F64)
    tiled = render(g, cam, bg, 1, RenderSettings(tile_size=16, backend=backend))
    small = RenderSettings(tile_size=8, max_group_elements=5000, backend=backend)
    small_groups = render(g, cam, bg, 1, small)
    brute = render(g, cam, bg, 1, RenderSettings(tile_size=16, brute_force=True, backend=backend))
    assert tiled.pairs < brute.pairs  # culling did cull
    assert torch.abs(tiled.image - brute.image).max() < 1e-12
    assert torch.abs(small_groups.image - brute.image).max() < 1e-12
    assert tiled.image.std() > 0.05  # not a blank image


@pytest.mark.parametrize("backend", BACKENDS)
def test_gradients_match_finite_differences(backend: str) -> None:
    cam = Camera(np.eye(3), np.array([0.0, 0.0, 3.0]), 14.0, 14.0, 6.0, 5.0, 12, 10)
    base = _random_scene(4, seed=2)
    with torch.no_grad():
        base.means.mul_(0.4)
        base.log_scales.copy_(torch.log(torch.full_like(base.log_scales, 0.35)))
        base.opacity_logits.copy_(torch.tensor([0.5, -0.3, 0.2, 0.0], dtype=F64))
    bg = torch.tensor([0.2, 0.3, 0.4], dtype=F64)
    camera_centre_dir = torch.linspace(0, 1, 3 * 10 * 12, dtype=F64).view(3, 10, 12)
    names = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")
    leaves = [getattr(base, n).detach().clone().requires_grad_(True) for n in names]

    def loss(*params: torch.Tensor) -> torch.Tensor:
        g = Gaussians(**dict(zip(names, params, strict=True)))
        return (render(g, cam, bg, 1, RenderSettings(backend=backend)).image * camera_centre_dir).sum()

    assert torch.autograd.gradcheck(loss, leaves, eps=1e-6, atol=1e-6, rtol=1e-4)


def _composite_both(
    g: Gaussians, cam: Camera, bg: torch.Tensor, tile: int
) -> dict[str, dict[str, torch.Tensor]]:
    """Image and gradients w.r.t. the compositor's inputs (means2D, conics, opacities, colours,
    background) for a fixed random linear loss, with each backend, from the same projection."""
    with torch.no_grad():
        proj = project(g, cam, 1)
    weights = torch.randn(3, cam.height, cam.width, generator=torch.Generator().manual_seed(0), dtype=F64)
    out = {}
    for backend in BACKENDS:
        leaves = {n: getattr(proj, n).detach().clone().requires_grad_(True)
                  for n in ("means2d", "conics", "opacity", "colours")}
        leaves["bg"] = bg.clone().requires_grad_(True)
        p = type(proj)(leaves["means2d"], leaves["conics"], proj.depths, proj.radii, leaves["opacity"],
                       leaves["colours"])
        image, _ = rasterise(p, cam, leaves["bg"], RenderSettings(tile_size=tile, backend=backend))
        (image * weights).sum().backward()
        out[backend] = {"image": image.detach(), **{n: t.grad for n, t in leaves.items()}}
    return out


@pytest.mark.parametrize("seed", [11, 12])
def test_kernel_equals_reference_image_and_gradients(seed: int) -> None:
    # Opaque and transparent Gaussians: exercises the 0.99 clamp, the 1/255 skip and early
    # termination (T < 1e-4), which the kernel and the autograd reference implement separately.
    cam = Camera(np.eye(3), np.array([0.0, 0.0, 4.0]), 60.0, 60.0, 27.0, 21.0, 53, 41)
    g = _random_scene(300, seed=seed)
    with torch.no_grad():
        g.opacity_logits[::3] = 8.0  # sigmoid > 0.99: clamped alpha
    bg = torch.tensor([0.3, 0.6, 0.9], dtype=F64)
    out = _composite_both(g, cam, bg, tile=16 if seed % 2 else 8)
    ref, fast = out["torch"], out["kernel"]
    assert torch.abs(fast["image"] - ref["image"]).max() < 1e-6
    for name in ("means2d", "conics", "opacity", "colours", "bg"):
        scale = ref[name].abs().max()
        assert scale > 0, name  # the gradient is not trivially zero
        assert torch.abs(fast[name] - ref[name]).max() <= 1e-5 * max(1.0, float(scale)), name
    clamped = torch.sigmoid(g.opacity_logits.detach()) > 0.99
    assert (ref["opacity"][clamped] == 0).any()  # some alpha was clamped at 0.99 somewhere


def test_ssim_fast_equals_ssim_torch() -> None:
    gen = torch.Generator().manual_seed(1)
    a = torch.rand(3, 37, 52, generator=gen, dtype=F64, requires_grad=True)
    b = torch.rand(3, 37, 52, generator=gen, dtype=F64)
    fast, ref = ssim_fast(a, b), ssim_torch(a, b)
    (g_fast,) = torch.autograd.grad(fast, a)
    (g_ref,) = torch.autograd.grad(ref, a)
    assert abs(float(fast.detach() - ref.detach())) < 1e-12
    assert torch.abs(g_fast - g_ref).max() < 1e-12
    assert abs(float(ssim_fast(b, b)) - 1.0) < 1e-12


def test_densify_clones_splits_and_prunes() -> None:
    g = _random_scene(6, seed=3, dtype=torch.float32)
    with torch.no_grad():
        g.log_scales[:3] = math.log(0.001)  # small: cloned
        g.log_scales[3:] = math.log(0.5)  # large: split
        g.opacity_logits[5] = -10.0  # transparent: pruned (it is also hot, so its split halves go too)
    opt = torch.optim.Adam([{"params": [getattr(g, n)], "name": n} for n in g.params()], eps=1e-15)
    grads = torch.tensor([1.0, 0.0, 1.0, 1.0, 0.0, 1.0])
    gen = torch.Generator().manual_seed(0)
    out = densify_and_prune(g, opt, grads, SplatOptions(), extent=1.0, generator=gen)
    # kept: 0,1,2 (small) + 4 (large, cold) ; clones of 0,2 ; split of 3 -> 2 new ; 5 pruned with its halves
    assert out.count == 4 + 2 + 2
    assert torch.allclose(out.scales()[-1], torch.full((3,), 0.5 / 1.6), rtol=1e-5)
    assert all(p.requires_grad and p.is_leaf for p in out.params().values())


def test_training_reduces_loss_on_a_tiny_scene() -> None:
    # Fit 60 Gaussians to renders of a reference set of Gaussians from 4 views (ground truth exists).
    truth = _random_scene(30, seed=4, dtype=torch.float32)
    cams = [camera_from_blender(_look_from(angle), 0.9, 32, 32) for angle in (0.0, 0.5, 1.0, 1.5)]
    bg = torch.ones(3)
    with torch.no_grad():
        targets = [render(truth, c, bg, 1).image for c in cams]
    rng = np.random.default_rng(5)
    g = from_points(rng.uniform(-1, 1, (60, 3)), rng.random((60, 3)))
    options = SplatOptions(iterations=120, white_background=True, densify_from=1000, sh_degree_up_at=60)
    result = train_splat(g, cams, targets, options, extent=4.0)
    first, last = np.mean(result.losses[:10]), np.mean(result.losses[-10:])
    assert result.iterations == 120
    assert last < 0.6 * first


def _look_from(angle: float, radius: float = 4.0) -> np.ndarray:
    """Blender camera-to-world looking at the origin from the xz plane (OpenGL axes)."""
    centre = np.array([radius * math.sin(angle), 0.3, radius * math.cos(angle)])
    back = centre / np.linalg.norm(centre)  # camera +z points away from the target
    right = np.cross([0.0, 1.0, 0.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, back, centre
    return c2w


def _write_model(path: Path, cams: list[Camera], names: list[str], points: np.ndarray) -> None:
    """A real COLMAP sparse model written by pycolmap (PINHOLE cameras, given poses, 3D points)."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    c0 = cams[0]
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera.create_from_model_name(1, "PINHOLE", c0.fx, c0.width, c0.height)
    )
    for i, (cam, name) in enumerate(zip(cams, names, strict=True), start=1):
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(cam.rotation), cam.translation)
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=i), pose)
    for p in points:
        rec.add_point3D(p, pycolmap.Track(), np.array([128, 128, 128], dtype=np.uint8))
    path.mkdir(parents=True)
    rec.write(str(path))


def test_stage_trains_both_sides_and_reports_both_costs(tmp_path: Path) -> None:
    import PIL.Image

    from poisoner.blend import poison_array
    from poisoner.spec import PatchSpec
    from verifier.splat.render import to_uint8
    from verifier.splat.stage import run_splat_stage

    truth = _random_scene(30, seed=6, dtype=torch.float32)
    cams = [camera_from_blender(_look_from(a), 0.9, 48, 48) for a in (0.0, 0.4, 0.8, 1.2)]
    names = [f"v{i}.png" for i in range(len(cams))]
    (tmp_path / "clean").mkdir()
    (tmp_path / "poisoned").mkdir()
    with torch.no_grad():
        for cam, name in zip(cams, names, strict=True):
            img = to_uint8(render(truth, cam, torch.ones(3), 1).image)
            PIL.Image.fromarray(img).save(tmp_path / "clean" / name)
            PIL.Image.fromarray(poison_array(img, PatchSpec(patch_size=12, block_size=4))[0]).save(
                tmp_path / "poisoned" / name
            )
    points = np.random.default_rng(7).uniform(-1, 1, (200, 3))
    _write_model(tmp_path / "m_clean", cams, names, points)
    # "SfM on the poisoned set" went wrong: the same views with rotated cameras
    wrong = [
        Camera(c.rotation @ _rot_y(0.3 * i), c.translation, c.fx, c.fy, c.cx, c.cy, c.width, c.height)
        for i, c in enumerate(cams)
    ]
    _write_model(tmp_path / "m_poisoned", wrong, names, points)
    options = SplatOptions(
        iterations=40,
        long_edge=48,
        white_background=True,
        densify_from=1000,
        lpips_net="alex",
        preview_views=2,
        threads=1,
    )
    result = run_splat_stage(
        tmp_path / "m_clean",
        tmp_path / "clean",
        tmp_path / "m_poisoned",
        tmp_path / "poisoned",
        tmp_path / "out",
        options,
    )
    assert result["outcome"] == "ok", result
    assert result["clean"]["views"] == result["poisoned"]["views"] == 4
    assert result["clean"]["iterations"] == 40
    cost2 = result["cost2"]
    assert cost2["images"] == 4
    assert 0.8 < cost2["ssim"] < 1.0 and 15 < cost2["psnr"] < 60
    for side in ("clean", "poisoned"):
        assert 0 < result[side]["cost1"]["ssim"] < 1 and result[side]["cost1"]["psnr"] > 5
    if result["lpips_unavailable"] is None:
        assert 0 < cost2["lpips"] < result["poisoned"]["cost1"]["lpips"]
    else:
        assert cost2["lpips"] is None  # n/a, never a made-up number
    with PIL.Image.open(result["preview"]) as im:
        assert im.size[0] == 3 * (48 + 2) and im.size[1] == 2 * (48 + 2)


def test_stage_reports_a_bad_model_as_failed(tmp_path: Path) -> None:
    from verifier.splat.stage import run_splat_stage

    (tmp_path / "empty").mkdir()
    result = run_splat_stage(
        tmp_path / "empty",
        tmp_path,
        tmp_path / "empty",
        tmp_path,
        tmp_path / "out",
        SplatOptions(iterations=1),
    )
    assert result["outcome"] == "failed"
    assert result["error"] and "\n" not in result["error"]


def _rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def test_splat_job_and_result_are_checked_at_the_process_boundary() -> None:
    import msgspec

    from verifier.splat.stage import SplatJob, SplatResult

    job = SplatJob("m_clean", "clean", "m_poisoned", "poisoned", "out", {"iterations": 3})
    assert msgspec.json.decode(msgspec.json.encode(job), type=SplatJob) == job
    with pytest.raises(msgspec.ValidationError, match=r"\$\.out_dir"):
        msgspec.json.decode(b'{"clean_model_dir": "a", "clean_images": "b", "poisoned_model_dir": "c",'
                            b' "poisoned_images": "d", "out_dir": 4}', type=SplatJob)  # fmt: skip
    with pytest.raises(msgspec.ValidationError, match=r"\$\.outcome"):
        msgspec.json.decode(b'{"outcome": 3}', type=SplatResult)
    decoded = msgspec.json.decode(b'{"outcome": "failed", "error": "x"}', type=SplatResult)
    failed = msgspec.to_builtins(decoded)
    assert failed["outcome"] == "failed" and failed["error"] == "x" and failed["clean"] is None
