"""Structure-preserving 3-D flow losses (Eq. 9) against independent references: DIS optical flow of a rigidly
translated render vs the known image shift, ARAP energy vs closed forms and finite differences, the flow loss
vs an exactly consistent motion, the ray term (not in the seed) vs closed forms and on an ambiguous flow."""

import numpy as np
import pytest
import scipy.ndimage as nd
import torch

from physar.recon.flow import (
    arap_energy,
    dis_flow,
    flow_loss,
    flow_target_loss,
    polar_rotation,
    project,
    ray_motion,
    sp_flow_prior,
    visible,
)
from physar.recon.pointrender import render_spheres
from physar.recon.train import _trilinear_matrix


def _textured_plane():
    g = np.stack(np.meshgrid(*[np.arange(-0.2, 0.2, 0.005)] * 2, indexing="ij"), -1).reshape(-1, 2)
    k = np.floor(g / 0.05).astype(int).sum(1) % 2
    col = np.where(k[:, None] == 0, [0.85, 0.35, 0.3], [0.95, 0.85, 0.55])
    return np.c_[g, np.ones(len(g))], col


@pytest.mark.parametrize("shift", [(0.02, -0.01), (0.005, 0.007), (-0.013, 0.004)])
def test_dis_flow_of_translated_render_matches_the_shift(shift):
    # a textured plane at depth 1 m, f = 100 px, translated by d (m): image shift = f d / z px everywhere
    K = np.array([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]])
    P, col = _textured_plane()
    d = np.array([*shift, 0.0])
    a, m0 = render_spheres(P, col, 0.004, K, np.eye(3), np.zeros(3), 64, 64, supersample=6)
    b, m1 = render_spheres(P + d, col, 0.004, K, np.eye(3), np.zeros(3), 64, 64, supersample=6)
    fl = dis_flow(a, b)
    inner = nd.binary_erosion(m0 & m1, iterations=3)
    expected = 100 * d[:2]
    assert np.allclose(np.median(fl[inner], 0), expected, atol=0.1)
    assert np.abs(fl[inner] - expected).mean() < 0.15


def _lattice(n=3, h=0.02):
    X = np.stack(np.meshgrid(*[np.arange(n) * h] * 3, indexing="ij"), -1).reshape(-1, 3)
    from scipy.spatial import cKDTree

    pairs = cKDTree(X).query_pairs(1.01 * np.sqrt(3) * h, output_type="ndarray")
    return torch.as_tensor(X), torch.as_tensor(pairs, dtype=torch.long)


def _rot(axis, ang):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    Kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return torch.as_tensor(np.eye(3) + np.sin(ang) * Kx + (1 - np.cos(ang)) * Kx @ Kx)


def test_arap_zero_for_rigid_motion_and_closed_form_for_uniform_stretch():
    X, pairs = _lattice()
    R = _rot([1, 2, 3], 0.7)
    x = X @ R.T + torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64)
    assert float(arap_energy(x, X, pairs)) < 1e-24
    s = 1.1  # x = R s X: residual (s - 1) R dX on every edge, E = (s - 1)^2 mean |dX|^2
    dX = X[pairs[:, 0]] - X[pairs[:, 1]]
    expected = (s - 1) ** 2 * float((dX**2).sum(1).mean())
    assert float(arap_energy(s * X @ R.T, X, pairs)) == pytest.approx(expected, rel=1e-10)


def test_arap_gradient_matches_finite_differences_of_the_full_energy():
    # R_i held fixed in autograd; at the optimal R_i this is the exact gradient (envelope theorem)
    X, pairs = _lattice()
    g = torch.Generator().manual_seed(0)
    x = (X + 0.004 * torch.randn(X.shape, generator=g, dtype=torch.float64)).requires_grad_(True)
    arap_energy(x, X, pairs).backward()
    eps = 1e-7
    for k in [(0, 0), (5, 1), (13, 2), (26, 0)]:
        xp, xm = x.detach().clone(), x.detach().clone()
        xp[k] += eps
        xm[k] -= eps
        fd = (float(arap_energy(xp, X, pairs)) - float(arap_energy(xm, X, pairs))) / (2 * eps)
        assert float(x.grad[k]) == pytest.approx(fd, rel=1e-5, abs=1e-12)


def test_polar_rotation_is_a_proper_rotation():
    g = torch.Generator().manual_seed(1)
    S = torch.randn(20, 3, 3, generator=g, dtype=torch.float64)
    R = polar_rotation(S)
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(20, 3, 3), atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(20, dtype=torch.float64))


def test_flow_loss_zero_for_consistent_motion_and_visibility():
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]], dtype=torch.float64)
    R, t = torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
    g = torch.Generator().manual_seed(2)
    x0 = torch.cat([0.1 * (torch.rand(30, 2, generator=g, dtype=torch.float64) - 0.5),
                    torch.full((30, 1), 1.0, dtype=torch.float64)], 1)
    u = torch.tensor([1.5, -0.5], dtype=torch.float64)  # constant flow field (px)
    flow = u.expand(64, 64, 2).clone()
    x1 = x0.clone()
    x1[:, :2] += u / 100.0  # fronto-parallel plane at z = 1: image shift = f d / z
    vis = torch.ones(30, dtype=torch.bool)
    assert float(flow_loss(x0, x1, flow, vis, K, R, t)) < 1e-10
    x2 = x1.clone()
    x2[:, 0] += 0.01  # 1 px off in u
    assert float(flow_loss(x0, x2, flow, vis, K, R, t)) == pytest.approx(1.0, rel=1e-9)
    # visibility: a covered surface at 1 m hides points at 1.1 m, not those at 1.0 m
    uv, z = project(torch.cat([x0, x0 + torch.tensor([0, 0, 0.1], dtype=torch.float64)]), K, R, t)
    depth, alpha = torch.full((64, 64), 1.0, dtype=torch.float64), torch.ones(64, 64, dtype=torch.float64)
    v = visible(uv, z, depth, alpha, tol=0.02)
    assert bool(v[:30].all()) and not bool(v[30:].any())


def test_material_grid_interpolation_reproduces_linear_fields():
    rng = np.random.default_rng(3)
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([0.24, 0.2, 0.12])
    X = lo + rng.random((50, 3)) * (hi - lo)
    W = _trilinear_matrix(X, lo, hi, (4, 3, 2)).numpy()
    assert np.allclose(W.sum(1), 1.0)
    nodes = np.stack(np.meshgrid(*[np.linspace(lo[a], hi[a], k) for a, k in enumerate((4, 3, 2))],
                                 indexing="ij"), -1).reshape(-1, 3)
    f = lambda p: 1.0 + p @ np.array([2.0, -3.0, 5.0])
    assert np.allclose(W @ f(nodes), f(X), atol=1e-12)
    assert _trilinear_matrix(X, lo, hi, (0, 0, 0)) is None


def test_ray_motion_is_the_squared_motion_along_the_camera_ray():
    """Closed forms: motion across the ray costs nothing, motion d along it costs d^2.  Catches the mutants
    'penalise the whole motion |x_new - x_prev|^2' and 'rays from the world origin instead of the camera
    centre'."""
    c = torch.tensor([0.3, -0.2, -2.0], dtype=torch.float64)
    g = torch.Generator().manual_seed(3)
    x0 = 0.2 * torch.rand(25, 3, generator=g, dtype=torch.float64)
    r = (x0 - c) / torch.linalg.vector_norm(x0 - c, dim=1, keepdim=True)
    across = torch.linalg.cross(r, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand(25, 3))
    across = 0.01 * across / torch.linalg.vector_norm(across, dim=1, keepdim=True)
    assert float(ray_motion(x0, x0 + across, c)) < 1e-30
    assert float(ray_motion(x0, x0 + 0.004 * r, c)) == pytest.approx(0.004**2, rel=1e-12)


def test_sp_flow_prior_keeps_the_unobserved_depth():
    """A lattice facing the camera at 1 m, a DIS-like flow that is a 1-px shift plus a 2 % expansion about the
    image centre (the looming of a 2 cm approach, or an in-plane stretch: a 2-D flow cannot tell them apart).
    Minimising the Eq. 9 geometric terms from the previous positions must keep the depth (the ray term) and still
    follow the shift.  Catches the mutant 'lambda_ray not applied in sp_flow_prior' (the lattice then moves
    toward the camera by ~4 mm) and a flow term of the wrong sign (the shift goes the other way)."""
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]], dtype=torch.float64)
    R, t = torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
    h = 0.02
    ax = torch.arange(-0.1, 0.1001, h, dtype=torch.float64)
    X = torch.stack(torch.meshgrid(ax, ax, torch.tensor([1.0, 1.0 + h], dtype=torch.float64), indexing="ij"),
                    -1).reshape(-1, 3)
    pairs = torch.as_tensor(np.array([(i, j) for i in range(len(X)) for j in range(i + 1, len(X))
                                      if float((X[i] - X[j]).norm()) < 1.01 * np.sqrt(3) * h]))
    yy, xx = torch.meshgrid(torch.arange(64, dtype=torch.float64) + 0.5, torch.arange(64, dtype=torch.float64)
                            + 0.5, indexing="ij")
    flow = torch.stack([1.0 + 0.02 * (xx - 32), 0.02 * (yy - 32)], -1)
    vis = X[:, 2] < 1.0 + h / 2  # the front layer

    def solve(lambda_ray):
        x = X.clone().requires_grad_(True)
        opt = torch.optim.Adam([x], lr=2e-3)
        for _ in range(150):
            loss = sp_flow_prior(x, X, flow, vis, K, R, t, X, pairs, 3.0, 3.0e5, lambda_ray)
            opt.zero_grad()
            loss.backward()
            opt.step()
        return x.detach()

    x = solve(3.0e5)
    dz = float((x[:, 2] - X[:, 2]).mean())
    shift = float((x[:, 0] - X[:, 0]).mean()) * 100.0 / 1.0  # px at f = 100 px, z = 1 m
    assert abs(dz) < 1e-3, dz
    assert shift == pytest.approx(1.0, abs=0.2)
    # without the ray term the lattice approaches the camera (measured: -3.9 mm; with it -0.15 mm)
    assert float((solve(0.0)[:, 2] - X[:, 2]).mean()) < -2.5e-3


def test_flow_target_loss_compares_the_chosen_particles_across_the_rays():
    """Closed forms of the Eq. 10 term's variants (TrainConfig.flow_target): all particles, mean |d| over the
    coordinates; a selection, only its rows; with the camera centre, only the part of d across the ray through the
    target.  A particle moved 4 mm along its ray and another moved 3 mm across it: all -> the mean of |d| over the
    six coordinates; across the rays -> 3 mm spread over the across direction only.  Catches the mutants 'the
    selection ignored', 'along-ray part kept' (or subtracted twice: a sign flip), 'rays from the world origin'."""
    c = torch.tensor([0.3, -0.2, -2.0], dtype=torch.float64)
    tgt = torch.tensor([[0.1, 0.05, 0.2], [-0.05, 0.1, 0.15], [0.0, 0.0, 0.1]], dtype=torch.float64)
    r = (tgt - c) / torch.linalg.vector_norm(tgt - c, dim=1, keepdim=True)
    across = torch.linalg.cross(r[1], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    across = across / torch.linalg.vector_norm(across)
    x = tgt.clone()
    x[0] += 0.004 * r[0]
    x[1] += 0.003 * across
    x[2] += torch.tensor([0.01, -0.02, 0.03], dtype=torch.float64)
    d = x - tgt
    assert float(flow_target_loss(x, tgt)) == pytest.approx(float(d.abs().sum()) / 9, rel=1e-12)
    sel = torch.tensor([True, True, False])
    assert float(flow_target_loss(x, tgt, sel)) == pytest.approx(float(d[:2].abs().sum()) / 6, rel=1e-12)
    got = float(flow_target_loss(x, tgt, sel, c))
    assert got == pytest.approx(0.003 * float(across.abs().sum()) / 6, rel=1e-9)
    assert float(flow_target_loss(x, tgt, torch.zeros(3, dtype=torch.bool), c)) == 0.0
    # the gradient: nothing pulls the first particle along its ray
    xg = x.clone().requires_grad_(True)
    flow_target_loss(xg, tgt, sel, c).backward()
    assert abs(float(xg.grad[0] @ r[0])) < 1e-12 and float(xg.grad[2].abs().sum()) == 0.0
