"""Rasteriser against closed forms, an independent per-pixel numpy reference and finite differences."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from physar.errors import PhysarError
from physar.gaussians import Camera, Gaussians, render

D = torch.float64


def _cam(w=64, h=64, f=100.0, R=None, t=None, cx=None, cy=None):
    R = torch.eye(3, dtype=D) if R is None else torch.as_tensor(R, dtype=D)
    t = torch.zeros(3, dtype=D) if t is None else torch.as_tensor(t, dtype=D)
    return Camera(f, f, w / 2 if cx is None else cx, h / 2 if cy is None else cy, w, h, R, t)


def _footprint(mean, sigma, cam):
    """Closed form 2-D footprint of an isotropic Gaussian: pixel mean and J W Sigma W^T J^T (numpy)."""
    R, t = cam.R.numpy(), cam.t.numpy()
    x, y, z = R @ mean + t
    J = np.array([[cam.fx / z, 0, -cam.fx * x / z**2], [0, cam.fy / z, -cam.fy * y / z**2]])
    cov = J @ R @ (sigma**2 * np.eye(3)) @ R.T @ J.T
    return np.array([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy]), cov


@pytest.mark.parametrize("rotated", [False, True])
def test_single_isotropic_gaussian_matches_analytic_footprint(rotated):
    R = Rotation.from_euler("xyz", [0.2, -0.3, 0.1]).as_matrix() if rotated else np.eye(3)
    cam = _cam(R=R, t=[0.05, -0.02, 0.1])
    # put the mean on the ray through the centre of pixel (33, 30) at depth 3 m, off-axis
    z = 3.0
    p_cam = np.array([(33.5 - cam.cx) * z / cam.fx, (30.5 - cam.cy) * z / cam.fy, z])
    mean = R.T @ (p_cam - cam.t.numpy())
    sigma, eta = 0.06, 0.8
    g = Gaussians.from_values(torch.tensor(mean[None], dtype=D), torch.tensor([sigma], dtype=D),
                              torch.tensor([eta], dtype=D), torch.tensor([[0.2, 0.5, 0.9]], dtype=D))
    out = render(g, cam, eps2d=0.0)
    m2, cov = _footprint(mean, sigma, cam)
    assert np.allclose(m2, [33.5, 30.5])
    jj, ii = np.mgrid[0:64, 0:64] + 0.5
    d = np.stack([ii - m2[0], jj - m2[1]], -1)
    q = np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d)
    expect = eta * np.exp(-0.5 * q)
    expect[expect < 1 / 255] = 0.0
    alpha = out.alpha.numpy()
    assert np.abs(alpha - expect).max() < 1e-12
    assert alpha[30, 33] == pytest.approx(eta, abs=1e-12)  # peak opacity at the projected mean
    # the footprint integrates to eta * 2 pi sqrt(det) (mass below the 1/255 cut is < 1 %)
    assert alpha.sum() == pytest.approx(eta * 2 * math.pi * math.sqrt(np.linalg.det(cov)), rel=1e-2)
    assert np.allclose(out.rgb.numpy()[30, 33], eta * np.array([0.2, 0.5, 0.9]))
    assert out.depth[30, 33].item() == pytest.approx(z, abs=1e-12)


def test_two_gaussians_composite_front_to_back():
    cam = _cam(32, 32)
    red, blue = [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]
    mk = lambda order: Gaussians.from_values(
        torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 4.0]], dtype=D)[order], torch.tensor([0.1, 0.2], dtype=D)[order],
        torch.tensor([0.9, 0.7], dtype=D)[order], torch.tensor([red, blue], dtype=D)[order])
    for order in ([0, 1], [1, 0]):
        out = render(mk(order), cam, eps2d=0.0, background=torch.tensor([0.0, 1.0, 0.0]))
        c = out.rgb[16, 16].numpy()  # pixel centre (16.5, 16.5): 0.5 px off the projected means
        a_front = 0.9 * math.exp(-0.5 * 0.5 / (100 * 0.1 / 2.0) ** 2)
        a_back = 0.7 * math.exp(-0.5 * 0.5 / (100 * 0.2 / 4.0) ** 2)
        T2 = (1 - a_front) * (1 - a_back)
        assert np.allclose(c, [a_front, T2, (1 - a_front) * a_back], atol=1e-12)
        assert out.alpha[16, 16].item() == pytest.approx(1 - T2, abs=1e-12)
        ed = (2.0 * a_front + 4.0 * (1 - a_front) * a_back) / (1 - T2)
        assert out.depth[16, 16].item() == pytest.approx(ed, abs=1e-12)


def _reference_numpy(g, cam, eps2d, bg):
    """Independent per-pixel 3DGS reference: sequential loop with the CUDA rasteriser's rules."""
    mu = g.means.numpy()
    q = g.quats.numpy() / np.linalg.norm(g.quats.numpy(), axis=1, keepdims=True)
    Rg = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    S = np.exp(g.log_scales.numpy())
    eta = 1 / (1 + np.exp(-g.opacity_logits.numpy()))
    col = 0.28209479177387814 * g.sh.numpy()[:, 0] + 0.5
    R, t = cam.R.numpy(), cam.t.numpy()
    items = []
    for i in range(len(mu)):
        x, y, z = R @ mu[i] + t
        J = np.array([[cam.fx / z, 0, -cam.fx * x / z**2], [0, cam.fy / z, -cam.fy * y / z**2]])
        cov3 = Rg[i] @ np.diag(S[i] ** 2) @ Rg[i].T
        cov2 = J @ R @ cov3 @ R.T @ J.T + eps2d * np.eye(2)
        items.append((z, np.array([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy]), np.linalg.inv(cov2),
                      eta[i], col[i]))
    items.sort(key=lambda it: it[0])
    img = np.zeros((cam.height, cam.width, 3))
    acc = np.zeros((cam.height, cam.width))
    for j in range(cam.height):
        for i in range(cam.width):
            T, c = 1.0, np.zeros(3)
            p = np.array([i + 0.5, j + 0.5])
            for z, m, Q, o, cc in items:
                d = p - m
                power = -0.5 * d @ Q @ d
                if power > 0:
                    continue
                a = min(0.99, o * math.exp(power))
                if a < 1 / 255:
                    continue
                if T * (1 - a) < 1e-4:
                    break
                c += a * T * cc
                T *= 1 - a
            img[j, i] = c + T * bg
            acc[j, i] = 1 - T
    return img, acc


def _random_scene(n, seed, sh_degree=0, spread=0.6):
    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=gen, dtype=D) - 0.5) * spread
    means[:, 2] += 2.5
    g = Gaussians.from_values(means, 0.02 + 0.08 * torch.rand(n, 3, generator=gen, dtype=D),
                              0.3 + 0.69 * torch.rand(n, generator=gen, dtype=D),
                              torch.rand(n, 3, generator=gen, dtype=D),
                              quats=torch.randn(n, 4, generator=gen, dtype=D), sh_degree=sh_degree)
    return g


def test_matches_independent_per_pixel_reference_on_random_scene():
    g = _random_scene(40, seed=1)
    cam = _cam(27, 21, f=40.0)  # sizes not multiples of the tile size
    bg = np.array([0.1, 0.2, 0.3])
    ref_rgb, ref_a = _reference_numpy(g, cam, 0.3, bg)
    assert ref_a.max() > 0.99 and ref_a.min() < 0.5  # opaque overlaps and free pixels both present
    for backend, ts in (("torch", 4), ("torch", 16), ("dense", 4)):
        out = render(g, cam, background=torch.tensor(bg), backend=backend, tile_size=ts)
        assert np.abs(out.rgb.numpy() - ref_rgb).max() < 1e-10, (backend, ts)
        assert np.abs(out.alpha.numpy() - ref_a).max() < 1e-10


def test_tiles_match_dense_float32_larger_scene():
    g = _random_scene(600, seed=2, sh_degree=2, spread=1.5).to(torch.float32)
    g.sh[:, 1:] = 0.1 * torch.randn_like(g.sh[:, 1:])
    cam = Camera.look_at((0.3, -0.2, -1.0), (0.0, 0.0, 2.5), width=80, height=64, fov_y_deg=50)
    a = render(g, cam, backend="torch")
    b = render(g, cam, backend="dense")
    assert (a.rgb - b.rgb).abs().max() < 1e-4
    assert (a.alpha - b.alpha).abs().max() < 1e-4
    mask = b.alpha > 0.05
    assert (a.depth - b.depth)[mask].abs().max() < 1e-4


def test_gradients_match_central_finite_differences():
    g = _random_scene(6, seed=3, sh_degree=1, spread=0.4)
    g.sh[:, 1:] = 0.2
    cam = _cam(14, 12, f=30.0)
    gen = torch.Generator().manual_seed(4)
    wr = torch.rand(12, 14, 3, generator=gen, dtype=D)
    wa = torch.rand(12, 14, generator=gen, dtype=D)
    wd = torch.rand(12, 14, generator=gen, dtype=D)
    names = ["means", "log_scales", "sh", "opacity_logits", "quats"]

    def loss(*tensors):
        gg = Gaussians(**dict(zip(names, tensors, strict=True)))
        out = render(gg, cam, background=torch.tensor([0.3, 0.3, 0.3], dtype=D))
        return (out.rgb * wr).sum() + (out.alpha * wa).sum() + 0.1 * (out.depth * out.alpha * wd).sum()

    inputs = tuple(getattr(g, k).clone().requires_grad_() for k in names)
    assert torch.autograd.gradcheck(loss, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_deformation_gradient_changes_footprint_like_eq3():
    """Rendering with F equals rendering with the explicitly deformed covariance F Sigma F^T."""
    g = _random_scene(20, seed=5)
    F = torch.eye(3, dtype=D) + 0.2 * torch.randn(20, 3, 3, generator=torch.Generator().manual_seed(6),
                                                    dtype=D)
    cam = _cam(24, 24, f=40.0)
    a = render(g, cam, F=F)
    Rg = torch.tensor(Rotation.from_quat(
        (g.quats / g.quats.norm(dim=1, keepdim=True)).numpy()[:, [1, 2, 3, 0]]).as_matrix())
    S2 = torch.diag_embed(torch.exp(2 * g.log_scales))
    b = render(g, cam, cov3d=F @ Rg @ S2 @ Rg.transpose(1, 2) @ F.transpose(1, 2))
    assert torch.allclose(a.rgb, b.rgb, atol=1e-12)
    assert not torch.allclose(a.rgb, render(g, cam).rgb, atol=1e-3)


def test_bad_arguments_raise_clear_errors():
    g = _random_scene(3, seed=0)
    with pytest.raises(PhysarError, match="backend"):
        render(g, _cam(), backend="vulkan")
    with pytest.raises(PhysarError, match="F must have shape"):
        render(g, _cam(), F=torch.eye(3, dtype=D))
    with pytest.raises(PhysarError, match="means"):
        Gaussians(torch.zeros(3, 2), torch.zeros(3, 4), torch.zeros(3, 3), torch.zeros(3), torch.zeros(3, 1, 3))
    with pytest.raises(PhysarError, match="sh"):
        Gaussians(torch.zeros(3, 3), torch.zeros(3, 4), torch.zeros(3, 3), torch.zeros(3), torch.zeros(3, 5, 3))


def test_gaussians_behind_camera_are_culled():
    g = Gaussians.from_values(torch.tensor([[0.0, 0.0, -2.0]], dtype=D), torch.tensor([0.5], dtype=D),
                              torch.tensor([0.9], dtype=D), torch.tensor([[1.0, 1.0, 1.0]], dtype=D))
    out = render(g, _cam(16, 16))
    assert out.alpha.abs().max() == 0


def test_memory_guard_and_offscreen_jacobian_clamp():
    g = _random_scene(50, seed=7)
    with pytest.raises(PhysarError, match="max_elements"):
        render(g, _cam(32, 32), max_elements=1e3)
    # a Gaussian just in front of the camera plane and far off to the side: footprint stays bounded
    near = Gaussians.from_values(torch.tensor([[5.0, 0.0, 0.05]], dtype=D), torch.tensor([0.01], dtype=D),
                                 torch.tensor([0.9], dtype=D), torch.ones(1, 3, dtype=D))
    out = render(near, _cam(32, 32))
    assert out.alpha.max() == 0 and out.n_pairs == 0


def _opaque_layers(n_layers=6, per_layer=16, seed=11):
    """Stacked layers of nearly opaque, strongly anisotropic Gaussians (axis ratios up to 8): a quarter of
    the pixels terminate (T < 1e-4), and the pairs behind them are culled."""
    gen = torch.Generator().manual_seed(seed)
    n = n_layers * per_layer
    means = (torch.rand(n, 3, generator=gen, dtype=D) - 0.5) * torch.tensor([0.4, 0.4, 0.0], dtype=D)
    means[:, 2] = 2.0 + 0.1 * torch.arange(n_layers, dtype=D).repeat_interleave(per_layer)
    scales = 0.04 + 0.15 * torch.rand(n, 3, generator=gen, dtype=D)
    scales[0::2, 0] *= 0.125  # thin in x: the x and y extents of the bounding box differ
    scales[1::2, 1] *= 0.125
    return Gaussians.from_values(means, scales, 0.9 + 0.0999 * torch.rand(n, generator=gen, dtype=D),
                                 torch.rand(n, 3, generator=gen, dtype=D),
                                 quats=torch.randn(n, 4, generator=gen, dtype=D))


def test_culled_tiles_match_dense_reference_values_and_gradients():
    """With autograd the tile backend drops (tile, Gaussian) pairs that cannot contribute (alpha = 0 at every
    pixel of the tile, or compositing terminated before them) and buckets each footprint by the bounding box
    of its ellipse; image and gradients must equal the dense reference (every Gaussian at every pixel, no
    tiles, no culling) to float64 rounding.  Mutants caught: culling a pair terminated at any (not every)
    pixel of its tile, the x and y half-widths of the bounding box swapped, culling without a pixel test."""
    g = _opaque_layers()
    cam = _cam(30, 26, f=60.0)  # not multiples of the tile size
    gen = torch.Generator().manual_seed(12)
    wr, wa, wd = (torch.rand(26, 30, *s, generator=gen, dtype=D) for s in ((3,), (), ()))
    names = ["means", "log_scales", "sh", "opacity_logits", "quats"]
    results = {}
    for backend in ("torch", "dense"):
        leaves = {k: getattr(g, k).clone().requires_grad_() for k in names}
        out = render(Gaussians(**leaves), cam, background=torch.tensor([0.2, 0.3, 0.4], dtype=D), backend=backend)
        ((out.rgb * wr).sum() + (out.alpha * wa).sum() + (out.depth * out.alpha * wd).sum()).backward()
        results[backend] = (out, {k: v.grad for k, v in leaves.items()})
    (a, ga), (b, gb) = results["torch"], results["dense"]
    assert b.alpha.max() > 0.999 and b.alpha.min() < 0.5  # terminated pixels (T < 1e-3) and free pixels
    assert 0 < a.n_composited < 0.7 * a.n_pairs  # the culling is exercised
    for name in ("rgb", "alpha", "depth"):
        assert (getattr(a, name) - getattr(b, name)).abs().max() < 1e-12, name
    for k in names:
        assert gb[k].abs().max() > 0, k
        assert (ga[k] - gb[k]).abs().max() <= 1e-9 * gb[k].abs().max(), k
    # without autograd nothing is culled, and the image is the same
    with torch.no_grad():
        c = render(g, cam, background=torch.tensor([0.2, 0.3, 0.4], dtype=D))
    assert c.n_composited == c.n_pairs == a.n_pairs
    assert (c.rgb - b.rgb.detach()).abs().max() < 1e-12


def test_bounding_box_buckets_fewer_pairs_than_the_circle():
    """The support ellipse of a thin Gaussian is bucketed by its bounding box (half-widths
    k sqrt(Sigma'_xx), k sqrt(Sigma'_yy)), not by the enclosing circle of radius k sqrt(lambda_max):
    closed-form tile count of one axis-aligned Gaussian, 8:1 in x:y."""
    cam = _cam(64, 64, f=100.0)
    g = Gaussians.from_values(torch.tensor([[0.0, 0.0, 2.0]], dtype=D), torch.tensor([[0.16, 0.02, 0.02]], dtype=D),
                              torch.tensor([0.5], dtype=D), torch.ones(1, 3, dtype=D))
    out = render(g, cam, eps2d=0.0)
    sx, sy = 100 * 0.16 / 2.0, 100 * 0.02 / 2.0  # px
    k = math.sqrt(2 * math.log(255 * 0.5))
    ntiles = lambda c, h: math.floor((c + h - 0.5) / 4) - math.floor((c - h - 0.5) / 4) + 1
    tx = min(ntiles(32.0, 1.001 * k * sx), 16)  # clipped to the image's 16 tiles
    assert out.n_pairs == tx * ntiles(32.0, 1.001 * k * sy)
    assert out.n_pairs < 16 * 16 / 2  # the circle (radius k sx > 32 px) would cover every tile


def test_terminating_pair_is_kept_and_the_pairs_behind_it_are_culled():
    """Four large Gaussians stacked on the optical axis (sigma 50 px at 2 m, image 16 px): after layers 1-2
    T >= 1e-4 at every pixel, layer 3 brings it below 1e-4 everywhere (so it terminates and does not
    composite), layer 4 is never reached.  Closed form at every pixel: colour = c1 a1 + c2 a2 (1 - a1)
    + bg T2, alpha = 1 - T2, T2 = (1 - a1)(1 - a2); layer 4's pairs are culled, layer 3's kept, and the
    gradients equal the dense reference's.  Mutant caught: culling by T (1 - alpha) < 1e-4 instead of
    T < 1e-4 (drops the terminating layer 3, and layer 4 composites with weight ~1e-5)."""
    cam = _cam(16, 16, f=100.0)
    z = torch.tensor([2.0, 2.1, 2.2, 2.3], dtype=D)
    eta = torch.tensor([0.9999, 0.98, 0.99, 0.3], dtype=D)
    cols = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]], dtype=D)
    names = ["means", "log_scales", "sh", "opacity_logits", "quats"]
    g = Gaussians.from_values(torch.stack([torch.zeros(4, dtype=D), torch.zeros(4, dtype=D), z], 1),
                              z / 2.0, eta, cols)  # scale z / 2 m at depth z: sigma = 50 px for all four
    bg = torch.tensor([0.2, 0.3, 0.4], dtype=D)
    res = {}
    for backend in ("torch", "dense"):
        leaves = {k: getattr(g, k).clone().requires_grad_() for k in names}
        out = render(Gaussians(**leaves), cam, background=bg, backend=backend, eps2d=0.0)
        (out.rgb.sum() + out.alpha.sum()).backward()
        res[backend] = (out, {k: v.grad for k, v in leaves.items()})
    (a, ga), (b, gb) = res["torch"], res["dense"]
    jj, ii = torch.meshgrid(torch.arange(16, dtype=D) + 0.5, torch.arange(16, dtype=D) + 0.5, indexing="ij")
    r2 = (ii - 8.0) ** 2 + (jj - 8.0) ** 2
    al = [torch.clamp(eta[i] * torch.exp(-0.5 * r2 / (100 * (z[i] / 2) / z[i]) ** 2), max=0.99) for i in range(4)]
    T1, T2, T3 = 1 - al[0], (1 - al[0]) * (1 - al[1]), (1 - al[0]) * (1 - al[1]) * (1 - al[2])
    assert T2.min() > 1e-4 and T3.max() < 1e-4  # the scenario: layer 3 terminates every pixel
    rgb = al[0][..., None] * cols[0] + (al[1] * T1)[..., None] * cols[1] + T2[..., None] * bg
    for out in (a, b):
        assert (out.rgb - rgb).abs().max() < 1e-12 and (out.alpha - (1 - T2)).abs().max() < 1e-12
    assert a.n_pairs == 64 and a.n_composited == 48  # 16 tiles x 4 layers; layer 4 culled
    for k in names:
        assert (ga[k] - gb[k]).abs().max() <= 1e-9 * gb[k].abs().max(), k
    assert ga["sh"][2:].abs().max() == 0 and ga["opacity_logits"][2:].abs().max() == 0
