"""The gsplat backend's call, against gsplat.rasterization's documented contract (no GPU needed).

gsplat itself runs only on CUDA; its agreement with the tile backend was measured on a lent H200 by
benchmarks/gpu_check_gsplat.py (benchmarks/RESULTS.md, "Gaussians and MPM on CUDA"). Here a stand-in module implements
``rasterization`` as gsplat 1.5.3 documents it (activated scales and opacities, (w, x, y, z) quaternions that it
normalises, SH coefficients (N, K, 3) with ``sh_degree`` or colours (N, D), world-to-camera ``viewmats`` (C, 4, 4),
``Ks`` (C, 3, 3), optional ``covars`` (N, 3, 3), "RGB+ED" output (C, H, W, 4) and alphas (C, H, W, 1), float32
only) with the dense per-pixel reference, and physar's mapping onto it must give the tile backend's image.

Mutants caught (each was tried): log-scales or opacity logits passed instead of activated values; the viewmat
transposed; ``sh_degree`` dropped (the stand-in, like gsplat, then reads the SH array as colours and fails);
``covars`` (the deformation gradient F) dropped; the background not composited; float64 passed (gsplat's kernels
take float32 only).
"""

from __future__ import annotations

import types

import pytest
import torch

from physar.errors import PhysarError
from physar.gaussians import Camera, Gaussians, render
from physar.gaussians.model import covariance
from physar.gaussians.rasterize import _gsplat_rasterize, project, rasterize_dense
from physar.gaussians.sh import eval_sh


def _rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, near_plane=0.01,
                   eps2d=0.3, sh_degree=None, render_mode="RGB", rasterize_mode="classic", covars=None,
                   backgrounds=None, **_):
    for t in (means, quats, scales, opacities, colors, viewmats, Ks):
        assert t.dtype == torch.float32, "gsplat's kernels take float32"
    assert render_mode == "RGB+ED" and rasterize_mode == "classic" and backgrounds is None
    assert viewmats.shape == (1, 4, 4) and Ks.shape == (1, 3, 3)
    assert torch.all(scales > 0) and torch.all((opacities > 0) & (opacities < 1))
    K, V = Ks[0].double(), viewmats[0].double()
    cam = Camera(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), width, height, V[:3, :3], V[:3, 3])
    cov = covariance(quats.double(), scales.double()) if covars is None else covars.double()
    if sh_degree is None:
        assert colors.ndim == 2, "without sh_degree gsplat reads colours (N, D)"
        rgb = colors.double()
    else:
        rgb = eval_sh(colors[:, : (sh_degree + 1) ** 2].double(), means.double() - cam.center)
    pr = project(means.double(), cov, opacities.double(), rgb, cam, eps2d, near_plane)
    res = rasterize_dense(pr, width, height)
    out = torch.cat([res.rgb, res.depth[..., None]], -1).float()[None]
    return out, res.alpha.float()[None, ..., None], {}


STAND_IN = types.SimpleNamespace(rasterization=_rasterization)


def _scene():
    gen = torch.Generator().manual_seed(1)
    n = 150
    means = torch.rand(n, 3, generator=gen, dtype=torch.float64) * torch.tensor([0.4, 0.3, 0.2]) - torch.tensor(
        [0.2, 0.15, 0.1])
    q = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    g = Gaussians.from_values(means, 0.01 + 0.03 * torch.rand(n, 3, generator=gen, dtype=torch.float64),
                              0.1 + 0.8 * torch.rand(n, generator=gen, dtype=torch.float64),
                              torch.rand(n, 3, generator=gen, dtype=torch.float64), quats=2.0 * q, sh_degree=1)
    sh = g.sh.clone()
    sh[:, 1:] = 0.4 * torch.randn(n, 3, 3, generator=gen, dtype=torch.float64)
    cam = Camera.look_at((0.1, -0.2, -0.8), (0.0, 0.0, 0.0), fov_y_deg=40.0, width=48, height=40,
                         dtype=torch.float64)
    F = torch.eye(3, dtype=torch.float64) + 0.3 * torch.randn(n, 3, 3, generator=gen, dtype=torch.float64)
    return g.replace(sh=sh), cam, F


@pytest.mark.parametrize("use_F", [False, True])
def test_gsplat_call_matches_tile_backend(use_F):
    g, cam, F = _scene()
    bg = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    ref = render(g, cam, F=F if use_F else None, background=bg, backend="torch")
    got = _gsplat_rasterize(STAND_IN, g, cam, g.covariance(F) if use_F else None, None, bg, 0.3, 0.01)
    assert got.rgb.dtype == torch.float64  # back in the caller's dtype
    assert float(ref.alpha.max()) > 0.9 and float((ref.alpha > 0.5).float().mean()) > 0.2  # a covered image
    assert torch.allclose(got.rgb, ref.rgb, atol=2e-5)
    assert torch.allclose(got.alpha, ref.alpha, atol=2e-5)
    m = ref.alpha > 0.5
    assert torch.allclose(got.depth[m], ref.depth[m], atol=1e-5)


def test_gsplat_colour_override_and_gradients_reach_caller():
    g, cam, _ = _scene()
    colors = torch.rand(len(g), 3, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    g = g.detach().requires_grad_(True)
    ref = render(g, cam, colors=colors, backend="torch")
    got = _gsplat_rasterize(STAND_IN, g, cam, None, colors, None, 0.3, 0.01)
    assert torch.allclose(got.rgb, ref.rgb, atol=2e-5)
    got.rgb.sum().backward()  # through the float32 casts to the float64 leaves
    assert g.means.grad is not None and float(g.means.grad.abs().sum()) > 0


def test_gsplat_backend_refuses_cpu_tensors(monkeypatch):
    g, cam, _ = _scene()
    monkeypatch.setitem(__import__("sys").modules, "gsplat", STAND_IN)
    with pytest.raises(PhysarError, match="CUDA device"):
        render(g, cam, backend="gsplat")
    # "auto" on CPU tensors keeps the tile backend even when gsplat imports
    assert torch.allclose(render(g, cam, backend="auto").rgb, render(g, cam, backend="torch").rgb)
